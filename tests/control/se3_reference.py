"""An SE(3) logarithm written from its closed form, independent of the core's, for the tests'
references."""

from __future__ import annotations

import numpy as np


def se3_log(t: np.ndarray) -> np.ndarray:
    """Independent SE(3) log: (V⁻¹ p, ω), ω the rotation vector of R."""
    r, p = t[:3, :3], t[:3, 3]
    angle = np.arccos(np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0))
    w_hat = (r - r.T) / 2.0
    w = np.array([w_hat[2, 1], w_hat[0, 2], w_hat[1, 0]])
    if angle > 1e-9:
        w = w * angle / np.sin(angle)
    wx = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    if angle < 1e-9:
        v_inv = np.eye(3) - 0.5 * wx
    else:
        v_inv = np.eye(3) - 0.5 * wx + (1.0 - angle * np.sin(angle) / (2.0 * (1.0 - np.cos(angle)))) / angle**2 * wx @ wx
    return np.r_[v_inv @ p, w]
