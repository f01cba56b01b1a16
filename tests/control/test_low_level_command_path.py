"""The low-level controller as a robot's command path (`LowLevelController(command_acceleration=...)`):
it tracks the reference rate-limited per joint, from the measured velocity after a reset, so a plant
driven through it accelerates no faster than the bound; bad bounds are refused."""

from __future__ import annotations

import numpy as np
import pytest

import sabre
from sabre.errors import InvalidValueError, ShapeError

DT = 0.001


@pytest.fixture(scope="module")
def scene():
    return sabre.Scene.load()


def test_the_torque_is_that_of_the_reference_ramped_by_hand_at_the_bound(scene):
    """A step in the reference is tracked as the ramp from the measured velocity toward it at a·dt
    per call: the capped controller's torques equal, to the last bit, a plain controller's given that
    ramp."""
    nq = scene.nq
    caps = np.linspace(0.5, 5.0, nq)
    x = np.asarray(scene.default_state(), dtype=float).copy()
    x[nq : 2 * nq] = np.linspace(-0.1, 0.1, nq)  # the ramp starts at the measured velocity
    target = np.linspace(0.3, -0.2, nq)
    capped = sabre.LowLevelController(scene, dt=DT, command_acceleration=caps)
    plain = sabre.LowLevelController(scene, dt=DT)
    ramp = x[nq : 2 * nq].copy()
    for _ in range(1000):
        ramp = np.clip(target, ramp - caps * DT, ramp + caps * DT)
        np.testing.assert_array_equal(capped.torque(x, target), plain.torque(x, ramp))
    np.testing.assert_array_equal(ramp, target)  # the ramp got there
    np.testing.assert_array_equal(capped.command_acceleration, caps)


def test_a_reset_starts_the_ramp_again_from_the_measured_velocity(scene):
    nq = scene.nq
    caps = np.full(nq, 2.0)
    x = np.asarray(scene.default_state(), dtype=float).copy()
    capped = sabre.LowLevelController(scene, dt=DT, command_acceleration=caps)
    for _ in range(50):
        capped.torque(x, np.ones(nq))
    capped.reset()
    x[nq : 2 * nq] = 0.25
    plain = sabre.LowLevelController(scene, dt=DT)
    np.testing.assert_array_equal(capped.torque(x, np.ones(nq)), plain.torque(x, np.full(nq, 0.25 + 2.0 * DT)))


def test_a_plant_driven_through_it_accelerates_its_base_no_faster_than_the_bound(scene):
    """A 1 m/s step on the base's x, bounded at 1 m/s²: the base follows the ramp (the servo's
    feed-forward tracks it within two steps), never further ahead, so after 0.3 s it
    moves at 0.3 m/s; without the bound it reaches the step within 0.2 s."""
    nq = scene.nq
    caps = np.full(nq, 10.0)
    caps[0] = 1.0
    u = np.zeros(nq)
    u[0] = 1.0
    speeds = {}
    for name, bound in (("capped", caps), ("plain", None)):
        plant = sabre.Plant(scene, dt=DT)
        plant.reset(scene.default_state())
        low = sabre.LowLevelController(scene, dt=DT, command_acceleration=bound)
        v = []
        for _ in range(300):
            low.track(plant, u, 1)
            v.append(plant.state[nq])
        speeds[name] = np.array(v)
    t = DT * np.arange(1, 301)
    assert np.all(speeds["capped"] <= (t + 2 * DT) * 1.0)
    assert speeds["capped"][-1] == pytest.approx(0.3, abs=0.005)
    assert speeds["plain"][:200].max() > 0.9  # at its effort's pace: at the step within 0.2 s


@pytest.mark.parametrize(
    ("caps", "error"),
    [
        ([1.0] * 3, ShapeError),
        ("ten", ShapeError),
        ([0.0] + [1.0] * 9, InvalidValueError),
        ([np.nan] + [1.0] * 9, InvalidValueError),
    ],
)
def test_bad_bounds_are_refused(scene, caps, error):
    assert scene.nq == 10
    with pytest.raises(error):
        sabre.LowLevelController(scene, dt=DT, command_acceleration=caps)
