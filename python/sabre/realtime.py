"""The deployment loop of the cascade, on any clock: :class:`RealtimeCascade` plans (outer loop) and ticks
(inner loop, Sec. IV) on the states a simulator or a robot hands it.

``tick(x, tau_ext, t)`` is the inner loop: one call into the core's cascade (``_core.Cascade``, the same
tick :func:`sabre.run_episode` and the ROS 2 bridge run), which takes over the plan handed over for t,
interpolates the plan in force at time t, runs the controller's inner FILTER-QP with the energy tank
(variants I, IO), refills the tank from the plan's predicted dissipation, integrates it, and computes the
low-level torque; every input is checked there, once. ``plan(x, t)`` is one planning iteration in the
caller's thread, so that a simulator can run the cascade in simulated time, deterministically
(``delay=`` the planning time to simulate); ``start()`` instead plans in the background against the wall
clock: a thread running ``Controller.update`` on the newest state (its iterations release the GIL in Rust,
its Python work between them holds it), or, with ``planner_process=factory``, a process of its own
(:class:`~sabre.planner_process.PlannerProcess`), so that a 1 kHz callback never waits for it. Either way
the inner loop reads :class:`~sabre.PlanSnapshot` values, swapped in whole, never the planner's working copy.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import _core
from ._validate import as_finite, as_float_array, as_non_negative, as_positive
from .errors import InvalidValueError, ShapeError
from .inner_loop import LowLevelController, PlanSnapshot, inner_cascade
from .planner import Controller
from .planner_process import PlannerProcess

__all__ = ["RealtimeCascade", "TickResult"]


@dataclass(frozen=True)
class TickResult:
    """One inner-loop tick: reference (nu,) from the plan, command (nu,) after the filter, torque
    (nq,) from the low-level controller (None without one), tank energy (J), filter status
    (``"unfiltered"`` without a filter)."""

    reference: np.ndarray
    command: np.ndarray
    torque: np.ndarray | None
    tank_energy: float
    status: str


def _vector(name: str, value: Any, copy: bool) -> np.ndarray:
    """``value`` as the C-contiguous float64 array the core's tick takes (a copy if asked); its shape
    and values are checked there."""
    try:
        return np.array(value, dtype=np.float64) if copy else np.ascontiguousarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ShapeError(f"{name}: cannot be read as a float array ({exc})") from None


def _number(name: str, value: Any) -> float:
    """``value`` as a float (its finiteness is checked by the core)."""
    try:
        return float(value)
    except (TypeError, ValueError):
        raise InvalidValueError(f"{name}: expected a number, got {value!r}") from None


class RealtimeCascade:
    """Runs ``controller`` as a cascade: :meth:`plan` and :meth:`tick` in the caller's loop (simulated or
    wall-clock time), or :meth:`start` / :meth:`stop` (or a ``with`` block) with the planner in the
    background against the wall clock.

    ``low_level``: the low-level controller (53) whose torques :meth:`tick` returns, for a robot (or
    simulator) taking joint torques. None: a robot with a velocity interface, which gets the command;
    the tick then returns no torque, since a PI controller whose torques nobody applies would only wind
    up its integral (the core's tick still computes one, with a controller at ``inner_dt`` kept inside).

    ``planner_process``: a picklable callable (a module-level function or a ``functools.partial``
    of one) that builds the same controller as ``controller`` (scene, task, configuration); the
    outer loop then plans in a spawned process on that copy, niced by ``planner_nice`` and, with
    ``planner_idle``, under SCHED_IDLE (it runs only on CPU time nothing else wants), while
    ``controller`` serves the inner loop (its FILTER-QP and tank). Obstacles then go through the
    cascade's :meth:`add_obstacle` and friends, which reach both copies. None: a thread of this
    process plans on ``controller`` itself.

    ``delay_compensation`` (default True): each plan takes over only once computed, while the inner
    loop still follows the previous one, so the planner plans from the state
    :meth:`Controller.predict` expects at that moment (the planning time ahead) instead of the
    measured one. ``command_delay`` (s, default 0) adds the time a robot takes before a command acts
    beyond that (an arm on trajectory segments: their lead and half a publication period), so that
    the plan starts where the robot will be when its first command takes effect.

    τ_ext as a robot delivers it (:meth:`set_external_torque`, or a wrist wrench read in the core by the
    ROS 2 bridge through ``wrench_frames``: world frame, the sensor frame of an empty header, the moment's
    point frame or "") is low-passed at ``tau_ext_cutoff`` Hz (None: as read) and counts as none once older
    than ``tau_ext_timeout`` s (None: never); :meth:`tick`'s own τ_ext is taken as read at its time.
    """

    def __init__(
        self,
        controller: Controller,
        *,
        low_level: LowLevelController | None = None,
        inner_dt: float = 0.001,
        min_replan_period: float = 0.0,
        planner_process: Callable[[], Controller] | None = None,
        planner_nice: int = 10,
        planner_idle: bool = False,
        delay_compensation: bool = True,
        command_delay: float = 0.0,
        tau_ext_cutoff: float | None = None,
        tau_ext_timeout: float | None = None,
        wrench_frames: tuple[str, str, str] | None = None,
    ) -> None:
        if not isinstance(controller, Controller):
            raise TypeError(f"controller must be a sabre.Controller, got {type(controller).__name__}")
        if low_level is not None and not isinstance(low_level, LowLevelController):
            raise TypeError(f"low_level must be a sabre.LowLevelController, got {type(low_level).__name__}")
        if planner_process is not None and not callable(planner_process):
            raise InvalidValueError("planner_process must be a callable that builds the planner's Controller")
        scene = controller.scene
        if low_level is not None and (low_level.scene.nq != scene.nq or low_level.scene.nx != scene.nx):
            raise InvalidValueError("low_level: built for a different scene than the controller's")
        self.controller = controller
        self.low_level = low_level
        self.inner_dt = as_positive("inner_dt", inner_dt)
        self.min_replan_period = as_non_negative("min_replan_period", min_replan_period)
        self._factory = planner_process
        self._planner_nice = int(planner_nice)
        self._planner_idle = bool(planner_idle)
        self.delay_compensation = bool(delay_compensation)
        self.command_delay = as_non_negative("command_delay", command_delay)
        self._low = low_level if low_level is not None else LowLevelController(scene, dt=self.inner_dt)
        self._cascade = inner_cascade(
            self._low,
            controller.inner_filter,
            controller.tank,
            controller.config.safety_config,
            tau_ext_cutoff=tau_ext_cutoff,
            tau_ext_timeout=tau_ext_timeout,
            wrench_frames=wrench_frames,
        )
        self._delay = 0.0  # the last wall-clock planning's time from reading a state to handing its plan over
        self._process: PlannerProcess | None = None
        self._obstacle_log: list[tuple[str, tuple[object, ...]]] = []  # replayed in each planner process
        # A single reference, swapped whole: the planner thread and the tick never see half of one.
        self._latest: tuple[np.ndarray, float] | None = None
        # The snapshots of the plans the core's cascade holds (in force, waiting), by the number it gave them.
        self._snapshots: dict[int, PlanSnapshot] = {}
        self._from_process: PlanSnapshot | None = None  # the planner process's plan handed over last
        self._lock = threading.Lock()  # the cascade's plans: the planner thread hands over, the tick takes over
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        self._stopped = False

    # Outer loop -----------------------------------------------------------------------------
    def reset(self, seed: int | None = None, t0: float = 0.0) -> None:
        """Resets the controller (``seed``: its sampler's stream, default the configured one; ``t0``: the
        start time), the low-level controller's integral and the tank, and forgets the plans and the
        measured planning time: a simulated run after reset repeats exactly. Refused while the planner runs."""
        self._refuse_while_planning("reset()")
        self.controller.reset(seed, as_finite("t0", t0))
        self._cascade.reset()
        self._snapshots, self._latest, self._from_process = {}, None, None
        self._delay = 0.0
        self._stopped = False

    def plan(self, x: Sequence[float] | np.ndarray, t: float, *, delay: float | None = None) -> PlanSnapshot:
        """One planning iteration in the caller's thread from the measured state x (nx,) at time t (s);
        returns its plan, which the next ticks follow.

        ``delay`` None (wall-clock use): the plan takes over at once, and with ``delay_compensation`` it is
        made from the state :meth:`Controller.predict` expects the previous planning's measured time
        ahead. ``delay`` in seconds (simulated use): the planning is taken to last that long, so the plan
        takes over at the first tick at t + delay (the plan in force runs until then) and, with
        ``delay_compensation``, is made from the state predicted that far ahead; no clock is read, so a
        run is deterministic for the controller's seed. Refused while :meth:`start` plans in the background.

        Raises:
            ShapeError: x is not (nx,). InvalidValueError: non-finite x or t, a negative delay.
        """
        self._refuse_while_planning("plan()")
        x = as_float_array("x", x, (self.controller.scene.nx,))
        t = as_finite("t", t)
        self._latest = (x, t)
        if delay is None:
            snapshot = self._plan_now(x, t)
            self._put(snapshot)
        else:
            delay = as_non_negative("delay", delay)
            self._plan_at(t)  # a plan handed over for t or earlier is in force by now
            snapshot = self._make_plan(x, t, delay + self.command_delay if self.delay_compensation else 0.0)
            self._put(snapshot, t + delay if delay > 0.0 else None)
        return snapshot

    def hand_over(self, snapshot: PlanSnapshot, at: float | None = None) -> None:
        """Hands the inner loop a plan: one from :meth:`plan` or :meth:`Controller.snapshot`, or made
        elsewhere (:meth:`PlanSnapshot.of`). It takes over at the first tick at time ``at`` (s) or later;
        None, or no plan in force yet: at once. A plan still waiting for its time is dropped. Refused while
        :meth:`start` plans in the background."""
        if not isinstance(snapshot, PlanSnapshot):
            raise TypeError(f"snapshot must be a sabre.PlanSnapshot, got {type(snapshot).__name__}")
        self._refuse_while_planning("hand_over()")
        self._put(snapshot, None if at is None else as_finite("at", at))

    def _put(self, snapshot: PlanSnapshot, at: float | None = None) -> None:
        """Hands ``snapshot`` to the core's cascade (see :meth:`hand_over`) and keeps it while the cascade
        holds its plan."""
        with self._lock:
            serial = self._cascade.hand_over(snapshot.plan, at)
            self._snapshots[serial] = snapshot
            pending = self._cascade.pending
            held = {self._cascade.in_force, None if pending is None else pending[0]}
            for old in [k for k in self._snapshots if k not in held]:
                del self._snapshots[old]
        self._stopped = False

    @property
    def _plan(self) -> PlanSnapshot | None:
        """The snapshot of the plan in force (None before the first)."""
        with self._lock:
            return self._snapshots.get(self._cascade.in_force or 0)

    def _refuse_while_planning(self, what: str) -> None:
        if self._thread is not None or self._process is not None:
            raise InvalidValueError(f"{what}: the planner runs in the background (start()); stop() it first")

    def _make_plan(self, x: np.ndarray, t: float, delay: float) -> PlanSnapshot:
        """One planning iteration from the state predicted ``delay`` s after x at t (x itself for 0)."""
        observed = x
        if delay > 0.0:
            x, t = self.controller.predict(x, t, delay)
        self.controller.update(x, t, observed=observed)
        return self.controller.snapshot()

    def _plan_now(self, x: np.ndarray, t: float) -> PlanSnapshot:
        """A wall-clock planning iteration: compensated by the previous one's measured time, and timed."""
        taken = time.perf_counter()
        snapshot = self._make_plan(x, t, self._delay + self.command_delay if self.delay_compensation else 0.0)
        self._delay = time.perf_counter() - taken
        return snapshot

    def start(self, x0: Sequence[float] | np.ndarray, t0: float = 0.0, *, wait: bool = True) -> RealtimeCascade:
        """Resets (:meth:`reset`), plans once from x0 (so the first tick has a reference) and starts
        the planner: a thread, or the planner process (which makes that first plan itself). With
        the planner process, ``wait=False`` returns before that first plan: :attr:`ready` tells when
        it has arrived (a caller answers the states before it with a safe stop and hands them to
        :meth:`observe`); ticking earlier raises. A thread always plans once before returning."""
        if self._thread is not None or self._process is not None:
            raise InvalidValueError("the cascade is already running")
        x0 = as_float_array("x0", x0, (self.controller.scene.nx,))
        t0 = as_finite("t0", t0)
        self.reset(t0=t0)
        self._latest = (x0, t0)
        if self._factory is not None:
            self._start_process(self._factory, x0, t0, wait)
            return self
        self._put(self._plan_now(x0, t0))
        self._stop.clear()
        self._error = None
        self._thread = threading.Thread(target=self._run, name="sabre-outer-loop", daemon=True)
        self._thread.start()
        return self

    def _start_process(self, factory: Callable[[], Controller], x0: np.ndarray, t0: float, wait: bool) -> None:
        c = self.controller
        self._process = PlannerProcess(
            factory,
            nx=c.scene.nx,
            steps=c.config.horizon_steps,
            nu=c.scene.nu,
            phases=tuple(c.task.phases),
            min_replan_period=self.min_replan_period,
            nice=self._planner_nice,
            idle=self._planner_idle,
            compensate=self.delay_compensation,
            command_delay=self.command_delay,
        )
        for name, args in self._obstacle_log:
            self._process.call(name, *args)
        try:
            first = self._process.start(x0, t0, wait=wait)
            if first is not None:
                self._from_process = first
                self._put(first)
        except BaseException:
            self._process.stop()
            self._process = None
            raise

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                started = time.perf_counter()
                latest = self._latest
                assert latest is not None, "start() stores the first state before the thread starts"
                self._put(self._plan_now(*latest))
                rest = self.min_replan_period - (time.perf_counter() - started)
                if rest > 0:
                    self._stop.wait(rest)
        except BaseException as exc:  # surfaced on the next tick
            self._error = exc

    def stop(self) -> None:
        """Stops the planner (thread or process) and waits for it to finish; ticks then raise until the
        next :meth:`start` or :meth:`plan`."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
            self._stopped = True
        if self._process is not None:
            self._process.stop()
            self._process = None
            self._stopped = True

    def __enter__(self) -> RealtimeCascade:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def running(self) -> bool:
        """Whether the planner (thread or process) runs."""
        if self._process is not None:
            return self._process.alive
        return self._thread is not None and self._thread.is_alive()

    @property
    def ready(self) -> bool:
        """Whether a plan is there for the inner loop to read."""
        process = self._process
        if process is not None and self._plan is None:
            self._take_newer_plan(process)
        return self._plan is not None

    @property
    def current_plan(self) -> PlanSnapshot | None:
        """The plan in force: the one the last tick followed, or the newest handed over since."""
        return self._plan

    @property
    def phase(self) -> str:
        """The task phase of the plan in force (the controller's before the first plan)."""
        plan = self._plan
        return self.controller.phase if plan is None else plan.phase

    @property
    def iteration_time(self) -> float:
        """Wall time (s) of the planning iteration that made the plan in force (NaN before one)."""
        plan = self._plan
        return float("nan") if plan is None else plan.iteration_time

    @property
    def iterations(self) -> int:
        """Planning iterations since the start up to the plan in force (0 before one)."""
        plan = self._plan
        return 0 if plan is None else plan.iterations

    @property
    def planner_in_process(self) -> bool:
        """Whether the outer loop plans in a process of its own."""
        return self._factory is not None

    @property
    def planner_pid(self) -> int | None:
        """The planner process's id while it runs (to pin it to cores, say), else None."""
        return None if self._process is None else self._process.pid

    # Obstacles, into both filters of the variant (and the planner process's copy) -----------
    def add_obstacle(self, center: Sequence[float] | np.ndarray, radius: float) -> int | None:
        """:meth:`Controller.add_obstacle` on the inner loop's controller and the planner's."""
        oid = self.controller.add_obstacle(center, radius)
        self._forward("add_obstacle", np.asarray(center, dtype=np.float64).tolist(), float(radius))
        return oid

    def _forward(self, name: str, *args: object) -> None:
        """Sends an obstacle change to the planner process, and logs it: a planner process started
        later builds its controller afresh and replays the log before its first plan."""
        if self._factory is None:
            return
        self._obstacle_log.append((name, args))
        if self._process is not None:
            self._process.call(name, *args)

    def move_obstacle(self, obstacle_id: int, center: Sequence[float] | np.ndarray) -> None:
        """:meth:`Controller.move_obstacle` on both controllers."""
        self.controller.move_obstacle(obstacle_id, center)
        self._forward("move_obstacle", int(obstacle_id), np.asarray(center, dtype=np.float64).tolist())

    def remove_obstacle(self, obstacle_id: int) -> None:
        """:meth:`Controller.remove_obstacle` on both controllers."""
        self.controller.remove_obstacle(obstacle_id)
        self._forward("remove_obstacle", int(obstacle_id))

    # Inner loop -----------------------------------------------------------------------------
    def reference(self, t: float) -> np.ndarray:
        """(nu,) the reference a tick at time t would follow: the plan in force at t, linearly
        interpolated (held at its ends)."""
        with self._lock:
            pending = self._cascade.pending
            serial = self._cascade.in_force
            if pending is not None and t >= pending[1] - _core.TAKEOVER_TOLERANCE:
                serial = pending[0]
            plan = self._snapshots.get(serial or 0)
        if plan is None:
            raise InvalidValueError("no plan yet: call plan() or start() first (and, with wait=False, wait until ready)")
        return plan.reference(t)

    def _plan_at(self, t: float) -> PlanSnapshot | None:
        """The plan in force at time t, after a plan handed over for t or earlier takes over."""
        with self._lock:
            return self._snapshots.get(self._cascade.plan_at(t) or 0)

    def observe(self, x: Sequence[float] | np.ndarray, t: float) -> None:
        """Hands the planner the newest measured state x (nx,) at time t without ticking (a caller
        that answers this state with a safe stop instead, e.g. because the plan is stale, must
        still let the planner catch up), and takes over a newer plan if the planner process has one."""
        x = as_float_array("x", x, (self.controller.scene.nx,))
        t = as_finite("t", t)
        self._latest = (x, t)
        process = self._process
        if process is not None:
            process.share_state(x, t)
            self._take_newer_plan(process)

    def _take_newer_plan(self, process: PlannerProcess) -> None:
        """Takes over the planner process's newest plan if it is not the one in force; raises
        PlannerError once the process has failed. The caller passes the process it saw: another
        thread may :meth:`stop` the cascade meanwhile."""
        snapshot = process.snapshot()
        if snapshot is not None and snapshot is not self._from_process:
            self._from_process = snapshot
            self._put(snapshot)

    @property
    def plan_start(self) -> float | None:
        """Time (s) of the first step of the plan in force (None before one)."""
        process = self._process
        if process is not None:
            self._take_newer_plan(process)
        plan = self._plan
        return None if plan is None else plan.t0

    def _check_running(self) -> None:
        if self._error is not None:
            raise self._error
        if self._stopped:
            raise InvalidValueError("the cascade was stopped: its plan is frozen; start() it again")

    def poll(self) -> None:
        """Takes over a newer plan of the planner process, for a caller that ticks the cascade in the core
        itself (the ROS 2 bridge's ``_core.BridgeTick``, built on :attr:`core`), which then hands the state
        it answered to :meth:`observe`.

        Raises:
            InvalidValueError: a stopped cascade. PlannerError: the planner process failed.
        """
        self._check_running()
        process = self._process
        if process is not None:
            self._take_newer_plan(process)

    @property
    def core(self) -> _core.Cascade:
        """The core's cascade the plans are handed to and :meth:`tick` runs; a tick in Rust (the ROS 2
        bridge's) is built on it, so that the bridge and this loop follow the same plan in force."""
        return self._cascade

    @property
    def ticks(self) -> int:
        """The cascade's ticks since the last reset (also the ones a tick in Rust ran on :attr:`core`)."""
        return int(self._cascade.ticks)

    def set_external_torque(self, tau_ext: Sequence[float] | np.ndarray, force: float, received: float) -> None:
        """The newest τ_ext (nq,) a robot delivered and the wrist force's magnitude (N; inf: torques only, contact
        assumed), arrived at ``received`` (s, the ticks' clock): the ticks of a tick in Rust read it, conditioned."""
        self._cascade.set_external_torque(_vector("tau_ext", tau_ext, copy=False), float(force), float(received))

    def tick(
        self, x: Sequence[float] | np.ndarray, tau_ext: Sequence[float] | np.ndarray, t: float, dt: float | None = None
    ) -> TickResult:
        """One inner-loop step from the measured state x (nx,) and external torques τ_ext (nq,)
        at time t (s): the plan in force at t → FILTER-QP with the tank (variants I, IO) → the tank's
        refill (when the controller's tank has one, :class:`~sabre.TankRefill`, while τ_ext agrees with the
        plan's predicted dissipation) and step → low-level torque with the plan's gain inertia floor.
        The tank integrates over ``dt`` (s): the measured time since the previous state, e.g. the
        difference of two message stamps (default: ``inner_dt``).
        The tank integrates this τ_ext against the returned command, the same pair the passivity
        row constrained, so the floor holds step by step. τ_ext should be a band-limited estimate
        (a momentum observer, a filtered wrist sensor; in simulation :attr:`PlantInterface.measured_tau_ext`):
        raw impact spikes that vanish between steps let the command through in between and chatter.
        The state also becomes the outer loop's next starting point.

        Raises:
            ShapeError: x not (nx,), τ_ext not (nq,). InvalidValueError: non-finite input, dt not
            positive, no plan yet, a stopped cascade. PlannerError: the planner process failed.
        """
        self._check_running()
        x = _vector("x", x, copy=True)  # kept as the planner's next state: the caller may reuse its array
        tau_ext = _vector("tau_ext", tau_ext, copy=False)
        t = _number("t", t)
        step = self.inner_dt if dt is None else _number("dt", dt)
        process = self._process
        if process is not None:
            self._take_newer_plan(process)
        if self._cascade.in_force is None:
            raise InvalidValueError("no plan yet: call plan() or start() first (and, with wait=False, wait until ready)")
        reference, command, torque, energy, status = self._cascade.tick(x, tau_ext, t, step)
        self._latest = (x, t)
        if process is not None:
            process.share_state(x, t)
        return TickResult(
            reference=reference,
            command=command,
            torque=None if self.low_level is None else torque,
            tank_energy=float("nan") if energy is None else energy,
            status=status,
        )
