"""Closed-loop episodes on a plant: :func:`run_episode` runs a :class:`~sabre.Controller` on the 1 kHz plant, a
:class:`~sabre.Plant` or any other :class:`~sabre.PlantInterface`.

The inner loop interpolates the plan in force (a :class:`~sabre.PlanSnapshot`), filters it (variants I, IO) and
tracks it with the low-level controller (53); the outer loop re-plans at ``replan_rate`` in simulated time.
:func:`paper_start_state` is the paper's starting condition.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from ._validate import as_count, as_float_array, as_non_negative, as_positive
from .episode import Episode, PlanRecorder, TraceChunks
from .errors import InvalidValueError
from .estimated_object import SEATING_PHASE, EstimatedObject
from .inner_loop import LowLevelController, PlanSnapshot, follow_plant, inner_cascade
from .planner import Controller, likelihood_weights
from .plants import PlantInterface, as_plant
from .scene import Scene
from .sim import Plant
from .tasks import OpenObject, Task

if TYPE_CHECKING:
    from .viz.viewer import Viewer

__all__ = ["run_episode", "paper_start_state"]


def paper_start_state(scene: Scene) -> np.ndarray:
    """The robot's start state (:meth:`Scene.start_state`): its declared ``<start>`` posture over its
    home posture, at rest, object closed. For the RoyalPanda it is the paper's starting condition:
    base at (−3, −3), arm folded near its joint limits and close to self-collision (shoulder back,
    elbow fully bent); a robot that declares no start begins at its home posture."""
    return scene.start_state()


# long: the docstring documents each keyword of the one entry point; the body is short
def run_episode(
    scene: Scene,
    controller: Controller,
    duration: float,
    *,
    seed: int | None = None,
    x0: Sequence[float] | np.ndarray | None = None,
    replan_rate: float = 20.0,
    record_every: int = 10,
    stop_on_success: bool = True,
    settle_time: float = 0.5,
    progress: bool | None = None,
    plant: PlantInterface | None = None,
    low_level: LowLevelController | None = None,
    on_replan: Callable[[float, np.ndarray, PlantInterface, Controller], None] | None = None,
    record_plans: bool = False,
    viewer: Viewer | None = None,
    plan_delay: float = 0.0,
    delay_compensation: bool = True,
    estimated: EstimatedObject | None = None,
    judge: Task | None = None,
) -> Episode:
    """Runs the controller on the plant for ``duration`` seconds of simulated time; returns the traces.

    The controller re-plans every 1/``replan_rate`` s (Hz, default 20) of simulated time from the
    plant's state; in between, the core's cascade (the tick :class:`sabre.RealtimeCascade` and the ROS 2 bridge
    run) interpolates its reference, filters it (variants I, IO) and tracks it with the low-level controller (53).

    ``record_plans`` records the nominal plan's hand path and the contacts at every re-plan (see
    :class:`Episode`); a :class:`sabre.viz.viewer.Viewer` passed as ``viewer`` shows the run live (and
    implies the recording).

    Args:
        seed: the sampler's seed for this episode (default: the controller's configured seed).
        x0: start state (nx,) (default: :func:`paper_start_state`).
        record_every: record every n-th plant step (default 10, i.e. 100 Hz on the 1 kHz plant).
        stop_on_success, settle_time: end ``settle_time`` s (default 0.5) after the task succeeds.
        progress: a tqdm bar; None (default) shows it for runs longer than 10 s of simulated time.
        plant, low_level: any :class:`~sabre.PlantInterface` (default: a new 1 kHz :class:`Plant`, stepped in
            Rust; others from Python, same tick) and its controller (default: one at the plant's step).
        on_replan: ``on_replan(t, x, plant, controller)`` runs before each re-plan (for
            disturbances); returning True ends the episode there.
        plan_delay: seconds (default 0) between the state a plan is made from and the plan taking
            over, during which the previous plan keeps running: the computation time of a planner
            running against the wall clock (:class:`sabre.RealtimeCascade`, the ROS 2 bridge),
            here in simulated time. At most the re-planning period.
        delay_compensation: with a ``plan_delay``, plan from the state :meth:`Controller.predict`
            expects when the plan takes over (default True), as :class:`sabre.RealtimeCascade` does.
        estimated: an object the controller knows only by its handle (:class:`sabre.EstimatedObject`):
            ``scene`` (the plant's) holds the true object, hidden from the controller, which plans
            with the estimated object's scene (switched to it at the start and whenever it is rebuilt)
            from the robot's measured joints and the object's state along the estimate. The estimate
            takes every recorded plant step (``record_every``); success is the true object's.
        judge: the task whose success rule judges ``scene``'s state (default: the controller's); a
            hidden object's own task (its handle named as the true object names it).

    Raises:
        InvalidValueError: non-positive duration or replan_rate, record_every < 1, non-finite x0,
            a negative plan_delay or one longer than the re-planning period, a plant of another scene.
        ShapeError: x0 is not (nx,). TypeError: plant is no :class:`~sabre.PlantInterface` (naming what it lacks).
    """
    duration = as_positive("duration", duration)
    replan_rate = as_positive("replan_rate", replan_rate)
    plan_delay = as_non_negative("plan_delay", plan_delay)
    record_every = as_count("record_every", record_every)
    plant = Plant(scene) if plant is None else as_plant(plant, scene)
    low_level = low_level or LowLevelController(scene, dt=plant.dt)
    x0 = paper_start_state(scene) if x0 is None else as_float_array("x0", x0, (scene.nx,))
    steps_per_plan = max(1, int(round(1.0 / (replan_rate * plant.dt))))
    delay_steps = int(round(plan_delay / plant.dt))
    if delay_steps > steps_per_plan:
        raise InvalidValueError(f"plan_delay {plan_delay} s is longer than the re-planning period {1.0 / replan_rate} s")
    plant.reset(x0)
    low_level.reset()
    if estimated is not None:
        _plan_with_estimate(controller, estimated)
    controller.reset(seed, 0.0)
    bar = _progress_bar(scene, duration, duration > 10.0 if progress is None else progress)
    loop = _ClosedLoop(
        scene,
        controller,
        plant,
        low_level,
        delay_steps=delay_steps,
        record_every=record_every,
        delay_compensation=delay_compensation,
        record_plans=record_plans or viewer is not None,
        viewer=viewer,
        estimated=estimated,
        judge=judge,
    )
    total_steps = max(1, int(round(duration / plant.dt)))
    return loop.run(total_steps, steps_per_plan, on_replan, stop_on_success, settle_time, bar)


def _plan_with_estimate(controller: Controller, estimated: EstimatedObject) -> None:
    """Has the controller plan with the estimated object's scene, the opening counted from where its hook
    holds the bar."""
    if controller.scene is not estimated.scene:
        controller.set_scene(estimated.scene)
    if isinstance(controller.task, OpenObject):
        estimated.hook_point = controller.task.grasp_offset(estimated.scene, "hook")[:3, 3]


def _progress_bar(scene: Scene, duration: float, show: bool) -> Any:
    """A tqdm bar over the simulated seconds, or None when not shown or tqdm is missing."""
    if not show:
        return None
    try:
        from tqdm import tqdm
    except ImportError:
        return None
    return tqdm(total=round(duration, 3), unit="s sim", leave=False, desc=f"{scene.object_name}")


class _ClosedLoop:
    """The state of one :func:`run_episode` between re-plans: the plant and its inner loop, the plan the inner loop
    follows while the next one is computed, and the recorders of the episode."""

    def __init__(
        self,
        scene: Scene,
        controller: Controller,
        plant: PlantInterface,
        low_level: LowLevelController,
        *,
        delay_steps: int,
        record_every: int,
        delay_compensation: bool,
        record_plans: bool,
        viewer: Viewer | None,
        estimated: EstimatedObject | None = None,
        judge: Task | None = None,
    ) -> None:
        self.scene, self.controller, self.plant, self.low_level = scene, controller, plant, low_level
        self.estimated = estimated
        self.judge = judge or controller.task
        self.delay_steps, self.record_every, self.delay_compensation = delay_steps, record_every, delay_compensation
        self.viewer = viewer
        safety = controller.config.safety_config
        self.cascade = inner_cascade(low_level, controller.inner_filter, controller.tank, safety)
        self.chunks = TraceChunks("cost", "phase")
        self.plans = PlanRecorder(scene) if record_plans else None
        self.kept_samples = controller.keep_samples
        if self.plans is not None:
            controller.keep_samples = True  # the recorder draws the heaviest sampled rollouts
        self.planning_times: list[float] = []
        self.success_time: float | None = None
        self.running: PlanSnapshot | None = None  # the plan the cascade follows until the next takes over

    def run(
        self,
        total_steps: int,
        steps_per_plan: int,
        on_replan: Callable[[float, np.ndarray, PlantInterface, Controller], None] | None,
        stop_on_success: bool,
        settle_time: float,
        bar: Any,
    ) -> Episode:
        """Re-plans every ``steps_per_plan`` plant steps and follows each plan until ``total_steps``, ``on_replan``
        returning True, or ``settle_time`` s after success; returns the episode."""
        plant = self.plant
        wall = time.perf_counter()
        try:
            done = 0
            while done < total_steps:
                steps = min(steps_per_plan, total_steps - done)  # the last plan is cut at the duration
                done += steps
                x = plant.state
                t = plant.time
                if on_replan is not None and on_replan(t, x, plant, self.controller) is True:
                    break
                x = self.seen(x, t)
                self.follow(self.replan(x, t), steps)
                self.record(x, t)
                if bar is not None:
                    bar.update(round(steps * plant.dt, 3))
                self.note_success()
                if stop_on_success and self.success_time is not None and plant.time >= self.success_time + settle_time:
                    break
        finally:
            self.controller.keep_samples = self.kept_samples
            if bar is not None:
                bar.close()
        return self.episode(time.perf_counter() - wall)

    def seen(self, x: np.ndarray, t: float) -> np.ndarray:
        """The state the controller plans from: the plant's, or with an estimated object the robot's
        joints and the object along the estimate (the controller switched to a rebuilt scene first)."""
        estimated = self.estimated
        if estimated is None:
            return x
        scene = estimated.refresh(t)
        if scene is not None:
            self.controller.set_scene(scene)
        nq = self.scene.nq
        if estimated.hook_pulls and self.controller.phase == SEATING_PHASE:
            # the pull begins where the hand holds the handle now
            self.controller.set_phase("open", t)
            estimated.observe([t], x[None, :nq], None, "open")
        return estimated.state(x[:nq], x[nq : 2 * nq])

    def replan(self, x: np.ndarray, t: float) -> PlanSnapshot:
        """One planning iteration from the plant's state x at time t, or, with a compensated delay, from the
        state the controller predicts for when the plan takes over."""
        controller = self.controller
        if self.delay_steps and self.delay_compensation:
            stats = controller.update(*controller.predict(x, t, self.delay_steps * self.plant.dt), observed=x)
        else:
            stats = controller.update(x, t)
        self.planning_times.append(stats.iteration_time)
        return controller.snapshot()

    def follow(self, plan: PlanSnapshot, steps: int) -> None:
        """``steps`` plant steps of the cascade: the running plan for the delay, then ``plan``, which is handed
        over to take over once the delay has passed (at once without one)."""
        delayed = min(self.delay_steps, steps)
        at = self.plant.time + delayed * self.plant.dt if delayed else None
        self.cascade.plan_at(self.plant.time)  # a plan handed over for now takes over before the next waits
        self.cascade.hand_over(plan.plan, at)
        for segment, count in ((self.running or plan, delayed), (plan, steps - delayed)):
            if count == 0:
                continue
            trace = follow_plant(self.cascade, self.plant, count, self.record_every)
            self.chunks.append(trace, cost=segment.nominal_cost, phase=self.controller.task.phases.index(segment.phase))
            if self.estimated is not None and len(trace.time):
                nq = self.scene.nq
                self.estimated.observe(trace.time, trace.state[:, :nq], trace.wrench, segment.phase)
        self.running = plan

    def record(self, x: np.ndarray, t: float) -> None:
        """Records the plan made from x at time t with the plant's contacts now, and shows it in the viewer."""
        if self.plans is None:
            return
        _record_plan(self.plans, self.controller, x, t, self.plant)
        if self.viewer is not None:
            controller = self.controller
            self.viewer.show_live(
                self.plant.state,
                self.plant.time,
                self.plans.latest(),
                phase=controller.phase,
                tank_energy=controller.tank.energy,
                safety=controller.config.safety_config,
            )

    def note_success(self) -> None:
        """Notes the time the task first succeeds."""
        if self.success_time is None and self.judge.success(self.scene, self.plant.state):
            self.success_time = self.plant.time

    def episode(self, wall_time: float) -> Episode:
        """The recorded traces as an :class:`Episode`, ``wall_time`` s after the start."""
        data = self.chunks.arrays()
        controller = self.controller
        target_opening, success_opening = _opening_targets(self.scene, self.judge)
        return Episode(
            scene=self.scene,
            time=data["time"],
            state=data["state"],
            reference=data["reference"],
            wrench=data["wrench"],
            tau_ext=data["tau_ext"],
            tau_ext_measured=data["tau_ext_measured"],
            contact=data["contact"].astype(bool),
            cost=data["cost"],
            phase=data["phase"].astype(int),
            phases=tuple(controller.task.phases),
            success=self.success_time is not None,
            time_to_success=self.success_time,
            planning_times=np.asarray(self.planning_times),
            wall_time=wall_time,
            command=data["command"],
            tank_energy=data["tank"],
            variant=controller.config.variant,
            filter_fallbacks=0 if controller.inner_filter is None else int(controller.inner_filter.stats.fallbacks),
            tank_floor=controller.tank.floor,
            target_opening=target_opening,
            success_opening=success_opening,
            **({} if self.plans is None else self.plans.arrays()),
        )


def _record_plan(plans: PlanRecorder, controller: Controller, x: np.ndarray, t: float, plant: PlantInterface) -> None:
    """Hands ``plans`` the controller's latest plan, made from x at time t: the nominal's rollout in the
    controller's model, the sampled rollouts it kept with their weights (55), the filters' sphere obstacles, and
    the plant's contacts now."""
    nominal = np.ascontiguousarray(controller.nominal)[None]
    states = controller.model.rollout(x, nominal, threads=1).states[0]
    sample_states, weights = None, None
    if controller.last_samples is not None:
        sample_states, costs = controller.last_samples
        weights = likelihood_weights(costs, "invariant", controller.config.h)
    filters = controller.filters
    spheres = filters[0].obstacles if filters else []
    contacts = plant.contacts()
    plans.append(
        t,
        states,
        np.array([c.point for c in contacts]).reshape(-1, 3),
        np.array([c.force for c in contacts]).reshape(-1, 3),
        sample_states=sample_states,
        sample_weights=weights,
        obstacles=np.array([[*o.center, o.radius] for o in spheres]).reshape(-1, 4),
    )


def _opening_targets(scene: Scene, task: Task) -> tuple[float | None, float | None]:
    """(target opening, opening that counts as success) of an OpenObject task, else (None, None)."""
    if not isinstance(task, OpenObject):
        return None, None
    target = task.target_opening(scene)
    return target, task.open.success_fraction * target
