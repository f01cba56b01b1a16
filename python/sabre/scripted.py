"""Scripted hook-and-pull motions: an open-loop joint-velocity sequence planned by differential IK.

Used by the demo and the tests as an independent check that the scene, the hook and the object
interact as designed; the sampling-based controller does not need it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ._validate import as_float_array, as_positive
from .guides import rotation_log
from .scene import Scene

__all__ = ["ScriptedMotion", "hook_and_pull"]


@dataclass(frozen=True)
class ScriptedMotion:
    """An open-loop input sequence with its plan.

    Attributes:
        U: (K, nu) joint velocity commands at steps of ``dt``.
        dt: step of the sequence (s).
        phases: (K,) phase of each step: 0 approach, 1 insert, 2 hook, 3 pull, 4 retreat.
        planned_states: (K+1, nq) kinematic plan of q.
        planned_opening: (K+1,) object opening the pull phase aims at, per step.
    """

    U: np.ndarray
    dt: float
    phases: np.ndarray
    planned_states: np.ndarray
    planned_opening: np.ndarray


# Waypoints in the handle frame: behind the bar (−z) and beside it (−y), clear of the tip.
_PRE_INSERT = (0.0, -0.022, -0.09)
_INSERTED = (0.0, -0.022, 0.0)
_HOOKED = (0.0, 0.0, 0.0)
_PULLING = (0.0, 0.0, -0.016)


@dataclass(frozen=True)
class _Segment:
    """One phase of the motion: the grasp pose and the object opening it aims at, as functions of
    the phase's progress s ∈ (0, 1]."""

    phase: int
    duration: float
    pose_at: Callable[[float], np.ndarray]
    opening_at: Callable[[float], float]


def _offset(pose: np.ndarray, xyz: tuple[float, float, float]) -> np.ndarray:
    out = pose.copy()
    out[:3, 3] = pose[:3, 3] + pose[:3, :3] @ np.asarray(xyz)
    return out


def _blend(a: np.ndarray, b: np.ndarray, s: float) -> np.ndarray:
    """The pose a fraction s of the way from a to b (position linear, rotation along the geodesic),
    eased so that the motion starts and stops smoothly."""
    s = 0.5 - 0.5 * np.cos(np.pi * np.clip(s, 0.0, 1.0))
    out = np.eye(4)
    out[:3, 3] = (1 - s) * a[:3, 3] + s * b[:3, 3]
    rel = a[:3, :3].T @ b[:3, :3]
    w = rotation_log(rel) * s
    angle = np.linalg.norm(w)
    if angle < 1e-12:
        out[:3, :3] = a[:3, :3]
    else:
        k = w / angle
        kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        out[:3, :3] = a[:3, :3] @ (np.eye(3) + np.sin(angle) * kx + (1 - np.cos(angle)) * kx @ kx)
    return out


def _engage(s: float) -> tuple[float, float, float]:
    """The pull's offset from the handle: taking up the slack first (tip against the bar)."""
    x, y, z = np.asarray(_PULLING) * min(1.0, 8.0 * s)
    return (float(x), float(y), float(z))


def _pull_target(scene: Scene, opening: float | None, release_after: bool | None) -> tuple[float, bool]:
    """The opening the pull aims at, and whether the hook retreats after it (by default for objects
    that fall open under gravity: the dishwasher)."""
    upper = float(scene.o_upper[0])
    target = 0.75 * upper if opening is None else float(opening)
    if release_after is None:
        release_after = scene.object_name == "dishwasher"
    if release_after and opening is None:
        target = 0.45
    return target, release_after


def _segments(
    scene: Scene,
    q0: np.ndarray,
    o0: float,
    target: float,
    approach_time: float,
    pull_time: float,
    release_after: bool,
) -> list[_Segment]:
    """Approach, insert, hook, pull along the handle's path to ``target`` and, with
    ``release_after``, retreat."""

    def handle(o: float) -> np.ndarray:
        return scene.object_fk(np.array([o]), "handle_frame")

    def closed(s: float) -> float:
        return o0

    def opening_profile(s: float) -> float:
        return o0 + (target - o0) * (0.5 - 0.5 * np.cos(np.pi * np.clip(s, 0, 1)))

    h0 = handle(o0)
    grasp0 = scene.fk(q0, scene.require_tool_frame("hook_and_pull"))
    segments = [
        _Segment(0, approach_time, lambda s: _blend(grasp0, _offset(h0, _PRE_INSERT), s), closed),
        _Segment(1, 1.2, lambda s: _blend(_offset(h0, _PRE_INSERT), _offset(h0, _INSERTED), s), closed),
        _Segment(2, 0.8, lambda s: _blend(_offset(h0, _INSERTED), _offset(h0, _HOOKED), s), closed),
        _Segment(3, pull_time, lambda s: _offset(handle(opening_profile(s)), _engage(s)), opening_profile),
    ]
    if release_after:
        end = _offset(handle(target), _PULLING)
        away = end.copy()
        away[:3, 3] += np.array([-0.15, 0.0, 0.12]) @ np.eye(3)
        segments.append(_Segment(4, 1.5, lambda s: _blend(end, away, s), lambda s: target))
    return segments


class _DifferentialIK:
    """Damped least-squares differential IK of the tool frame on the robot's Jacobian (a holonomic
    base and the arm, the base weighted to move less), with a null-space pull of the arm toward the
    robot's working posture (:meth:`Scene.work_configuration`) and the base kept ``standoff`` in
    front of the object."""

    DAMPING = 1e-4

    def __init__(self, scene: Scene, dt: float, standoff: float) -> None:
        self.scene = scene
        self.frame = scene.require_tool_frame("hook_and_pull")
        self.dt = dt
        self.standoff = standoff
        self.lower, self.upper, self.vmax = scene.q_lower, scene.q_upper, scene.dq_limit
        base = list(scene.base_indices or ())
        self.arm = np.ones(scene.nq, dtype=bool)
        self.arm[base] = False
        weights = np.where(self.arm, 1.0, 4.0)  # moving a heavy base is costlier than moving the arm
        self.w_inv = 1.0 / weights
        self.home = scene.work_configuration()
        # Keep the base footprint clear of the cabinet front: its centre stays `standoff` in front of
        # the object's front plane (the plane x = 0 of the object frame).
        pose = scene.object_pose
        self.front_normal = -pose[:3, 0]  # points from the object toward the robot
        self.front_point = pose[:3, 3]
        self.base_joints = base[:2]

    def step(self, q: np.ndarray, desired: np.ndarray) -> np.ndarray:
        """The configuration one step on from q toward the grasp pose ``desired``, within the
        joints' velocity and position limits and the base's standoff."""
        scene, dt, w_inv = self.scene, self.dt, self.w_inv
        current = scene.fk(q, self.frame)
        err = np.concatenate([desired[:3, 3] - current[:3, 3], rotation_log(desired[:3, :3] @ current[:3, :3].T)])
        twist = err / dt * 0.5
        J = scene.jacobian(q, self.frame)
        Jw = J * w_inv
        u = w_inv * (J.T @ np.linalg.solve(Jw @ J.T + self.DAMPING * np.eye(6), twist))
        # Secondary task: stay near the home posture and away from the joint limits (arm only).
        null = np.eye(scene.nq) - (w_inv[:, None] * J.T) @ np.linalg.solve(Jw @ J.T + self.DAMPING * np.eye(6), J)
        posture = np.where(self.arm, 0.5 * (self.home - q), 0.0)
        u = u + null @ posture
        u = np.clip(u, -0.8 * self.vmax, 0.8 * self.vmax)
        q_next = np.clip(q + dt * u, self.lower + 1e-3, self.upper - 1e-3)
        if len(self.base_joints) == 2:
            xy = q_next[self.base_joints]
            depth = self.standoff - float(np.dot(np.r_[xy, 0.0] - self.front_point, self.front_normal))
            if depth > 0.0:
                normal = self.front_normal[:2]
                q_next[self.base_joints] = xy + depth * normal / max(float(np.linalg.norm(normal)), 1e-9)
        return q_next


def _follow(ik: _DifferentialIK, segments: list[_Segment], q0: np.ndarray, o0: float) -> ScriptedMotion:
    """Steps the IK through every segment; the commands are what the joints actually did."""
    dt = ik.dt
    total = sum(int(round(seg.duration / dt)) for seg in segments)
    U = np.zeros((total, len(q0)))
    phases = np.zeros(total, dtype=np.int64)
    q = q0.copy()
    planned = [q.copy()]
    planned_opening = [o0]
    k = 0
    for seg in segments:
        steps = int(round(seg.duration / dt))
        for i in range(steps):
            s = (i + 1) / steps
            q_next = ik.step(q, seg.pose_at(s))
            U[k] = (q_next - q) / dt  # what the joints can actually do at their limits
            q = q_next
            phases[k] = seg.phase
            planned.append(q.copy())
            planned_opening.append(seg.opening_at(s))
            k += 1
    return ScriptedMotion(
        U=U,
        dt=dt,
        phases=phases,
        planned_states=np.asarray(planned),
        planned_opening=np.asarray(planned_opening),
    )


def hook_and_pull(
    scene: Scene,
    x0: np.ndarray | None = None,
    *,
    opening: float | None = None,
    dt: float = 0.015,
    approach_time: float = 4.0,
    pull_time: float = 5.0,
    release_after: bool | None = None,
    standoff: float = 0.75,
) -> ScriptedMotion:
    """Plans the hook finger onto the handle and pulls the handle along its opening path.

    The grasp frame is driven through five phases by damped least-squares differential IK on the
    robot's Jacobian (base and arm, the base weighted to move less): approach a pre-insert pose
    in front of the handle and offset sideways, insert past the bar, hook (slide the bar into the
    finger's pocket), pull while following ``handle_frame`` as the object opens to ``opening``, and,
    for objects that fall open under gravity (the dishwasher), retreat and let go.
    """
    dt = as_positive("dt", dt)
    x0 = scene.default_state() if x0 is None else as_float_array("x0", x0, (scene.nx,))
    q0, _, o0, _ = scene.split_state(x0)
    target, release_after = _pull_target(scene, opening, release_after)
    segments = _segments(scene, q0, o0[0], target, approach_time, pull_time, release_after)
    return _follow(_DifferentialIK(scene, dt, standoff), segments, q0, o0[0])
