"""Closed-loop episodes: the :class:`Episode` traces, the recorders that gather them during a run
(:class:`TraceChunks`, :class:`PlanRecorder`), and the episode file (one ``.npz``: arrays plus a JSON header)."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING

import numpy as np

from . import _core
from .errors import InvalidValueError, UnknownAssetError
from .poses import pose_to_xyz_rpy
from .safety import CLASSES, SafetyConfig, SafetyFilter
from .scene import OBJECTS, ROBOTS, Scene

if TYPE_CHECKING:
    from .inner_loop import Trace

__all__ = [
    "Episode",
    "RecordedPlan",
    "TraceChunks",
    "PlanRecorder",
    "save_episode",
    "load_episode",
    "pose_to_xyz_rpy",
    "hand_contact_forces",
    "contact_force_stats",
]

#: The tank's floor ε (J) an episode reports when the run did not say (the core's default).
_TANK_FLOOR = _core.SafetyConfig().tank_floor


def hand_contact_forces(wrench: np.ndarray, contact: np.ndarray) -> np.ndarray:
    """The hand's contact force (N) at each plant step in contact: |f| of the wrist wrench's force
    (the first three columns of ``wrench``, (N, 6) as :attr:`sabre.PlantInterface.wrench` reads, or
    the force alone, (N, 3)) at the steps where a robot–object contact carried force (``contact``,
    (N,)); steps without contact are left out. The one definition :attr:`Episode.hand_contact_forces`
    and the simulated robot's summary report."""
    w = np.atleast_2d(np.asarray(wrench, dtype=np.float64))
    touching = np.asarray(contact, dtype=bool).reshape(-1)
    if w.ndim != 2 or w.shape[1] < 3 or len(touching) != len(w):
        raise InvalidValueError(f"wrench must be (N, 6) or (N, 3) with N = len(contact) = {len(touching)}, got {w.shape}")
    return np.linalg.norm(w[touching, :3], axis=1)


def contact_force_stats(forces: np.ndarray) -> dict[str, float]:
    """Mean, 99th percentile and maximum (N) of per-step contact forces (:func:`hand_contact_forces`)
    and how many steps they cover; NaN statistics for none."""
    f = np.asarray(forces, dtype=np.float64).reshape(-1)
    if len(f) == 0:
        return {"mean": float("nan"), "p99": float("nan"), "max": float("nan"), "steps": 0}
    return {"mean": float(f.mean()), "p99": float(np.percentile(f, 99)), "max": float(f.max()), "steps": len(f)}


@dataclass
class Episode:
    """Traces of a closed-loop run, one row per recorded plant step.

    time (M,), state (M, nx), reference (M, nu) the interpolated outer-loop reference, command
    (M, nu) what the low-level controller tracked (the reference after the inner filter, if any),
    wrench (M, 6), tau_ext (M, nq), contact (M,), cost (M,) nominal cost of the latest plan, phase
    (M,) phase index into ``phases``, tank_energy (M,) the energy tank after each step (J),
    tau_ext_measured (M, nq) the plant's τ_ext measurement after each step (what the tank and the
    passivity row read; ``tau_ext`` is the contact torque of the step itself),
    filter_fallbacks: inner-loop steps where the FILTER-QP fell back to the safe stop.
    tank_floor: the tank's floor ε (J). target_opening, success_opening: the task's target opening
    and the opening that counts as success (rad or m), None for a task that is not an
    :class:`~sabre.tasks.OpenObject`.
    With ``run_episode(..., record_plans=True)``, one row per re-plan: plan_time (P,), plan_hand_path
    (P, K + 1, 3) the grasp frame along the nominal plan's rollout, sample_hand_paths (P, S, K + 1, 3)
    and sample_weights (P, S) along the S heaviest sampled rollouts, obstacles (P, O, 4) the
    filters' sphere obstacles (centre, radius; NaN rows pad to O), contact_points and contact_forces
    (P, C, 3) the plant's robot–object contacts after the plan's inner loop (NaN rows pad to C).
    """

    scene: Scene
    time: np.ndarray
    state: np.ndarray
    reference: np.ndarray
    wrench: np.ndarray
    tau_ext: np.ndarray
    contact: np.ndarray
    cost: np.ndarray
    phase: np.ndarray
    phases: tuple[str, ...]
    success: bool
    time_to_success: float | None
    planning_times: np.ndarray = field(default_factory=lambda: np.zeros(0))
    wall_time: float = 0.0
    command: np.ndarray | None = None
    tank_energy: np.ndarray | None = None
    variant: str = "N"
    filter_fallbacks: int = 0
    tank_floor: float = _TANK_FLOOR
    tau_ext_measured: np.ndarray | None = None
    target_opening: float | None = None
    success_opening: float | None = None
    plan_time: np.ndarray | None = None
    plan_hand_path: np.ndarray | None = None
    sample_hand_paths: np.ndarray | None = None
    sample_weights: np.ndarray | None = None
    obstacles: np.ndarray | None = None
    contact_points: np.ndarray | None = None
    contact_forces: np.ndarray | None = None

    def save(self, path: str | os.PathLike[str]) -> None:
        """Writes the episode to an ``.npz`` file that :meth:`load` reads back (built-in scenes only)."""
        save_episode(self, path)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Episode:
        """Reads an episode written by :meth:`save`; the scene is rebuilt from its built-in assets."""
        return load_episode(path)

    def plan_at(self, t: float) -> RecordedPlan | None:
        """The recorded plan running at time t (s): the last one made at or before t (the first one for an
        earlier t); None without recorded plans (``run_episode(..., record_plans=True)``)."""
        if self.plan_time is None or len(self.plan_time) == 0 or self.plan_hand_path is None:
            return None
        j = int(np.clip(np.searchsorted(self.plan_time, t, side="right") - 1, 0, len(self.plan_time) - 1))
        no_contacts = np.zeros((0, 3))
        return RecordedPlan(
            time=float(self.plan_time[j]),
            hand_path=self.plan_hand_path[j],
            sample_hand_paths=None if self.sample_hand_paths is None else self.sample_hand_paths[j],
            sample_weights=None if self.sample_weights is None else self.sample_weights[j],
            obstacles=np.zeros((0, 4)) if self.obstacles is None else self.obstacles[j],
            contact_points=no_contacts if self.contact_points is None else self.contact_points[j],
            contact_forces=no_contacts if self.contact_forces is None else self.contact_forces[j],
        )

    @property
    def opening(self) -> np.ndarray:
        """(M,) the object's opening (rad or m)."""
        return self.scene.split_state(self.state).o[:, 0]

    @property
    def duration(self) -> float:
        """Simulated time of the last recorded step (s)."""
        return float(self.time[-1]) if len(self.time) else 0.0

    @property
    def real_time_factor(self) -> float:
        """Simulated over wall time (above 1: faster than real time)."""
        return self.duration / self.wall_time if self.wall_time > 0 else float("inf")

    def mean_wrench(self, only_contact: bool = True) -> float:
        """Mean wrist force |f| (N), over the steps in contact (all steps if none, or with ``only_contact=False``)."""
        mask = self.contact if only_contact and self.contact.any() else np.ones_like(self.contact)
        return float(hand_contact_forces(self.wrench, mask).mean()) if mask.any() else 0.0

    @property
    def hand_contact_forces(self) -> np.ndarray:
        """The hand's contact force (N) at each recorded step in contact (:func:`hand_contact_forces`);
        every plant step with ``run_episode(..., record_every=1)``."""
        return hand_contact_forces(self.wrench, self.contact)

    def dissipated_energy(self) -> float:
        """Σ −uᵀ τ_ext dt over the episode (58) with u the tracked command, J."""
        u = self.reference if self.command is None else self.command
        dt = np.diff(self.time, prepend=0.0)
        return float(np.sum(-np.einsum("ij,ij->i", u, self.tau_ext) * dt))

    def violations(self, config: SafetyConfig | None = None) -> dict[str, float]:
        """Cumulative constraint violation per ZBF class, Δ_tot = Σ_k max(0, −h(x_k)) over the
        recorded states (the metric of the paper's Fig. 8), with the rows of a filter built from ``config`` (default
        settings: the paper's base box)."""
        f = SafetyFilter(self.scene, config)
        names = f.row_names
        classes = [n.split(":")[0] for n in names]
        key = {
            "joint_limit": "joint_limits",
            "self_collision": "self_collision",
            "arm_reach": "arm_reach",
            "base_box": "base_box",
            "obstacle": "obstacles",
            "passivity": "passivity",
        }
        total = {c: 0.0 for c in CLASSES if c != "passivity"}
        for x in self.state:
            h = f.constraint_rows(x).h
            for c, v in zip(classes, h):
                if np.isfinite(v) and v < 0.0 and key.get(c) in total:
                    total[key[c]] += -float(v)
        return total


class TraceChunks:
    """The plant traces of consecutive inner-loop runs (:meth:`LowLevelController.follow`), gathered into the
    arrays of one :class:`Episode`. ``append(trace, **per_run)`` adds a run; each keyword is a value
    that holds for every recorded step of that run (e.g. the plan's cost)."""

    FIELDS = ("time", "state", "reference", "command", "tank", "wrench", "tau_ext", "tau_ext_measured", "contact")

    def __init__(self, *per_run: str) -> None:
        self._parts: dict[str, list[np.ndarray]] = {k: [] for k in self.FIELDS + per_run}

    def append(self, trace: Trace, **per_run: float) -> None:
        p = self._parts
        p["time"].append(trace.time)
        p["state"].append(trace.state)
        p["reference"].append(trace.reference)
        p["command"].append(trace.reference if trace.filtered is None else trace.filtered)
        if trace.tank_energy is not None:
            p["tank"].append(trace.tank_energy)
        p["wrench"].append(trace.wrench)
        p["tau_ext"].append(trace.tau_ext)
        p["tau_ext_measured"].append(trace.tau_ext_measured)
        p["contact"].append(trace.contact)
        for k, v in per_run.items():
            p[k].append(np.full(len(trace.time), v))

    def arrays(self) -> dict[str, np.ndarray]:
        return {k: np.concatenate(v) if v else np.zeros(0) for k, v in self._parts.items()}


@dataclass(frozen=True)
class RecordedPlan:
    """One re-plan of a run, as :meth:`PlanRecorder.latest` and :meth:`Episode.plan_at` give it.

    Attributes:
        time: when the plan was made (s).
        hand_path: (K + 1, 3) the grasp frame's position along the nominal plan's rollout (m).
        sample_hand_paths: (S, K + 1, 3) the same along the S heaviest sampled rollouts, heaviest first;
            None when the run kept no samples.
        sample_weights: (S,) their weights (55); None with ``sample_hand_paths``.
        obstacles: (O, 4) the filters' sphere obstacles: centre (m), radius (m).
        contact_points: (C, 3) the plant's robot–object contact points after the plan's inner loop (m).
        contact_forces: (C, 3) the force on the robot at each of those points (N).

    An :class:`Episode` pads ``obstacles`` and the contacts with rows of NaN to a common count.
    """

    time: float
    hand_path: np.ndarray
    sample_hand_paths: np.ndarray | None
    sample_weights: np.ndarray | None
    obstacles: np.ndarray
    contact_points: np.ndarray
    contact_forces: np.ndarray


class PlanRecorder:
    """Per re-plan, the plan arrays of an :class:`Episode` (``run_episode(..., record_plans=True)``): the grasp
    frame along the nominal plan's rollout and along the ``SAMPLES`` heaviest sampled rollouts with their
    weights (55), the filters' sphere obstacles and the plant's contacts. :meth:`latest` is the last plan,
    :meth:`arrays` all of them, padded, under the names of :class:`Episode`'s fields."""

    SAMPLES = 16

    def __init__(self, scene: Scene) -> None:
        self.scene = scene
        #: the frame whose path is recorded: the robot's tool frame where it has one, else its last frame
        self.frame = scene.tool_frame or scene.frame_names[-1]
        self._plans: list[RecordedPlan] = []

    def __len__(self) -> int:
        return len(self._plans)

    def _hand_path(self, states: np.ndarray) -> np.ndarray:
        return self.scene.fk_many(self.scene.split_state(states).q, self.frame)[..., :3, 3]

    def append(
        self,
        t: float,
        plan_states: np.ndarray,
        contact_points: np.ndarray,
        contact_forces: np.ndarray,
        *,
        sample_states: np.ndarray | None = None,
        sample_weights: np.ndarray | None = None,
        obstacles: np.ndarray | None = None,
    ) -> None:
        """Records the plan made at time t (s): plan_states (K + 1, nx) the nominal plan's rollout,
        contact_points and contact_forces (C, 3) the plant's contacts after the plan's inner loop,
        sample_states (N, K + 1, nx) the sampled rollouts with their weights (N,) (both or neither), and
        obstacles (O, 4) the filters' spheres (centre, radius)."""
        samples, weights = None, None
        if sample_states is not None and sample_weights is not None:
            best = np.argsort(-np.asarray(sample_weights))[: self.SAMPLES]
            samples = self._hand_path(np.asarray(sample_states)[best])
            weights = np.asarray(sample_weights, dtype=np.float64)[best]
        self._plans.append(
            RecordedPlan(
                time=float(t),
                hand_path=self._hand_path(np.asarray(plan_states)),
                sample_hand_paths=samples,
                sample_weights=weights,
                obstacles=np.zeros((0, 4)) if obstacles is None else np.asarray(obstacles, dtype=np.float64).reshape(-1, 4),
                contact_points=np.asarray(contact_points, dtype=np.float64).reshape(-1, 3),
                contact_forces=np.asarray(contact_forces, dtype=np.float64).reshape(-1, 3),
            )
        )

    def latest(self) -> RecordedPlan:
        """The last recorded plan. Raises InvalidValueError before the first :meth:`append`."""
        if not self._plans:
            raise InvalidValueError("PlanRecorder.latest: no plan recorded yet")
        return self._plans[-1]

    def arrays(self) -> dict[str, np.ndarray]:
        """The recorded plans as :class:`Episode` keeps them: plan_time (P,), plan_hand_path (P, K + 1, 3),
        obstacles (P, O, 4), contact_points and contact_forces (P, C, 3) padded with NaN rows, and, when every
        plan kept its samples, sample_hand_paths (P, S, K + 1, 3) and sample_weights (P, S)."""
        plans = self._plans

        def padded(rows: list[np.ndarray], columns: int) -> np.ndarray:
            out = np.full((len(rows), max([1] + [len(r) for r in rows]), columns), np.nan)
            for i, r in enumerate(rows):
                out[i, : len(r)] = r
            return out

        out = {}
        if plans and all(p.sample_hand_paths is not None for p in plans):
            out = {
                "sample_hand_paths": np.array([p.sample_hand_paths for p in plans]),
                "sample_weights": np.array([p.sample_weights for p in plans]),
            }
        out["obstacles"] = padded([p.obstacles for p in plans], 4)
        paths = np.array([p.hand_path for p in plans]) if plans else np.zeros((0, 0, 3))
        return {
            **out,
            "plan_time": np.array([p.time for p in plans]),
            "plan_hand_path": paths,
            "contact_points": padded([p.contact_points for p in plans], 3),
            "contact_forces": padded([p.contact_forces for p in plans], 3),
        }


# -- the episode file -----------------------------------------------------------------------------------------
_FORMAT = "sabre-episode/1"
_SCALARS = (
    "phases",
    "success",
    "time_to_success",
    "wall_time",
    "variant",
    "filter_fallbacks",
    "tank_floor",
    "target_opening",
    "success_opening",
)


def save_episode(episode: Episode, path: str | os.PathLike[str]) -> None:
    """Writes ``episode`` to ``path`` (``.npz``); only scenes built by :meth:`Scene.load` can be saved."""
    scene = episode.scene
    if scene.robot_name not in ROBOTS or scene.object_name not in OBJECTS:
        raise UnknownAssetError(
            f"Episode.save: scene {scene.robot_name}/{scene.object_name} is not built from "
            f"built-in assets; only those can be rebuilt on load"
        )
    header = {
        "format": _FORMAT,
        "robot": scene.robot_name,
        "object": scene.object_name,
        "object_pose": pose_to_xyz_rpy(scene.object_pose).tolist(),
    }
    for name in _SCALARS:
        value = getattr(episode, name)
        header[name] = list(value) if isinstance(value, tuple) else value
    arrays = {
        f.name: np.asarray(getattr(episode, f.name))
        for f in fields(episode)
        if f.name != "scene" and f.name not in _SCALARS and getattr(episode, f.name) is not None
    }
    arrays["header"] = np.array(json.dumps(header))
    np.savez_compressed(path, **arrays)  # type: ignore[arg-type]  # numpy's stub types **kwds as bool


def load_episode(path: str | os.PathLike[str]) -> Episode:
    """Reads an episode written by :func:`save_episode`."""
    with np.load(path, allow_pickle=False) as data:
        if "header" not in data.files:
            raise InvalidValueError(f"{path}: not a sabre episode file (no header)")
        header = json.loads(str(data["header"]))
        if header.get("format") != _FORMAT:
            raise InvalidValueError(f"{path}: unsupported episode format {header.get('format')!r}")
        arrays = {name: data[name] for name in data.files if name != "header"}
    scene = Scene.load(header["robot"], header["object"], obj_pose=header["object_pose"])
    scalars = {name: header.get(name) for name in _SCALARS}
    scalars["phases"] = tuple(scalars["phases"])
    return Episode(scene=scene, **scalars, **arrays)
