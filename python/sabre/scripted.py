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


def _offset(pose: np.ndarray, xyz: tuple[float, float, float]) -> np.ndarray:
    out = pose.copy()
    out[:3, 3] = pose[:3, 3] + pose[:3, :3] @ np.asarray(xyz)
    return out


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
    nq = scene.nq
    q0, _, o0, _ = scene.split_state(x0)
    upper = float(scene.o_upper[0])
    target = 0.75 * upper if opening is None else float(opening)
    if release_after is None:
        release_after = scene.object_name == "dishwasher"
    if release_after and opening is None:
        target = 0.45

    # Waypoints in the handle frame: behind the bar (−z) and beside it (−y), clear of the tip.
    pre_insert = (0.0, -0.022, -0.09)
    inserted = (0.0, -0.022, 0.0)
    hooked = (0.0, 0.0, 0.0)
    pulling = (0.0, 0.0, -0.016)

    def handle(o: float) -> np.ndarray:
        return scene.object_fk(np.array([o]), "handle_frame")

    segments: list[tuple[int, float, Callable[[float], np.ndarray]]] = []

    def add(phase: int, duration: float, pose_at: Callable[[float], np.ndarray]) -> None:
        segments.append((phase, duration, pose_at))

    h0 = handle(o0[0])
    grasp0 = scene.fk(q0, "grasp")

    def blend(a: np.ndarray, b: np.ndarray, s: float) -> np.ndarray:
        s = 0.5 - 0.5 * np.cos(np.pi * np.clip(s, 0.0, 1.0))  # smooth start and stop
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

    add(0, approach_time, lambda s: blend(grasp0, _offset(h0, pre_insert), s))
    add(1, 1.2, lambda s: blend(_offset(h0, pre_insert), _offset(h0, inserted), s))
    add(2, 0.8, lambda s: blend(_offset(h0, inserted), _offset(h0, hooked), s))

    def opening_profile(s: float) -> float:
        return o0[0] + (target - o0[0]) * (0.5 - 0.5 * np.cos(np.pi * np.clip(s, 0, 1)))

    # Take up the slack first (tip against the bar), then follow the handle along its path.
    def engage(s: float) -> tuple[float, float, float]:
        x, y, z = np.asarray(pulling) * min(1.0, 8.0 * s)
        return (float(x), float(y), float(z))

    add(3, pull_time, lambda s: _offset(handle(opening_profile(s)), engage(s)))
    if release_after:
        end = _offset(handle(target), pulling)
        away = end.copy()
        away[:3, 3] += np.array([-0.15, 0.0, 0.12]) @ np.eye(3)
        add(4, 1.5, lambda s: blend(end, away, s))

    total = sum(int(round(d / dt)) for _, d, _ in segments)
    U = np.zeros((total, nq))
    phases = np.zeros(total, dtype=np.int64)
    q = q0.copy()
    planned = [q.copy()]
    planned_opening = [o0[0]]
    lower, upper_q, vmax = scene.q_lower, scene.q_upper, scene.dq_limit
    weights = np.ones(nq)
    weights[:3] = 4.0  # moving the 165 kg base is costlier than moving the arm
    w_inv = 1.0 / weights
    home = scene.home_configuration()
    # Null-space posture: for a Panda, elbow up and wrist pitched so the hand points forward
    # with margin on every joint limit; other robots keep their home configuration.
    if scene.joint_names[3:] == tuple(f"panda_joint{i}" for i in range(1, 8)):
        home = home.copy()
        home[3:] = [0.0, 0.3, 0.0, -1.9, 0.0, 2.2, 0.785]
    # Keep the base footprint (radius 0.53 m) clear of the cabinet front: its centre stays
    # `standoff` in front of the object's front plane (the plane x = 0 of the object frame).
    pose = scene.object_pose
    front_normal = -pose[:3, 0]  # points from the object toward the robot
    front_point = pose[:3, 3]
    base_joints = [i for i, n in enumerate(scene.joint_names) if n in ("base_x", "base_y")]
    k = 0
    for phase, duration, pose_at in segments:
        steps = int(round(duration / dt))
        for i in range(steps):
            s = (i + 1) / steps
            desired = pose_at(s)
            current = scene.fk(q, "grasp")
            err = np.concatenate([desired[:3, 3] - current[:3, 3], rotation_log(desired[:3, :3] @ current[:3, :3].T)])
            twist = err / dt * 0.5
            J = scene.jacobian(q, "grasp")
            Jw = J * w_inv
            damping = 1e-4
            u = w_inv * (J.T @ np.linalg.solve(Jw @ J.T + damping * np.eye(6), twist))
            # Secondary task: stay near the home posture and away from the joint limits (arm only).
            null = np.eye(nq) - (w_inv[:, None] * J.T) @ np.linalg.solve(Jw @ J.T + damping * np.eye(6), J)
            posture = np.zeros(nq)
            posture[3:] = 0.5 * (home[3:] - q[3:])
            u = u + null @ posture
            u = np.clip(u, -0.8 * vmax, 0.8 * vmax)
            q_next = np.clip(q + dt * u, lower + 1e-3, upper_q - 1e-3)
            if len(base_joints) == 2:
                xy = q_next[base_joints]
                depth = standoff - float(np.dot(np.r_[xy, 0.0] - front_point, front_normal))
                if depth > 0.0:
                    q_next[base_joints] = xy + depth * front_normal[:2] / max(float(np.linalg.norm(front_normal[:2])), 1e-9)
            U[k] = (q_next - q) / dt  # what the joints can actually do at their limits
            q = q_next
            phases[k] = phase
            planned.append(q.copy())
            planned_opening.append(opening_profile(s) if phase == 3 else (target if phase == 4 else o0[0]))
            k += 1
    return ScriptedMotion(
        U=U,
        dt=dt,
        phases=phases,
        planned_states=np.asarray(planned),
        planned_opening=np.asarray(planned_opening),
    )
