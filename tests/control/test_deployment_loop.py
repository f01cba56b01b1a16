"""The deployment loop on any clock: RealtimeCascade.plan / tick in the caller's loop (simulated time) is
run_episode, plans are values (PlanSnapshot) handed over for a time, and the tick works without a
low-level controller."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

import sabre
from sabre.errors import InvalidValueError
from sabre.paper import scenarios

SECONDS = 0.3
CONFIG = sabre.ControllerConfig(variant="IO", rollouts=16, seed=4, threads=1, tank_initial=2.3)


@pytest.fixture(scope="module")
def hooked():
    """The shelf scene with the hook against the handle's bar."""
    scene = sabre.Scene.load()
    return scene, scenarios.hooked_state(scene)


def _pull_from_the_start(t, x, plant, controller):
    if t == 0.0:
        controller.set_phase("open", t)


def _cascade_in_simulated_time(scene, x0, delay, low_level=True):
    """The loop a simulator runs: re-plan at 20 Hz (planning taken to last ``delay`` s), tick every step."""
    controller = sabre.Controller(scene, sabre.tasks.OpenObject(), CONFIG)
    plant = sabre.Plant(scene)
    plant.reset(x0)
    servo = sabre.LowLevelController(scene, dt=plant.dt)  # the cascade's, or the velocity robot's own
    cascade = sabre.RealtimeCascade(controller, low_level=servo if low_level else None, inner_dt=plant.dt)
    cascade.reset(seed=4)
    states, ticks = [], []
    for k in range(round(SECONDS / plant.dt)):
        if k % 50 == 0:
            _pull_from_the_start(plant.time, plant.state, plant, controller)
            cascade.plan(plant.state, plant.time, delay=delay)
        tick = cascade.tick(plant.state, plant.measured_tau_ext, plant.time, dt=plant.dt)
        plant.step(tick.torque if low_level else servo.torque(plant.state, tick.command))
        states.append(plant.state)
        ticks.append(tick)
    return np.array(states), ticks


@pytest.mark.parametrize("delay", [0.0, 0.02], ids=["undelayed", "delayed"])
def test_the_cascade_in_simulated_time_is_run_episode(hooked, delay):
    """plan(x, t, delay=...) and tick(...) in a simulator's loop make run_episode's episode of the same
    seed: the same states, tank and commands to 1e-9, the previous plan running for the delay."""
    scene, x0 = hooked
    controller = sabre.Controller(scene, sabre.tasks.OpenObject(), CONFIG)
    episode = sabre.run_episode(
        scene,
        controller,
        SECONDS,
        seed=4,
        x0=x0,
        record_every=1,
        plan_delay=delay,
        stop_on_success=False,
        progress=False,
        on_replan=_pull_from_the_start,
    )
    states, ticks = _cascade_in_simulated_time(scene, x0, delay)
    np.testing.assert_allclose(states, episode.state, rtol=0.0, atol=1e-9)
    np.testing.assert_allclose([r.tank_energy for r in ticks], episode.tank_energy, rtol=0.0, atol=1e-9)
    np.testing.assert_allclose([r.command for r in ticks], episode.command, rtol=0.0, atol=1e-9)
    np.testing.assert_allclose([r.reference for r in ticks], episode.reference, rtol=0.0, atol=1e-9)
    assert episode.contact.mean() > 0.5 and np.abs(episode.command - episode.reference).max() > 1e-3


def test_a_plan_handed_over_for_a_time_takes_over_at_the_first_tick_at_that_time(scene):
    controller = sabre.Controller(scene, sabre.tasks.OpenObject(), sabre.ControllerConfig(rollouts=8, seed=0))
    cascade = sabre.RealtimeCascade(controller)
    x, tau = scene.default_state(), np.zeros(scene.nq)
    with pytest.raises(InvalidValueError, match="no plan yet"):
        cascade.tick(x, tau, 0.0)
    ones, twos = (sabre.PlanSnapshot.of(np.full((3, scene.nu), v), 0.0, 0.1) for v in (0.01, 0.02))
    cascade.hand_over(ones, at=5.0)  # nothing in force: at once
    cascade.hand_over(twos, at=0.0104)
    assert cascade.current_plan is ones
    np.testing.assert_array_equal(cascade.reference(0.0105), twos.reference(0.0105))
    assert cascade.tick(x, tau, 0.010).reference[0] == pytest.approx(0.01, abs=1e-15)
    # a clock that sums its steps lands a rounding error short of the time: the plan takes over all the same
    assert cascade.tick(x, tau, 0.0104 - 1e-9).reference[0] == pytest.approx(0.02, abs=1e-15)
    assert cascade.current_plan is twos and cascade.ticks == 2
    with pytest.raises(TypeError, match="PlanSnapshot"):
        cascade.hand_over(twos.plan)


def test_plan_is_refused_while_the_background_planner_runs_and_works_again_after_stop(scene):
    controller = sabre.Controller(scene, sabre.tasks.OpenObject(), sabre.ControllerConfig(rollouts=8, seed=0, threads=1))
    x = scene.default_state()
    with sabre.RealtimeCascade(controller, min_replan_period=10.0, delay_compensation=False).start(x) as cascade:
        for call in (lambda: cascade.plan(x, 0.0), lambda: cascade.hand_over(cascade.current_plan), cascade.reset):
            with pytest.raises(InvalidValueError, match="stop"):
                call()
    with pytest.raises(InvalidValueError, match="stopped"):
        cascade.tick(x, np.zeros(scene.nq), 0.0)
    snapshot = cascade.plan(x, 0.1)
    assert cascade.current_plan is snapshot and snapshot.t0 == pytest.approx(0.1)
    assert cascade.tick(x, np.zeros(scene.nq), 0.1).status == "unfiltered"
    with pytest.raises(InvalidValueError, match="delay"):
        cascade.plan(x, 0.2, delay=-0.01)


def test_without_a_low_level_controller_the_tick_returns_the_same_command_and_no_torque(hooked):
    """A velocity-interface robot: the cascade without a low-level controller ticks the same commands
    (here the robot's servo is the low-level controller (53) itself), with torque None."""
    scene, x0 = hooked
    with_torque, ticks = _cascade_in_simulated_time(scene, x0, 0.0)
    commanded, velocity_ticks = _cascade_in_simulated_time(scene, x0, 0.0, low_level=False)
    assert all(r.torque is None for r in velocity_ticks) and all(r.torque is not None for r in ticks)
    np.testing.assert_allclose([r.command for r in velocity_ticks], [r.command for r in ticks], rtol=0.0, atol=1e-9)
    np.testing.assert_allclose(commanded, with_torque, rtol=0.0, atol=1e-9)


def test_a_snapshot_is_the_plan_as_a_value(hooked):
    """Controller.snapshot: the controller's plan at the time, unchanged by later iterations; reference(t)
    and predicted_dissipation(t) as the controller's; pickles whole."""
    scene, x0 = hooked
    controller = sabre.Controller(scene, sabre.tasks.OpenObject(), CONFIG)
    controller.set_phase("open")
    stats = controller.update(x0, 0.25)
    snapshot = controller.snapshot()
    dt = controller.config.dt
    times = [0.0, 0.25, 0.25 + 0.4 * dt, 0.25 + 7.5 * dt, 9.0]
    for t in times:
        np.testing.assert_array_equal(snapshot.reference(t), controller.reference(t))
        assert snapshot.predicted_dissipation(t) == pytest.approx(controller.predicted_dissipation_at(t), rel=0.0, abs=1e-12)
    predicted = controller.predicted_dissipation
    assert controller.predicted_dissipation_at(0.0) == predicted[0] and controller.predicted_dissipation_at(9.0) == predicted[-1]
    assert controller.predicted_dissipation_at(0.25 + 0.5 * dt) == pytest.approx(0.5 * (predicted[0] + predicted[1]))
    assert np.abs(predicted).max() > 0.0
    assert (snapshot.phase, snapshot.iterations, snapshot.nominal_cost) == ("open", 1, stats.nominal_cost)
    assert snapshot.iteration_time == stats.iteration_time and snapshot.gain_inertia_floor is None
    nominal = controller.nominal.copy()
    np.testing.assert_array_equal(snapshot.nominal, nominal)
    controller.update(x0, 0.3)
    np.testing.assert_array_equal(snapshot.nominal, nominal)  # the planner moved on, the snapshot did not
    assert snapshot.t0 == 0.25 and not np.array_equal(controller.nominal, nominal)
    with pytest.raises(AttributeError):
        snapshot.phase = "approach"  # type: ignore[misc]
    again = pickle.loads(pickle.dumps(snapshot))
    assert again == snapshot and again.plan == snapshot.plan
    np.testing.assert_array_equal(again.predicted, predicted)
    assert sabre.Controller(scene, sabre.tasks.OpenObject(), sabre.ControllerConfig(seed=0)).predicted_dissipation_at(0.0) is None
