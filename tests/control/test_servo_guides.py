"""Servo guides in a batch: each guide of `sabre.guides.servo_guides` is the one `servo_guide` gives
for its target sequence alone, and bad batches are refused."""

from __future__ import annotations

import numpy as np
import pytest

import sabre
from sabre.guides import servo_guide, servo_guides


@pytest.fixture(scope="module")
def scene():
    return sabre.Scene.load(obj="drawer")


def _sequences(scene, q0, count, steps):
    """`count` target sequences (count, steps + 1, 4, 4): the grasp frame moved along different lines."""
    start = scene.fk(q0, "grasp")
    out = np.empty((count, steps + 1, 4, 4))
    for m in range(count):
        direction = np.array([0.05 * (m + 1), -0.03 * m, 0.02])
        for k in range(steps + 1):
            out[m, k] = start
            out[m, k, :3, 3] += direction * k / steps
    return out


def test_each_guide_is_the_guide_of_its_sequence_alone(scene):
    q0 = scene.default_state()[: scene.nq]
    targets = _sequences(scene, q0, 3, 40)
    linear = [0.05, 0.2, 0.4]
    alone = np.stack([servo_guide(scene, q0, t, 0.015, gain=3.0, max_linear=v, max_angular=1.0) for t, v in zip(targets, linear)])
    together = servo_guides(scene, q0, targets, 0.015, gain=3.0, max_linear=linear, max_angular=1.0)
    assert together.shape == (3, 40, scene.nu)
    np.testing.assert_array_equal(together, alone)
    assert servo_guides(scene, q0, targets[:0], 0.015).shape == (0, 40, scene.nu)
    # the slowest cap binds: its guide moves the frame less far than the fastest's
    assert np.abs(alone[0]).sum() < np.abs(alone[2]).sum()


@pytest.mark.parametrize(
    "case, call",
    [
        ("one sequence, not a batch", lambda s, q, t: servo_guides(s, q, t[0], 0.015)),
        ("a sequence of one pose", lambda s, q, t: servo_guides(s, q, t[:, :1], 0.015)),
        ("max_linear per guide, too few", lambda s, q, t: servo_guides(s, q, t, 0.015, max_linear=[0.1, 0.2])),
        ("gain per guide, a matrix", lambda s, q, t: servo_guides(s, q, t, 0.015, gain=np.ones((3, 1)))),
        ("a negative cap", lambda s, q, t: servo_guides(s, q, t, 0.015, max_angular=[1.0, -1.0, 1.0])),
    ],
)
def test_bad_batches_are_invalid_values(scene, case, call):
    q0 = scene.default_state()[: scene.nq]
    with pytest.raises(sabre.InvalidValueError):
        call(scene, q0, _sequences(scene, q0, 3, 5))
