"""Real-time mode of the cascade: the outer loop re-plans on its own thread, the inner loop is
driven by incoming state (e.g. a ROS 2 joint-state callback at 1 kHz).

``RealtimeCascade.tick(x, tau_ext, t)`` is the inner loop of Sec. IV: it interpolates the latest
reference at time t, runs the controller's inner FILTER-QP with the energy tank (variants I, IO),
integrates the tank, and returns the command (and, with a low-level controller, the torque). The
planner runs ``Controller.update`` in a background thread on the most recent state it was given;
its iterations release the GIL in Rust, but its Python work between those calls (phase logic,
guides) holds it. With ``planner_process=factory`` the planner runs in a process of its own on a
controller the factory builds there (:class:`~sabre.planner_process.PlannerProcess`), so that a
1 kHz callback never waits for it. The reference the inner loop reads is a snapshot swapped in
after each iteration, never the planner's working copy.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ._validate import as_finite, as_float_array, as_non_negative, as_positive
from .errors import InvalidValueError
from .inner_loop import LowLevelController
from .planner import Controller
from .planner_process import PlannerProcess, PlanSnapshot

__all__ = ["RealtimeCascade", "TickResult"]


@dataclass(frozen=True)
class TickResult:
    """One inner-loop tick: reference (nu,) from the plan, command (nu,) after the filter, torque
    (nq,) from the low-level controller (None without one), tank energy (J), filter status."""

    reference: np.ndarray
    command: np.ndarray
    torque: np.ndarray | None
    tank_energy: float
    status: str


def _interpolate(sequence: np.ndarray, t0: float, dt: float, t: float) -> np.ndarray:
    """Row k of ``sequence`` applies at t0 + k·dt: linear in between, held at both ends."""
    s = min(max((float(t) - t0) / dt, 0.0), float(len(sequence) - 1))
    i = int(s)
    j = min(i + 1, len(sequence) - 1)
    a = s - i
    return (1.0 - a) * sequence[i] + a * sequence[j]


class RealtimeCascade:
    """Runs `controller` as a real-time cascade. Use as a context manager or call start/stop.

    ``planner_process``: a picklable callable (a module-level function or a ``functools.partial``
    of one) that builds the same controller as ``controller`` (scene, task, configuration); the
    outer loop then plans in a spawned process on that copy, niced by ``planner_nice`` and, with
    ``planner_idle``, under SCHED_IDLE (it runs only on CPU time nothing else wants), while
    ``controller`` serves the inner loop (its FILTER-QP and tank). Obstacles then go through the
    cascade's :meth:`add_obstacle` and friends, which reach both copies. None: a thread of this
    process plans on ``controller`` itself.

    ``delay_compensation`` (default True): each plan takes over only once computed, while the inner
    loop still follows the previous one, so the planner plans from the state
    :meth:`Controller.predict` expects at that moment (its last iteration's time ahead) instead of
    the measured one. ``run_episode(plan_delay=...)`` reproduces the delay in simulated time.
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
    ) -> None:
        if not isinstance(controller, Controller):
            raise TypeError(f"controller must be a sabre.Controller, got {type(controller).__name__}")
        if planner_process is not None and not callable(planner_process):
            raise InvalidValueError("planner_process must be a callable that builds the planner's Controller")
        self.controller = controller
        self.low_level = low_level
        self.inner_dt = as_positive("inner_dt", inner_dt)
        self.min_replan_period = as_non_negative("min_replan_period", min_replan_period)
        self._factory = planner_process
        self._planner_nice = int(planner_nice)
        self._planner_idle = bool(planner_idle)
        self.delay_compensation = bool(delay_compensation)
        self._delay = 0.0  # the planner thread's last time from reading a state to handing its plan over
        self._process: PlannerProcess | None = None
        self._obstacle_log: list[tuple[str, tuple[object, ...]]] = []  # replayed in each planner process
        self._phase = controller.phase
        self._iteration_time = float("nan")
        self._lock = threading.Lock()
        self._latest: tuple[np.ndarray, float] | None = None
        # (nominal, t0, dt) and the plan's predicted port dissipation for the tank's refill
        self._plan: tuple[np.ndarray, float, float] | None = None
        self._predicted: np.ndarray | None = None
        # the task's low-level gain inertia floor for the planned phase (None: the controller's own)
        self._floor: float | None = None
        self._own_floor = 0.0 if low_level is None else low_level.gain_inertia_floor
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None
        self._stopped = False
        self.iterations = 0
        self.ticks = 0

    # Outer loop -----------------------------------------------------------------------------
    def start(self, x0: Sequence[float] | np.ndarray, t0: float = 0.0, *, wait: bool = True) -> RealtimeCascade:
        """Resets the controller, plans once from x0 (so the first tick has a reference) and starts
        the planner: a thread, or the planner process (which makes that first plan itself). With
        the planner process, ``wait=False`` returns before that first plan: :attr:`ready` tells when
        it has arrived (a caller answers the states before it with a safe stop and hands them to
        :meth:`observe`); ticking earlier raises. A thread always plans once before returning."""
        if self._thread is not None or self._process is not None:
            raise InvalidValueError("the cascade is already running")
        x0 = as_float_array("x0", x0, (self.controller.scene.nx,))
        t0 = as_finite("t0", t0)
        self.controller.reset(t0=t0)
        if self.low_level is not None:
            self.low_level.reset()
        self._latest = (x0, t0)
        self._delay = 0.0
        self._stopped = False
        with self._lock:
            self._plan, self._predicted, self._floor = None, None, None
        if self._factory is not None:
            self.iterations = 0
            c = self.controller
            self._process = PlannerProcess(
                self._factory,
                nx=c.scene.nx,
                steps=c.config.horizon_steps,
                nu=c.scene.nu,
                phases=tuple(c.task.phases),
                min_replan_period=self.min_replan_period,
                nice=self._planner_nice,
                idle=self._planner_idle,
                compensate=self.delay_compensation,
            )
            for name, args in self._obstacle_log:
                self._process.call(name, *args)
            try:
                first = self._process.start(x0, t0, wait=wait)
                if first is not None:
                    self._apply(first)
            except BaseException:
                self._process.stop()
                self._process = None
                raise
            return self
        self._plan_once()
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="sabre-outer-loop", daemon=True)
        self._thread.start()
        return self

    def _apply(self, snapshot: PlanSnapshot) -> None:
        """Takes over a plan the planner process handed over."""
        with self._lock:
            self._plan = (snapshot.nominal, snapshot.t0, snapshot.dt)
            self._predicted = snapshot.predicted
            self._floor = snapshot.floor
        self._phase = snapshot.phase
        self._iteration_time = snapshot.iteration_time
        self.iterations = snapshot.iterations

    def _plan_once(self) -> None:
        with self._lock:
            latest = self._latest
        assert latest is not None, "start() stores the first state before any planning"
        taken = time.perf_counter()
        x, t = latest
        if self.delay_compensation:
            x, t = self.controller.predict(x, t, self._delay)
        self.controller.update(x, t)
        plan = (np.array(self.controller.nominal), float(self.controller.nominal_t0), float(self.controller.config.dt))
        predicted = self.controller.predicted_dissipation
        floor = self.controller.task.gain_inertia_floor(self.controller.phase)
        with self._lock:
            self._plan = plan
            self._predicted = None if predicted is None else np.array(predicted)
            self._floor = floor
        self._phase = self.controller.phase
        stats = self.controller.stats
        self._iteration_time = float("nan") if stats is None else float(stats.iteration_time)
        self.iterations += 1
        self._delay = time.perf_counter() - taken

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                started = time.perf_counter()
                self._plan_once()
                rest = self.min_replan_period - (time.perf_counter() - started)
                if rest > 0:
                    self._stop.wait(rest)
        except BaseException as exc:  # surfaced on the next tick
            self._error = exc

    def stop(self) -> None:
        """Stops the planner (thread or process) and waits for it to finish."""
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
        """Whether a plan is there for the inner loop to read (after start)."""
        if self._process is not None and self._plan is None:
            self._take_newer_plan()
        return self._plan is not None

    @property
    def phase(self) -> str:
        """The task phase of the newest plan."""
        return self._phase

    @property
    def iteration_time(self) -> float:
        """Wall time (s) of the planning iteration that made the newest plan (NaN before one)."""
        return self._iteration_time

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
        """(nu,) the latest plan linearly interpolated at time t (held at its ends)."""
        with self._lock:
            plan = self._plan
        if plan is None:
            raise InvalidValueError("no plan yet: call start() first (and, with wait=False, wait until ready)")
        nominal, t0, dt = plan
        return _interpolate(nominal, t0, dt, t)

    def observe(self, x: Sequence[float] | np.ndarray, t: float) -> None:
        """Hands the planner the newest measured state x (nx,) at time t without ticking (a caller
        that answers this state with a safe stop instead, e.g. because the plan is stale, must
        still let the planner catch up), and takes over a newer plan if the planner process has one."""
        x = as_float_array("x", x, (self.controller.scene.nx,))
        t = as_finite("t", t)
        with self._lock:
            self._latest = (x, t)
        self._refresh(x, t)

    def _refresh(self, x: np.ndarray, t: float) -> None:
        if self._process is not None:
            self._process.share_state(x, t)
            self._take_newer_plan()

    def _take_newer_plan(self) -> None:
        """Takes over the planner process's newest plan if it is not the one in use; raises
        PlannerError once the process has failed."""
        assert self._process is not None
        snapshot = self._process.snapshot()
        if snapshot is not None and (self._plan is None or snapshot.iterations != self.iterations):
            self._apply(snapshot)

    @property
    def plan_start(self) -> float | None:
        """Time (s) of the first step of the plan the inner loop reads (None before start)."""
        if self._process is not None:
            self._take_newer_plan()
        with self._lock:
            plan = self._plan
        return None if plan is None else plan[1]

    def tick(
        self, x: Sequence[float] | np.ndarray, tau_ext: Sequence[float] | np.ndarray, t: float, dt: float | None = None
    ) -> TickResult:
        """One inner-loop step from the measured state x (nx,) and external torques τ_ext (nq,)
        at time t: reference → FILTER-QP with the tank (variants I, IO) → tank (refilled as in
        :class:`~sabre.TankRefill` when the controller's tank has a refill) → low-level torque.
        The tank integrates over ``dt`` (s): the measured time since the previous state, e.g.
        the difference of two message stamps (default: ``inner_dt``).
        The tank integrates this τ_ext against the returned command, the same pair the passivity
        row constrained, so the floor holds step by step. τ_ext should be a band-limited estimate
        (a momentum observer, a filtered wrist sensor; in simulation :attr:`Plant.measured_tau_ext`):
        raw impact spikes that vanish between steps let the command through in between and chatter.
        The state also becomes the outer loop's next starting point."""
        if self._error is not None:
            raise self._error
        if self._stopped:
            raise InvalidValueError("the cascade was stopped: its plan is frozen; start() it again")
        scene = self.controller.scene
        x = as_float_array("x", x, (scene.nx,))
        tau_ext = as_float_array("tau_ext", tau_ext, (scene.nq,))
        t = as_finite("t", t)
        with self._lock:
            self._latest = (x, t)
        self._refresh(x, t)
        u_ref = self.reference(t)
        tank = self.controller.tank
        status = "unfiltered"
        u = u_ref
        f = self.controller.inner_filter
        if f is not None:
            r = f.filter(x, u_ref, tau_ext, tank.energy)
            u, status = np.asarray(r.u), r.status
        step = self.inner_dt if dt is None else as_positive("dt", dt)
        with self._lock:
            predicted, plan = self._predicted, self._plan
        if predicted is not None and plan is not None and tank.refill_config is not None:
            tank.refill(float(_interpolate(predicted, plan[1], plan[2], t)), -float(tau_ext @ u_ref), step)
        energy = tank.step(tau_ext, u, step)
        torque = None
        if self.low_level is not None:
            with self._lock:
                floor = self._floor
            wanted = self._own_floor if floor is None else floor
            if self.low_level.gain_inertia_floor != wanted:
                self.low_level.gain_inertia_floor = wanted
            torque = self.low_level.torque(x, u)
        self.ticks += 1
        return TickResult(reference=u_ref, command=np.asarray(u), torque=torque, tank_energy=float(energy), status=status)
