"""The outer loop in a process of its own: a controller built there by a picklable factory re-plans
on the newest state the inner loop shares, and hands each plan back through shared memory, where
the inner loop's process takes it as a :class:`~sabre.PlanSnapshot` like one made in-process.

In one process, the planner's Python work (phase logic, guides, the task's probes) holds the
interpreter lock between its Rust calls, and a 1 kHz state callback waits for it; here the inner
loop's process only ever waits for its own work. Both sides exchange fixed-size float64 blocks
guarded by a sequence counter (odd while a write is under way), so neither side blocks the other:
the planner, reading the state, tries again when a copy overlapped a write; the inner loop, reading
the plan, tries once and keeps the plan it had.
"""

from __future__ import annotations

import multiprocessing
import os
import queue
import signal
import time
import traceback
from collections.abc import Callable
from typing import Any

import numpy as np

from .errors import PlannerError
from .inner_loop import PlanSnapshot

__all__ = ["PlanSnapshot", "PlannerProcess"]

# Plan block header: sequence, t0, dt, gain floor (NaN: none), phase index, iteration time (s),
# iterations, nominal cost, has predicted dissipation, failed; then nominal (K·nu), then predicted (K).
_SEQ, _T0, _DT, _FLOOR, _PHASE, _ITER_TIME, _ITERS, _COST, _HAS_PRED, _FAILED = range(10)
_PLAN_HEADER = 10
# State block: sequence, t, then x (nx).
_STATE_HEADER = 2


def _write(block: np.ndarray, values: list[tuple[int, Any]]) -> None:
    """Writes under the block's sequence counter: odd while writing, even when done. The new
    contents are staged first, so that the counter is odd only for the one copy into the block: a
    real-time reader that finds it odd does not wait for a writer the scheduler may have put aside."""
    staged = block[1:].copy()
    for start, value in values:
        data = np.asarray(value, dtype=np.float64).ravel()
        staged[start - 1 : start - 1 + data.size] = data
    block[0] += 1.0
    block[1:] = staged
    block[0] += 1.0


def _read(block: np.ndarray, tries: int = 1000) -> tuple[float, np.ndarray] | None:
    """(sequence, copy) of a block no write was under way on, or None if every try overlapped one
    (the real-time side tries once and keeps what it had)."""
    for attempt in range(tries):
        before = float(block[0])
        if before % 2.0 == 0.0:
            copy = block.copy()
            if float(block[0]) == before:
                return before, copy
        if attempt + 1 < tries:
            time.sleep(0)
    return None


def _lower_priority(nice: int, idle: bool) -> None:
    """Lowers the planner process's priority below the 1 kHz path and the DDS threads."""
    if nice:
        try:
            os.nice(nice)  # leave the cores to the 1 kHz path and the DDS threads when they want them
        except OSError:
            pass
    if idle and hasattr(os, "SCHED_IDLE"):
        # Stronger than any niceness: a waking middleware or control thread preempts the planner at
        # once instead of waiting for its time slice. The sampler's workers, started later, inherit it.
        try:
            os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
        except OSError:
            pass


def _run_commands(controller: Any, commands: Any) -> None:
    """Calls every method call the parent queued (obstacle changes) on the controller."""
    while True:
        try:
            name, args = commands.get_nowait()
        except queue.Empty:
            return
        getattr(controller, name)(*args)


def _hand_over(block: np.ndarray, snapshot: PlanSnapshot, phases: tuple[str, ...], steps: int, nu: int) -> None:
    """Writes a plan the controller made (:meth:`Controller.snapshot`), with its header, into the shared
    plan block; :meth:`PlannerProcess.snapshot` makes the same snapshot of it on the other side."""
    floor = snapshot.gain_inertia_floor
    predicted = snapshot.predicted
    header = [
        snapshot.t0,
        snapshot.dt,
        np.nan if floor is None else floor,
        float(phases.index(snapshot.phase)),
        snapshot.iteration_time,
        float(snapshot.iterations),
        snapshot.nominal_cost,
        0.0 if predicted is None else 1.0,
        0.0,
    ]
    values: list[tuple[int, Any]] = [(_T0, header), (_PLAN_HEADER, snapshot.nominal[:steps, :nu])]
    if predicted is not None:
        values.append((_PLAN_HEADER + steps * nu, predicted[:steps]))
    _write(block, values)


def _planner_main(
    factory: Callable[[], Any],
    state_raw: Any,
    plan_raw: Any,
    dims: tuple[int, int, int],
    commands: Any,
    errors: Any,
    stop: Any,
    min_period: float,
    t0: float,
    nice: int,
    idle: bool,
    compensate: bool,
    command_delay: float,
) -> None:
    """The planner process: build the controller, then plan on the newest shared state until told
    to stop, with ``compensate`` from the state predicted when the plan's commands will act (the last
    iteration's time from reading the state to handing the plan over, plus ``command_delay``). SIGINT
    is the parent's to handle (it stops the planner through ``stop``)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _lower_priority(nice, idle)
    parent = os.getppid()
    nx, steps, nu = dims
    state = np.frombuffer(state_raw, dtype=np.float64)
    plan = np.frombuffer(plan_raw, dtype=np.float64)
    try:
        controller = factory()
        phases = tuple(controller.task.phases)
        controller.reset(t0=t0)
        delay = 0.0
        while not stop.is_set() and os.getppid() == parent:  # an orphan (its parent killed) stops
            started = time.perf_counter()
            _run_commands(controller, commands)
            read = _read(state)
            if read is None:
                continue
            taken = time.perf_counter()
            copy = read[1]
            t, x = float(copy[1]), copy[_STATE_HEADER : _STATE_HEADER + nx]
            measured = x
            if compensate and delay + command_delay > 0.0:
                x, t = controller.predict(x, t, delay + command_delay)
            controller.update(x, t, observed=measured)
            _hand_over(plan, controller.snapshot(), phases, steps, nu)
            delay = time.perf_counter() - taken
            rest = min_period - (time.perf_counter() - started)
            if rest > 0.0:
                stop.wait(rest)
    except BaseException as exc:  # reported to the inner loop's process, raised on its next tick
        errors.put(f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}")
        _write(plan, [(_FAILED, [1.0])])


class PlannerProcess:
    """Runs the outer loop in a spawned process on a controller that ``factory`` builds there.

    ``factory`` must be picklable (a module-level function, a ``functools.partial`` of one) and
    build the same controller (scene, task, configuration) the inner loop holds, so that both agree
    on the plan's shape and the obstacles' ids. The process runs at ``nice`` (added niceness) and,
    with ``idle``, under SCHED_IDLE where the OS has it, so that a machine with few cores serves the
    1 kHz path and the middleware's threads first. With ``compensate`` (default) each plan is made
    from :meth:`Controller.predict` of the shared state, a delay ahead: the last iteration's time
    from reading the state to handing its plan over, which the inner loop spent on the previous plan,
    plus ``command_delay`` (s, the robot's own wait before a command acts).
    """

    def __init__(
        self,
        factory: Callable[[], Any],
        *,
        nx: int,
        steps: int,
        nu: int,
        phases: tuple[str, ...],
        min_replan_period: float,
        nice: int,
        idle: bool = False,
        compensate: bool = True,
        command_delay: float = 0.0,
        start_timeout: float = 120.0,
    ) -> None:
        self._factory = factory
        self._dims = (int(nx), int(steps), int(nu))
        self._phases = tuple(phases)
        self._min_period = float(min_replan_period)
        self._nice = int(nice)
        self._idle = bool(idle)
        self._compensate = bool(compensate)
        self._command_delay = float(command_delay)
        self._start_timeout = float(start_timeout)
        self._ctx = multiprocessing.get_context("spawn")
        self._state_raw = self._ctx.RawArray("d", _STATE_HEADER + int(nx))
        self._plan_raw = self._ctx.RawArray("d", _PLAN_HEADER + int(steps) * int(nu) + int(steps))
        self._state = np.frombuffer(self._state_raw, dtype=np.float64)
        self._staged_state = np.zeros(len(self._state) - 1)  # share_state's staging, reused at 1 kHz
        self._plan = np.frombuffer(self._plan_raw, dtype=np.float64)
        self._commands: Any = self._ctx.Queue()
        self._errors: Any = self._ctx.Queue()
        self._stop = self._ctx.Event()
        self._process: Any = None
        self._seen = -1.0
        self._snapshot: PlanSnapshot | None = None
        self._failure: str | None = None

    @property
    def pid(self) -> int | None:
        """The process's id while it runs, else None."""
        return None if self._process is None else self._process.pid

    def start(self, x0: np.ndarray, t0: float, wait: bool = True) -> PlanSnapshot | None:
        """Shares x0, spawns the process and waits for its first plan (``wait=False``: returns at
        once; :meth:`snapshot` is None until the first plan arrives)."""
        if self._process is not None:
            raise PlannerError("the planner process is already running")
        self.share_state(x0, t0)
        self._stop.clear()
        self._process = self._ctx.Process(
            target=_planner_main,
            name="sabre-planner",
            daemon=True,
            args=(
                self._factory,
                self._state_raw,
                self._plan_raw,
                self._dims,
                self._commands,
                self._errors,
                self._stop,
                self._min_period,
                float(t0),
                self._nice,
                self._idle,
                self._compensate,
                self._command_delay,
            ),
        )
        # The planner's Python side makes many small NumPy calls; BLAS threads of its own would spin
        # between them on the cores its rollouts (and the inner loop) need. A spawned process reads
        # the variable when it imports NumPy; one the user set is left alone.
        blas = os.environ.get("OPENBLAS_NUM_THREADS")
        os.environ["OPENBLAS_NUM_THREADS"] = blas or "1"
        try:
            self._process.start()
        except Exception as exc:  # pickling the factory, or the OS refusing a process
            self._process = None
            raise PlannerError(
                f"cannot start the planner process (the factory must be picklable: a module-level "
                f"function or a functools.partial of one): {type(exc).__name__}: {exc}"
            ) from exc
        finally:
            if blas is None:
                del os.environ["OPENBLAS_NUM_THREADS"]
        if not wait:
            return None
        deadline = time.monotonic() + self._start_timeout
        while True:
            snapshot = self.snapshot()
            if snapshot is not None:
                return snapshot
            if not self._process.is_alive() or time.monotonic() > deadline:
                self.stop()
                raise PlannerError(
                    "the planner process did not deliver a first plan"
                    + ("" if self._process is None else f" (exit code {self._process.exitcode})")
                )
            time.sleep(0.002)

    def share_state(self, x: np.ndarray, t: float) -> None:
        """The newest measured state, for the next planning iteration. :func:`_write`'s protocol,
        staged in a reused buffer: this runs once per state of a 1 kHz loop."""
        staged, block = self._staged_state, self._state
        staged[0] = t
        staged[_STATE_HEADER - 1 :] = x
        block[0] += 1.0
        block[1:] = staged
        block[0] += 1.0

    def snapshot(self) -> PlanSnapshot | None:
        """The newest complete plan (None before the first one); raises :class:`PlannerError` with
        the planner's traceback once the process has failed."""
        if self._plan.item(_SEQ) == self._seen:  # the common case at 1 kHz: no new plan
            if self._plan.item(_FAILED) != 0.0:
                raise PlannerError(self._error_text())
            return self._snapshot
        if self._plan.item(_FAILED) != 0.0:
            raise PlannerError(self._error_text())
        # One try: the 1 kHz callback never waits for the planner. A plan being written is taken
        # at the next tick.
        read = _read(self._plan, tries=1)
        if read is None or read[0] == 0.0:
            return self._snapshot
        seq, block = read
        _, steps, nu = self._dims
        if block[_FAILED] != 0.0:
            raise PlannerError(self._error_text())
        floor = float(block[_FLOOR])
        self._snapshot = PlanSnapshot.of(
            block[_PLAN_HEADER : _PLAN_HEADER + steps * nu].reshape(steps, nu),
            float(block[_T0]),
            float(block[_DT]),
            predicted=block[_PLAN_HEADER + steps * nu :] if block[_HAS_PRED] != 0.0 else None,
            gain_inertia_floor=None if np.isnan(floor) else floor,
            phase=self._phases[int(block[_PHASE])],
            iteration_time=float(block[_ITER_TIME]),
            iterations=int(block[_ITERS]),
            nominal_cost=float(block[_COST]),
        )
        self._seen = seq
        return self._snapshot

    def _error_text(self) -> str:
        if self._failure is None:
            try:
                self._failure = "the planner process failed: " + self._errors.get(timeout=1.0)
            except queue.Empty:
                self._failure = "the planner process failed"
        return self._failure

    def call(self, name: str, *args: Any) -> None:
        """Calls ``controller.<name>(*args)`` in the planner process before its next iteration
        (obstacles: ``add_obstacle``, ``move_obstacle``, ``remove_obstacle``)."""
        self._commands.put((name, tuple(args)))

    @property
    def alive(self) -> bool:
        return self._process is not None and self._process.is_alive()

    def stop(self, timeout: float = 10.0) -> None:
        """Stops the process (terminated if it does not finish an iteration within ``timeout`` s)."""
        self._stop.set()
        if self._process is not None:
            self._process.join(timeout)
            if self._process.is_alive():
                self._process.terminate()
                self._process.join(timeout)
            self._process = None
