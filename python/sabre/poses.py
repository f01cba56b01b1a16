"""Poses as URDF writes them: (x, y, z, roll, pitch, yaw) with R = Rz(yaw) Ry(pitch) Rx(roll), and
their (4, 4) homogeneous matrices."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["pose_to_xyz_rpy", "xyz_rpy_to_pose"]


def pose_to_xyz_rpy(pose: np.ndarray) -> np.ndarray:
    """(6,) x, y, z, roll, pitch, yaw of a (4, 4) pose, with R = Rz(yaw) Ry(pitch) Rx(roll) as in URDF."""
    m = np.asarray(pose, dtype=np.float64)
    r = m[:3, :3]
    pitch = -np.arcsin(np.clip(r[2, 0], -1.0, 1.0))
    if np.hypot(r[0, 0], r[1, 0]) > 1e-6:
        roll = np.arctan2(r[2, 1], r[2, 2])
        yaw = np.arctan2(r[1, 0], r[0, 0])
    else:  # pitch at ±90°: roll and yaw turn about the same axis, so yaw 0 and roll takes the turn
        yaw = 0.0
        roll = np.arctan2(r[0, 1], r[0, 2]) if r[2, 0] < 0 else np.arctan2(-r[0, 1], -r[0, 2])
    return np.concatenate([m[:3, 3], [roll, pitch, yaw]])


def xyz_rpy_to_pose(xyz_rpy: Sequence[float] | np.ndarray) -> np.ndarray:
    """(4, 4) pose of (x, y, z, roll, pitch, yaw), R = Rz(yaw) Ry(pitch) Rx(roll) as in URDF."""
    x, y, z, roll, pitch, yaw = (float(v) for v in np.asarray(xyz_rpy, dtype=np.float64).reshape(6))
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    m = np.eye(4)
    m[:3, :3] = [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]
    m[:3, 3] = [x, y, z]
    return m
