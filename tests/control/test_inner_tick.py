"""The cascade's tick in the core (`_core.Plan`, `_core.Cascade`): one tick per plant step is what the
cascade's `follow` runs on the Rust plant, plans are immutable, validated and picklable, and bad input raises
sabre errors."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

import sabre
from sabre import _core
from sabre.errors import InvalidValueError, ShapeError
from sabre.paper import scenarios

STEPS = 500
INITIAL = 2.5  # J: close enough to the floor (2 J) that the passivity row shapes the pull


@pytest.fixture(scope="module")
def pull():
    """The scripted pull from the hooked state, with the rollout model's predicted port dissipation."""
    scene = sabre.Scene.load()
    motion = sabre.hook_and_pull(scene, scene.default_state())
    U = np.ascontiguousarray(motion.U[int(np.argmax(motion.phases == 3)) :], dtype=np.float64)
    x0 = scenarios.hooked_state(scene)
    rollout = sabre.RolloutModel(scene, motion.dt).rollout(x0, U[None], threads=1)
    predicted = -np.einsum("kj,kj->k", rollout.tau_ext[0], U)
    return scene, U, motion.dt, x0, predicted


def _stage(scene, x0):
    """A plant at x0 with its low-level controller, the I variant's FILTER-QP and a tank with a refill."""
    plant = sabre.Plant(scene)
    plant.reset(x0)
    low = sabre.LowLevelController(scene, dt=plant.dt)
    return plant, low, sabre.SafetyFilter(scene), sabre.EnergyTank(INITIAL, 2.0, refill=sabre.TankRefill())


def test_a_tick_and_a_plant_step_per_step_is_what_follow_does(pull):
    scene, U, dt, x0, predicted = pull
    plan = _core.Plan(U, 0.0, dt, predicted)
    plant, low, safety, tank = _stage(scene, x0)
    followed = _core.Cascade(low._core, safety._core, tank._core)
    followed.hand_over(plan)
    trace = followed.follow(plant._core, STEPS, 1)

    plant, low, safety, ticked_tank = _stage(scene, x0)
    inner = _core.Cascade(low._core, safety._core, ticked_tank._core)
    inner.hand_over(plan)
    core = plant._core
    states, references, commands, energies, statuses = [], [], [], [], []
    for _ in range(STEPS):
        x, tau = np.array(core.state), np.array(core.measured_tau_ext)
        reference, command, torque, energy, status = inner.tick(x, tau, core.time, core.dt)
        core.step(torque)
        states.append(core.state)
        references.append(reference)
        commands.append(command)
        energies.append(energy)
        statuses.append(status)

    np.testing.assert_allclose(np.array(states), trace["state"], rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(np.array(references), trace["reference"], rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(np.array(commands), trace["filtered"], rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(np.array(energies), trace["tank_energy"], rtol=0.0, atol=1e-12)
    assert statuses == list(trace["filter_status"])
    assert ticked_tank.energy == energies[-1]  # the tick stepped the very tank the wrapper holds
    assert abs(ticked_tank.refilled - tank.refilled) <= 1e-12
    # What the comparison covers: contact, the refill, and a passivity row that changed the command.
    assert trace["contact"].any()
    assert ticked_tank.refilled > 0.05
    assert (np.abs(np.array(commands) - np.array(references)).max(axis=1) > 1e-6).sum() > STEPS // 4


def test_without_filter_and_tank_a_tick_is_the_torque_of_the_interpolated_reference_and_the_plans_floor(pull):
    scene, U, dt, x0, _ = pull
    plan = _core.Plan(U, 0.0, dt, gain_inertia_floor=0.3)
    low, by_hand = (sabre.LowLevelController(scene, dt=0.001, gain_inertia_floor=0.01) for _ in range(2))
    inner = _core.Cascade(low._core)
    assert inner.filter is None and inner.tank is None
    inner.hand_over(plan)
    tau_ext = np.zeros(scene.nq)
    for t in (0.0071, 0.0072):
        reference, command, torque, energy, status = inner.tick(x0, tau_ext, t, 0.001)
        np.testing.assert_array_equal(reference, plan.reference_at(t))
        np.testing.assert_array_equal(command, reference)
        by_hand.gain_inertia_floor = 0.3
        np.testing.assert_array_equal(torque, by_hand._core.torque(x0, reference))
        assert (energy, status) == (None, "unfiltered")
    assert low.gain_inertia_floor == 0.01  # the plan's floor holds for its ticks only


def test_a_plan_interpolates_on_its_grid_and_holds_its_ends():
    reference = np.array([[0.0, 10.0], [1.0, 20.0], [3.0, 40.0]])
    plan = _core.Plan(reference, 1.0, 0.5, np.array([1.0, 2.0, 4.0]), 0.2)
    assert (plan.steps, plan.nu, plan.t0, plan.dt, plan.gain_inertia_floor) == (3, 2, 1.0, 0.5, 0.2)
    np.testing.assert_array_equal(plan.reference_at(1.25), [0.5, 15.0])
    np.testing.assert_array_equal(plan.reference_at(1.5), [1.0, 20.0])
    np.testing.assert_array_equal(plan.reference_at(-4.0), [0.0, 10.0])
    np.testing.assert_array_equal(plan.reference_at(8.0), [3.0, 40.0])
    assert plan.predicted_dissipation_at(1.75) == 3.0
    assert _core.Plan(reference, 1.0, 0.5).predicted_dissipation_at(1.75) is None


def test_a_plan_is_immutable_and_pickles():
    reference = np.array([[0.0, 10.0], [1.0, 20.0]])
    plan = _core.Plan(reference, 0.5, 0.1, np.array([1.0, 2.0]))
    reference[0, 0] = 99.0  # the plan holds its own copy
    copy = plan.reference
    copy[0, 0] = 42.0  # and hands out copies
    np.testing.assert_array_equal(plan.reference, [[0.0, 10.0], [1.0, 20.0]])
    with pytest.raises(AttributeError):
        plan.t0 = 3.0  # type: ignore[misc]
    again = pickle.loads(pickle.dumps(plan))
    assert again == plan
    assert again is not plan and again.gain_inertia_floor is None
    np.testing.assert_array_equal(again.predicted_dissipation, [1.0, 2.0])
    assert again != _core.Plan(plan.reference, 0.5, 0.1)
    # Any memory layout: the plan copies its rows in order.
    assert _core.Plan(np.asfortranarray(plan.reference), 0.5, 0.1, np.array([3.0, 1.0, 2.0])[1:]) == plan


@pytest.mark.parametrize(
    ("args", "error"),
    [
        ((np.zeros(4), 0.0, 0.1), ShapeError),
        ((np.zeros((0, 2)), 0.0, 0.1), ShapeError),
        ((np.array([[0.0, np.nan]]), 0.0, 0.1), InvalidValueError),
        ((np.zeros((2, 2)), 0.0, 0.0), InvalidValueError),
        ((np.zeros((2, 2)), np.inf, 0.1), InvalidValueError),
        ((np.zeros((2, 2)), 0.0, 0.1, np.zeros(3)), ShapeError),
        ((np.zeros((2, 2)), 0.0, 0.1, np.array([0.0, np.nan])), InvalidValueError),
        ((np.zeros((2, 2)), 0.0, 0.1, None, -1.0), InvalidValueError),
    ],
)
def test_a_bad_plan_is_a_sabre_error(args, error):
    with pytest.raises(error):
        _core.Plan(*args)


def test_bad_tick_input_is_a_sabre_error_and_changes_nothing(pull):
    scene, U, dt, x0, _ = pull
    low = sabre.LowLevelController(scene, dt=0.001)
    safety, tank = sabre.SafetyFilter(scene), sabre.EnergyTank(INITIAL, 2.0)
    inner = _core.Cascade(low._core, safety._core, tank._core)
    plan = _core.Plan(U, 0.0, dt)
    tau = np.zeros(scene.nq)
    with pytest.raises(InvalidValueError, match="no plan yet"):
        inner.tick(x0, tau, 0.0, 0.001)
    with pytest.raises(ShapeError):
        inner.hand_over(_core.Plan(U[:, :-1], 0.0, dt))
    with pytest.raises(InvalidValueError):
        inner.hand_over(plan, float("nan"))
    assert inner.in_force is None
    inner.hand_over(plan)
    with pytest.raises(ShapeError):
        inner.tick(x0[:-1], tau, 0.0, 0.001)
    with pytest.raises(ShapeError):
        inner.tick(x0, np.zeros(scene.nq + 1), 0.0, 0.001)
    with pytest.raises(InvalidValueError):
        inner.tick(x0, np.full(scene.nq, np.nan), 0.0, 0.001)
    with pytest.raises(InvalidValueError):
        inner.tick(x0, tau, float("nan"), 0.001)
    with pytest.raises(InvalidValueError):
        inner.tick(x0, tau, 0.0, 0.0)
    with pytest.raises(InvalidValueError):
        plan.reference_at(float("inf"))
    assert safety.stats.calls == 0
    assert len(tank.history) == 1
    assert inner.ticks == 0 and inner.tau_ext_counts == (0, 0)
    *_, energy, status = inner.tick(x0, tau, 0.0, 0.001)
    assert (energy, status) == (INITIAL, "solved")
    assert inner.ticks == 1
    assert inner.low_level is low._core and inner.filter is safety._core and inner.tank is tank._core
