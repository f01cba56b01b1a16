"""The paper's evaluation scenarios (Sec. VI-A) as functions returning small frozen results.

- :func:`stuck_door`: hooked on the shelf handle, the door is held fixed while the robot pulls,
  then released (Fig. 11, 13).
- :func:`tank_chattering`: the stuck door with the passivity rate α of (56) (Fig. 12).
- :func:`obstacle_corridor`: target reaching with the base in a narrow corridor and a sphere
  obstacle that appears when the hand comes within 1 cm of it (Fig. 9, 10).
- :func:`object_manipulation`: reach the handle from the paper's start and open (Fig. 8).

Every function is deterministic for its ``seed`` and takes the controller ``variant``, and runs on the
plant ``plant(scene)`` builds (a :class:`~sabre.PlantInterface`; default: :class:`~sabre.Plant`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from .. import costs, tasks
from ..closed_loop import paper_start_state, run_episode
from ..episode import Episode, TraceChunks
from ..errors import InvalidValueError
from ..inner_loop import LowLevelController
from ..planner import Controller, ControllerConfig
from ..plants import PlantInterface, as_plant
from ..safety import EnergyTank, SafetyConfig, SafetyFilter
from ..scene import ROBOTS, Scene
from ..scripted import hook_and_pull
from ..sim import Plant

#: Builds the plant of a scene (a :class:`~sabre.PlantInterface`, e.g. a class taking the scene).
PlantFactory = Callable[[Scene], PlantInterface]

__all__ = [
    "StuckDoorResult",
    "ChatteringResult",
    "CorridorResult",
    "ManipulationResult",
    "hooked_state",
    "stuck_door",
    "tank_chattering",
    "obstacle_corridor",
    "object_manipulation",
    "manipulation_scene",
    "power_sign_changes_per_s",
    "tank_power",
    "FloorPower",
    "power_near_floor",
]


# -- helpers -----------------------------------------------------------------------------------
def _plant(scene: Scene, plant: PlantFactory | None) -> PlantInterface:
    """The plant ``plant`` builds for ``scene``, checked; a :class:`~sabre.Plant` without a factory."""
    return Plant(scene) if plant is None else as_plant(plant(scene), scene)


def hooked_state(scene: Scene, engage: float = 0.6, plant: PlantFactory | None = None) -> np.ndarray:
    """Plays :func:`~sabre.scripted.hook_and_pull` on the plant from the default state through the
    approach, insert and hook and ``engage`` s into the pull (tip against the bar), then zeroes
    the robot's velocities. Returns the state (nx,)."""
    motion = hook_and_pull(scene, scene.default_state())
    driven = _plant(scene, plant)
    low = LowLevelController(scene, dt=driven.dt)
    driven.reset(scene.default_state())
    per = int(round(motion.dt / driven.dt))
    n = int(np.argmax(motion.phases == 3)) + int(round(engage / motion.dt))
    for u in motion.U[:n]:
        low.track(driven, u, steps=per)
    x = np.array(driven.state, dtype=np.float64)  # a copy: the velocities are zeroed below
    scene.split_state(x).q_dot[:] = 0.0
    return x


def tank_power(episode: Episode) -> np.ndarray:
    """(M,) the power τ̂ᵀu the energy tank integrated in each recorded step: the command tracked in
    the step against the τ_ext measurement from before it (the previous row's
    ``tau_ext_measured``; zero before the first). Needs every step recorded (``record_every=1``)."""
    u = episode.reference if episode.command is None else episode.command
    tau = episode.tau_ext if episode.tau_ext_measured is None else episode.tau_ext_measured
    before = np.vstack([np.zeros((1, tau.shape[1])), tau[:-1]]) if len(tau) else tau
    return np.einsum("ij,ij->i", before, u)


def power_sign_changes_per_s(episode: Episode, mask: np.ndarray, near: float = 0.5, deadband: float = 0.01) -> float:
    """Sign changes per second of the filtered power τ̂ᵀu (:func:`tank_power`) over the samples in
    ``mask`` whose tank energy is within ``near`` J of the floor (consecutive such samples only).
    Power within ``deadband`` W of zero has no sign: at the floor the row holds τ̂ᵀu near 0 and its
    µW-scale solver residue flips sign at random, which is not the chattering of Fig. 12."""
    p = tank_power(episode)
    p = np.where(np.abs(p) > deadband, p, 0.0)
    if episode.tank_energy is None or len(episode.tank_energy) != len(p):
        return 0.0
    sel = mask & (episode.tank_energy - episode.tank_floor < near)
    if sel.sum() < 2:
        return 0.0
    dt = float(np.median(np.diff(episode.time))) if len(episode.time) > 1 else 1e-3
    s = np.sign(p)
    pairs = sel[1:] & sel[:-1] & (s[1:] != 0) & (s[:-1] != 0)
    changes = int(np.count_nonzero(pairs & (s[1:] != s[:-1])))
    return float(changes / (sel.sum() * dt))


@dataclass(frozen=True)
class FloorPower:
    """How the tank's power behaves near its floor (Fig. 12): over the samples of a mask whose tank
    energy is within ``near`` J of the floor. The passivity row bounds the dissipation there by
    α·(S − ε), so with α = 1 it fades out smoothly, while α = 1/dt still lets through bursts of
    high power that stop dead at the floor: the chattering the paper describes.

    seconds: time spent near the floor; peak_dissipation: largest −τ̂ᵀu (W);
    variation_per_s: total variation of τ̂ᵀu per second (W/s), how hard the power jumps;
    sign_changes_per_s: :func:`power_sign_changes_per_s` over the same samples.
    """

    seconds: float
    peak_dissipation: float
    variation_per_s: float
    sign_changes_per_s: float


def power_near_floor(episode: Episode, mask: np.ndarray, near: float = 0.5) -> FloorPower:
    """:class:`FloorPower` of an episode recorded at every step, over ``mask`` (M,)."""
    p = tank_power(episode)
    if episode.tank_energy is None or len(episode.tank_energy) != len(p):
        return FloorPower(0.0, 0.0, 0.0, 0.0)
    dt = float(np.median(np.diff(episode.time))) if len(episode.time) > 1 else 1e-3
    sel = mask & (episode.tank_energy - episode.tank_floor < near)
    pairs = sel[1:] & sel[:-1]
    return FloorPower(
        seconds=float(sel.sum() * dt),
        peak_dissipation=float(max(0.0, (-p[sel]).max())) if sel.any() else 0.0,
        variation_per_s=float(np.abs(np.diff(p))[pairs].sum() / (pairs.sum() * dt)) if pairs.any() else 0.0,
        sign_changes_per_s=power_sign_changes_per_s(episode, mask, near=near),
    )


def _scripted_episode(scene, variant, safety, x0, hold_seconds, release_seconds, tank_initial, plant=None):
    """Scripted pull (the rest of hook_and_pull's pull phase) as the outer-loop reference through
    the inner loop of `variant` (filter + tank for I/IO), door held for hold_seconds."""
    motion = hook_and_pull(scene, scene.default_state())
    start = int(np.argmax(motion.phases == 3))
    U = np.asarray(motion.U[start:], dtype=float)
    plant = _plant(scene, plant)
    low = LowLevelController(scene, dt=plant.dt)
    plant.reset(x0)
    low.reset()
    inner = SafetyFilter(scene, safety) if "I" in variant else None
    tank = EnergyTank(tank_initial, safety.tank_floor)
    chunks = TraceChunks()
    total = hold_seconds + release_seconds
    t = 0.0
    chunk = 0.05
    while t < total - 1e-9:
        plant.hold_object(t < hold_seconds - 1e-9)
        chunks.append(low.follow(plant, U, 0.0, motion.dt, int(round(chunk / plant.dt)), 1, safety=inner, tank=tank))
        t = plant.time
    d = chunks.arrays()
    return Episode(
        scene=scene,
        time=d["time"],
        state=d["state"],
        reference=d["reference"],
        wrench=d["wrench"],
        tau_ext=d["tau_ext"],
        tau_ext_measured=d["tau_ext_measured"],
        contact=d["contact"].astype(bool),
        cost=np.zeros(len(d["time"])),
        phase=np.zeros(len(d["time"]), dtype=int),
        phases=("pull",),
        success=False,
        time_to_success=None,
        command=d["command"],
        tank_energy=d["tank"],
        variant=variant,
        filter_fallbacks=0 if inner is None else int(inner.stats.fallbacks),
        tank_floor=tank.floor,
    )


# -- stuck door --------------------------------------------------------------------------------
@dataclass(frozen=True)
class StuckDoorResult:
    episode: Episode = field(repr=False)
    variant: str
    driver: str
    hold_seconds: float
    #: whether the door reached ``hold_at`` within ``reach_timeout`` and was held; if not,
    #: hold_start is the episode's end and the stuck-period numbers are NaN (wrench, opening after
    #: release) or empty (power statistics)
    held: bool
    #: simulated time (s) at which the hold began
    hold_start: float
    mean_wrench_stuck: float
    tank_energy: np.ndarray = field(repr=False)
    tank_floor: float
    tank_min: float
    opening_after_release: float
    power_sign_changes_per_s: float
    #: the power near the tank floor (within 0.5 J) during the stuck period
    floor_power: FloorPower


def stuck_door(
    variant: str = "IO",
    seed: int = 0,
    hold_seconds: float = 5.0,
    release_seconds: float = 10.0,
    obj: str = "shelf",
    alpha: float = 1.0,
    *,
    driver: str = "controller",
    replan_rate: float = 50.0,
    tank_initial: float = 10.0,
    reach_timeout: float = 40.0,
    hold_at: float = 0.2,
    plant: PlantFactory | None = None,
) -> StuckDoorResult:
    """The door is held for hold_seconds while the robot pulls on it, then released.

    driver "controller" (the paper's experiment): the sampling-based controller opens the object
    from the paper's start (``OpenObject``, Table I defaults, slip recovery on); the door is held
    where it is once the robot has opened it to the prescribed position ``hold_at`` (rad or m from
    its closed limit, in whichever phase: the hand sometimes drags the door while it still settles
    the bar in the hook), within ``reach_timeout`` s, for ``hold_seconds``, then runs free for
    ``release_seconds``. The stuck period (for ``mean_wrench_stuck``) is the hold window.
    driver "scripted": hooked by the scripted motion, the rest of the scripted pull is the
    outer-loop reference (deterministic, always loads the held door), through the inner loop of
    ``variant``; the hold starts at once.
    """
    scene = Scene.load(obj=obj)
    safety = SafetyConfig(passivity_alpha=alpha)
    if not (np.isfinite(hold_at) and 0.0 < hold_at < scene.o_upper[0] - scene.o_lower[0]):
        raise InvalidValueError(f"hold_at must lie inside the object's range, got {hold_at}")
    if driver == "scripted":
        x0 = hooked_state(scene, plant=plant)
        ep = _scripted_episode(scene, variant, safety, x0, hold_seconds, release_seconds, tank_initial, plant)
        hold_start, was_held = 0.0, True
    elif driver == "controller":
        task = tasks.OpenObject()
        ctrl = Controller(scene, task, ControllerConfig(variant=variant, safety=safety, seed=seed, tank_initial=tank_initial))
        schedule = _DoorHold(hold_at, reach_timeout, hold_seconds, release_seconds)

        def hold(t, x, plant, controller):
            holding, done = schedule.update(t, float(scene.split_state(x).o[0] - scene.o_lower[0]))
            plant.hold_object(holding)
            return done

        ep = run_episode(
            scene,
            ctrl,
            schedule.duration,
            seed=seed,
            replan_rate=replan_rate,
            record_every=1,
            stop_on_success=False,
            progress=False,
            on_replan=hold,
            plant=None if plant is None else plant(scene),
        )
        was_held = schedule.start is not None
        hold_start = schedule.start if schedule.start is not None else float(ep.time[-1])
    else:
        raise InvalidValueError(f"driver must be 'controller' or 'scripted', got {driver!r}")
    stuck = (ep.time >= hold_start - 1e-9) & (ep.time <= hold_start + hold_seconds + 1e-9) & was_held
    norms = np.linalg.norm(ep.wrench[:, :3], axis=1)
    i_rel = int(np.nonzero(stuck)[0][-1]) if stuck.any() else len(ep.time) - 1
    return StuckDoorResult(
        episode=ep,
        variant=variant,
        driver=driver,
        hold_seconds=hold_seconds,
        held=was_held,
        hold_start=float(hold_start),
        mean_wrench_stuck=float(norms[stuck].mean()) if stuck.any() else float("nan"),
        tank_energy=np.asarray(ep.tank_energy),
        tank_floor=float(ep.tank_floor),
        tank_min=float(np.min(ep.tank_energy)),
        opening_after_release=float(ep.opening[-1] - ep.opening[i_rel]) if was_held else float("nan"),
        power_sign_changes_per_s=power_sign_changes_per_s(ep, stuck),
        floor_power=power_near_floor(ep, stuck),
    )


@dataclass
class _DoorHold:
    """When the stuck door is held: from the first time the object is ``hold_at`` from closed, if
    that comes within ``reach_timeout`` s, for ``hold_seconds``; the episode then runs
    ``release_seconds`` more and ends. Holds that would start later never start, so every release
    runs in full within ``duration``."""

    hold_at: float
    reach_timeout: float
    hold_seconds: float
    release_seconds: float
    start: float | None = None

    @property
    def duration(self) -> float:
        return self.reach_timeout + self.hold_seconds + self.release_seconds

    def update(self, t: float, opening: float) -> tuple[bool, bool]:
        """(whether the object is held now, whether the episode is over) at time t."""
        if self.start is None and t <= self.reach_timeout + 1e-9 and opening >= self.hold_at:
            self.start = t
        if self.start is None:
            return False, False
        return t < self.start + self.hold_seconds - 1e-9, t >= self.start + self.hold_seconds + self.release_seconds - 1e-9


@dataclass(frozen=True)
class ChatteringResult:
    episode: Episode = field(repr=False)
    alpha: float
    power_sign_changes_per_s: float
    tank_min: float
    floor_power: FloorPower


def tank_chattering(
    alpha: float,
    seed: int = 0,
    hold_seconds: float = 5.0,
    release_seconds: float = 0.5,
    *,
    driver: str = "controller",
    obj: str = "shelf",
    tank_initial: float = 10.0,
    plant: PlantFactory | None = None,
) -> ChatteringResult:
    """The stuck door with variant IO and passivity rate α; α = 1000 should chatter at the floor.
    A ``tank_initial`` just above the floor (2 J) reaches it sooner."""
    r = stuck_door("IO", seed, hold_seconds, release_seconds, obj, alpha, driver=driver, tank_initial=tank_initial, plant=plant)
    return ChatteringResult(
        episode=r.episode,
        alpha=float(alpha),
        power_sign_changes_per_s=r.power_sign_changes_per_s,
        tank_min=r.tank_min,
        floor_power=r.floor_power,
    )


# -- obstacle corridor -------------------------------------------------------------------------
@dataclass
class _CorridorReach(tasks.Reach):
    """Reach with two phases whose costs differ: "obstacle" adds the sphere obstacle term."""

    obstacle_center: tuple[float, float, float] = (0.0, 0.0, 0.0)
    obstacle_radius: float = 0.1

    phases = ("free", "obstacle")

    def cost(self, scene: Scene, phase: str) -> costs.Cost:
        base = super().cost(scene, phase)
        if phase == "obstacle":
            base = base + costs.Obstacles([self.obstacle_center], [self.obstacle_radius], weight=1000.0, weight_slope=1000.0)
        return base


@dataclass(frozen=True)
class CorridorResult:
    episode: Episode = field(repr=False)
    variant: str
    appeared_at: float | None
    cartesian_violation: float
    reached: bool


#: corridor for the base: x ∈ [−0.5, 0.5] m, y ∈ [−0.1, 0.1] m.
CORRIDOR = (-0.5, 0.5, -0.1, 0.1)


def obstacle_corridor(
    variant: str = "IO",
    seed: int = 0,
    duration: float = 6.0,
    *,
    replan_rate: float = 20.0,
    obstacle_radius: float = 0.08,
    plant: PlantFactory | None = None,
) -> CorridorResult:
    """Reach a grasp target 0.5 m to the side with the base confined to :data:`CORRIDOR`; a sphere
    obstacle sits half-way on the straight path and appears (filters + sampler cost) when the grasp
    frame comes within 1 cm of its surface. cartesian_violation: Σ_k max(0, −h) over the obstacle
    and base-box rows from the appearance on (m² for obstacle rows, m for the box)."""
    scene = Scene.load(obj="shelf")
    x0 = scene.default_state()
    hand = scene.require_tool_frame("obstacle_corridor")
    start = scene.fk(scene.split_state(x0).q, hand)
    target = start.copy()
    target[:3, 3] = start[:3, 3] + np.array([-0.15, 0.5, 0.0])
    center = 0.5 * (start[:3, 3] + target[:3, 3])
    box = CORRIDOR
    task = _CorridorReach(
        target_pose=target,
        extra=costs.Cost([costs.BaseBox((box[0], box[2]), (box[1], box[3]))]),
        obstacle_center=tuple(center),
        obstacle_radius=obstacle_radius,
    )
    safety = SafetyConfig(base_box=box)
    ctrl = Controller(scene, task, ControllerConfig(variant=variant, safety=safety, seed=seed))
    appeared: list[float] = []

    def appear(t, x, plant, controller):
        if appeared:
            return
        p = scene.fk(scene.split_state(x).q, hand)[:3, 3]
        if np.linalg.norm(p - center) - obstacle_radius <= 0.01:
            appeared.append(t)
            controller.add_obstacle(center, obstacle_radius)
            controller.set_phase("obstacle", t)

    ep = run_episode(
        scene,
        ctrl,
        duration,
        seed=seed,
        x0=x0,
        replan_rate=replan_rate,
        record_every=10,
        stop_on_success=False,
        progress=False,
        on_replan=appear,
        plant=None if plant is None else plant(scene),
    )
    t_app = appeared[0] if appeared else None
    check = SafetyFilter(scene, safety)
    check.add_obstacle(center, obstacle_radius)
    rows = np.array([n.startswith(("obstacle", "base_box")) for n in check.row_names])
    violation = 0.0
    if t_app is not None:
        for x in ep.state[ep.time >= t_app]:
            h = np.asarray(check.constraint_rows(x).h)[rows]
            h = h[np.isfinite(h)]
            violation += float(np.sum(np.maximum(0.0, -h)))
    reached = bool(any(task.success(scene, x) for x in ep.state))
    return CorridorResult(episode=ep, variant=variant, appeared_at=t_app, cartesian_violation=violation, reached=reached)


# -- object manipulation -----------------------------------------------------------------------
def manipulation_scene(robot: str, obj: str) -> Scene:
    """The scene of ``robot`` (built-in or example) opening built-in object ``obj``."""
    if robot in ROBOTS:
        return Scene.load(robot, obj)
    from ..robot_examples import example_scene

    return example_scene(robot, obj)


@dataclass(frozen=True)
class ManipulationResult:
    episode: Episode = field(repr=False)
    variant: str
    obj: str
    success: bool
    violations: dict


def object_manipulation(
    variant: str = "IO",
    obj: str = "shelf",
    seed: int = 0,
    duration: float = 60.0,
    *,
    replan_rate: float = 50.0,
    plant: PlantFactory | None = None,
    robot: str = "royalpanda",
    rollouts: int | None = None,
) -> ManipulationResult:
    """OpenObject from :func:`~sabre.closed_loop.paper_start_state`; violations per ZBF class. ``robot``:
    a built-in robot (:data:`sabre.ROBOTS`) or an example robot
    (:data:`sabre.robot_examples.EXAMPLE_ROBOTS`, with its objects where it opens them); ``rollouts``:
    the samples per iteration (None: the controller's default)."""
    scene = manipulation_scene(robot, obj)
    if rollouts is None:
        config = ControllerConfig(variant=variant, seed=seed)
    else:
        config = ControllerConfig(variant=variant, seed=seed, rollouts=rollouts)
    ctrl = Controller(scene, tasks.OpenObject(), config)
    ep = run_episode(
        scene,
        ctrl,
        duration,
        seed=seed,
        x0=paper_start_state(scene),
        replan_rate=replan_rate,
        record_every=10,
        progress=False,
        plant=None if plant is None else plant(scene),
    )
    return ManipulationResult(episode=ep, variant=variant, obj=obj, success=bool(ep.success), violations=ep.violations())
