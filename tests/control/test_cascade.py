"""The cascade: controller variants (paper Sec. IV) in simulated time and the real-time mode."""

from __future__ import annotations

import math

import numpy as np
import pytest

import sabre
from sabre.errors import InvalidValueError


@pytest.fixture(scope="module")
def scene():
    return sabre.Scene.load(obj="shelf")


def test_variant_is_validated():
    with pytest.raises(InvalidValueError):
        sabre.ControllerConfig(variant="X")
    with pytest.raises(InvalidValueError):
        sabre.ControllerConfig(safety={"base_box": None})
    assert sabre.VARIANTS == ("N", "I", "O", "IO")


def _reach_beyond_joint_limit(scene, variant):
    """A Reach target that the arm can only approach by driving panda_joint4 through its upper limit."""
    x = scene.default_state()
    i = scene.joint_names.index("panda_joint4")
    x[i] = scene.q_upper[i] - 0.05
    q_goal = x[: scene.nq].copy()
    q_goal[i] = scene.q_upper[i] + 0.5
    target = scene.fk(q_goal, "grasp")
    task = sabre.tasks.Reach(target_pose=target, safety=sabre.tasks.SafetyWeights(joint_limit=0.0, joint_limit_slope=0.0))
    config = sabre.ControllerConfig(variant=variant, seed=1, rollouts=16, safety=sabre.SafetyConfig(base_box=None))
    return x, i, sabre.Controller(scene, task, config)


def test_sequential_filter_keeps_the_plan_inside_the_joint_limit(scene):
    """Algorithm 1: with the sequential filter (O) the optimised sequence keeps panda_joint4 inside
    its limit (the joint integrates its commanded velocity; the rollout model itself clamps at the
    limit, so the command is what tells); without it (N) the plan drives through."""
    worst = {}
    for variant in ("N", "O"):
        x, i, controller = _reach_beyond_joint_limit(scene, variant)
        for k in range(15):
            controller.update(x, k * 0.015)
        commanded = x[i] + np.cumsum(controller.nominal[:, i]) * controller.config.dt
        worst[variant] = commanded.max() - scene.q_upper[i]
    assert worst["N"] > 0.0
    assert worst["O"] <= 1e-3


def test_inner_filter_and_tank_in_run_episode(scene):
    """Variant I: the tracked command is the filtered reference, within the velocity limits, and
    the tank integrates S = S0 + ∫ τ_extᵀ u dt (free motion: no exchange, so S stays at S0)."""
    controller = sabre.Controller(scene, sabre.tasks.OpenObject(), sabre.ControllerConfig(variant="I", rollouts=16, seed=2))
    episode = sabre.run_episode(scene, controller, 0.6, replan_rate=50.0, record_every=5, progress=False)
    m = len(episode.time)
    assert episode.command.shape == (m, scene.nu) and episode.tank_energy.shape == (m,)
    assert np.all(np.abs(episode.command) <= scene.dq_limit + 1e-9)
    # From the paper's start, the base is outside the box: the filter must change the command.
    assert np.abs(episode.command - episode.reference).max() > 1e-3
    assert episode.filter_fallbacks == 0
    np.testing.assert_allclose(episode.tank_energy, 10.0, atol=1e-9)
    assert episode.violations()["base_box"] > 0.0


def test_realtime_cascade_plans_in_the_background_while_ticking(scene):
    """The inner loop drives the plant at its rate while the outer loop plans on its own thread:
    start() plans once before returning, further plans arrive while the inner loop ticks, and every
    tick returns finite commands inside the limits. The loop ticks until two background plans have
    arrived (at least 400 ticks), so the check does not depend on how fast the machine is; a
    planner that died would raise from the next tick."""
    controller = sabre.Controller(scene, sabre.tasks.OpenObject(), sabre.ControllerConfig(variant="IO", rollouts=16, seed=3))
    plant = sabre.Plant(scene)
    low = sabre.LowLevelController(scene, dt=plant.dt)
    x0 = scene.default_state()
    plant.reset(x0)
    with sabre.RealtimeCascade(controller, low_level=low, inner_dt=plant.dt).start(x0) as cascade:
        assert cascade.iterations >= 1
        assert np.all(np.isfinite(cascade.reference(0.0)))
        ticks = 0
        while ticks < 400 or cascade.iterations < 3:
            r = cascade.tick(plant.state, plant.measured_tau_ext, plant.time)
            assert np.all(np.isfinite(r.command)) and np.all(np.abs(r.command) <= scene.dq_limit + 1e-9)
            plant.step(r.torque)
            ticks += 1
            assert cascade.running
    assert not cascade.running
    assert cascade.iterations >= 3 and cascade.ticks == ticks


class _TwoPhaseReach(sabre.tasks.Reach):
    """A Reach whose phase flips at t = 0.1 s and asks for a gain floor only in the second phase."""

    phases = ("free", "stiff")

    def next_phase(self, scene, x, t, phase):
        return "stiff" if t >= 0.1 - 1e-9 else "free"

    def gain_inertia_floor(self, phase):
        return 0.1 if phase == "stiff" else None


def test_run_episode_hands_over_the_task_gain_floor_per_phase_and_keeps_the_controllers_own(scene):
    """Each plan handed to the cascade carries the task's floor for its planned phase (the cascade's tick
    applies it), None where the task has none, and the low-level controller's own floor (0.01 here) is
    never changed, also by an episode that raises."""
    task = _TwoPhaseReach(target_pose=scene.fk(scene.default_state()[: scene.nq], "grasp"))
    controller = sabre.Controller(scene, task, sabre.ControllerConfig(rollouts=8, seed=0))
    plant = sabre.Plant(scene)
    low = sabre.LowLevelController(scene, dt=plant.dt, gain_inertia_floor=0.01)
    seen = []
    sabre.run_episode(
        scene,
        controller,
        0.2,
        x0=scene.default_state(),
        replan_rate=20.0,
        plant=plant,
        low_level=low,
        progress=False,
        on_replan=lambda t, x, p, c: seen.append((round(t, 6), c.snapshot().gain_inertia_floor, low.gain_inertia_floor)),
    )
    # Each entry is read before the re-plan at t, so it is the floor of the plan made at t − 0.05.
    assert seen[1:] == [(0.05, None, 0.01), (0.1, None, 0.01), (0.15, 0.1, 0.01)]
    assert low.gain_inertia_floor == 0.01

    # An episode that raises inside the task's phase with a floor still hands the controller back
    # with its own floor.
    def stop_late(t, x, p, c):
        if t > 0.17:
            raise RuntimeError("stopped by the test")

    controller = sabre.Controller(scene, task, sabre.ControllerConfig(rollouts=8, seed=0))
    with pytest.raises(RuntimeError, match="stopped by the test"):
        sabre.run_episode(
            scene,
            controller,
            0.3,
            x0=scene.default_state(),
            replan_rate=20.0,
            plant=plant,
            low_level=low,
            progress=False,
            on_replan=stop_late,
        )
    assert low.gain_inertia_floor == 0.01
    with pytest.raises(InvalidValueError):
        low.gain_inertia_floor = -1.0
    with pytest.raises(InvalidValueError):
        low.gain_inertia_floor = float("nan")


def test_open_object_stiffens_the_hand_only_while_opening_or_holding():
    task = sabre.tasks.OpenObject(open=sabre.tasks.OpenConfig(gain_inertia_floor=0.03))
    floors = {p: task.gain_inertia_floor(p) for p in task.phases}
    assert floors == {"approach": None, "insert": None, "hook": None, "open": 0.03, "release": None, "hold": 0.03}
    assert sabre.tasks.OpenObject().gain_inertia_floor("open") is None
    with pytest.raises(InvalidValueError):
        sabre.tasks.OpenConfig(gain_inertia_floor=-0.1)


def test_realtime_cascade_ticks_with_the_task_gain_floor_of_the_planned_phase(scene):
    """The tick's torque is the low-level controller's with the floor of the plan's phase (the task's, else
    the controller's own, 0.01 here), and the controller keeps its own floor."""
    task = _TwoPhaseReach(target_pose=scene.fk(scene.default_state()[: scene.nq], "grasp"))
    x0 = scene.default_state()
    torques = {}
    for t0, floor, expected in ((0.0, None, 0.01), (0.2, 0.1, 0.1)):
        controller = sabre.Controller(scene, task, sabre.ControllerConfig(rollouts=8, seed=0))
        low = sabre.LowLevelController(scene, gain_inertia_floor=0.01)
        with sabre.RealtimeCascade(controller, low_level=low).start(x0, t0=t0) as cascade:
            r = cascade.tick(x0, np.zeros(scene.nq), t0)
            assert cascade.current_plan.gain_inertia_floor == floor
        by_hand = sabre.LowLevelController(scene, gain_inertia_floor=expected)
        np.testing.assert_array_equal(r.torque, by_hand.torque(x0, r.command))
        assert low.gain_inertia_floor == 0.01
        torques[expected] = (r.torque, sabre.LowLevelController(scene, gain_inertia_floor=0.01).torque(x0, r.command))
    with_floor, without = torques[0.1]
    assert np.abs(with_floor - without).max() > 1e-3  # the floor changed the torque


def test_iteration_stats_report_the_sequential_filter_only_with_the_outer_loop(scene):
    """IterationStats.sequential_time/fallbacks are None without the outer filter; with it they
    are set, and the sequential time is part of the iteration time."""
    x = scene.default_state()
    for variant, outer in (("N", False), ("O", True)):
        controller = sabre.Controller(
            scene, sabre.tasks.OpenObject(), sabre.ControllerConfig(variant=variant, rollouts=8, seed=1)
        )
        assert controller.stats is None
        stats = controller.update(x, 0.0)
        assert isinstance(stats, sabre.IterationStats) and controller.stats is stats
        assert stats.phase == controller.phase and stats.iteration == 1
        if outer:
            assert stats.sequential_fallbacks == 0
            assert 0.0 < stats.sequential_time <= stats.iteration_time
        else:
            assert stats.sequential_time is None and stats.sequential_fallbacks is None


def test_episode_knows_the_opening_target_and_plots_it(scene, tmp_path):
    """run_episode with OpenObject records the target and success openings of the task, and
    plot_episode writes a PNG of the episode."""
    pytest.importorskip("matplotlib")
    task = sabre.tasks.OpenObject()
    controller = sabre.Controller(scene, task, sabre.ControllerConfig(rollouts=8, seed=1))
    episode = sabre.run_episode(scene, controller, 0.2, replan_rate=50.0, record_every=10, progress=False)
    assert episode.target_opening == pytest.approx(task.target_opening(scene))
    assert episode.success_opening == pytest.approx(task.open.success_fraction * task.target_opening(scene))
    path = tmp_path / "episode.png"
    sabre.plot_episode(episode, path)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_realtime_tick_refills_the_tank_only_while_the_measured_power_matches_the_plan(scene):
    """The cascade's tick refills like the simulated inner loop: τ_ext chosen so that −τ_extᵀu_ref
    equals the plan's predicted port power refills the tank; ten times that power does not."""
    refilled = {}
    for factor in (1.0, 10.0):
        controller = sabre.Controller(
            scene, sabre.tasks.OpenObject(), sabre.ControllerConfig(variant="IO", rollouts=8, horizon=0.3, seed=0, threads=1)
        )
        x = scene.default_state()
        rt = sabre.RealtimeCascade(controller)
        planned = rt.plan(x, 0.0)
        # The plan's own prediction is zero (no contact from here): give it a pull of 1 W to compare with.
        rt.hand_over(sabre.PlanSnapshot.of(planned.nominal, planned.t0, planned.dt, predicted=np.ones(len(planned.nominal))))
        controller.tank.step(np.full(scene.nq, -1.0) / scene.nq, np.ones(scene.nq), 3.0)  # spend 3 J
        for k in range(200):
            u_ref = rt.reference(0.001 * k)
            tau = -factor * u_ref / max(float(u_ref @ u_ref), 1e-12)  # −τᵀu_ref = factor W
            rt.tick(x, tau, 0.001 * k, dt=0.001)
        refilled[factor] = controller.tank.refilled
    assert refilled[1.0] > 0.1
    assert refilled[10.0] < 0.01


def _moved_and_prediction_error(scene, seed: int) -> list[tuple[float, float]]:
    """After 20 re-plannings of the approach (seed ``seed``), for plan delays of 30, 50 and 90 ms:
    how far the plant moves following the plan, and how far the rollout model's prediction from
    the state at the start lands from where it ends."""
    controller = sabre.Controller(scene, sabre.tasks.OpenObject(), sabre.ControllerConfig(seed=seed))
    plant = sabre.Plant(scene)
    low = sabre.LowLevelController(scene, dt=plant.dt)
    plant.reset(sabre.paper.paper_start_state(scene))
    assert controller.predict(plant.state, 0.0, 0.03)[1] == 0.0  # no plan yet: nothing to predict with
    for _ in range(20):
        controller.update(plant.state, plant.time)
        low.follow(plant, controller.nominal, controller.nominal_t0, controller.config.dt, 20)
    x, t = plant.state, plant.time
    controller.update(x, t)
    nq = scene.nq
    outcomes = []
    for delay, steps in ((0.03, 2), (0.05, 3), (0.09, 6)):
        predicted, at = controller.predict(x, t, delay)
        assert at == pytest.approx(t + steps * controller.config.dt)
        follower = sabre.Plant(scene)
        follower.reset(x)  # its clock starts at 0: the plan is shifted by t
        sabre.LowLevelController(scene, dt=follower.dt).follow(
            follower, controller.nominal, controller.nominal_t0 - t, controller.config.dt, int(round((at - t) / follower.dt))
        )
        moved = np.abs(follower.state[:nq] - x[:nq]).max()
        outcomes.append((moved, np.abs(predicted[:nq] - follower.state[:nq]).max()))
    same, at = controller.predict(x, t, 0.004)  # under half a planning step: the state itself
    assert at == t and np.array_equal(same, x)
    with pytest.raises(InvalidValueError, match="delay"):
        controller.predict(x, t, -0.01)
    return outcomes


def test_predict_puts_the_planning_state_near_where_the_plant_is_when_the_plan_takes_over(scene):
    """Moving in free space, the plant follows the plan for 30–90 ms; the rollout model's
    prediction from the state at the start lands within a third of the distance the robot covered,
    typically within a fifth (planning from the measured state would be off by all of it)."""
    outcomes = [o for seed in (0, 1, 2) for o in _moved_and_prediction_error(scene, seed)]
    moved = np.array([m for m, _ in outcomes])
    share = np.array([e / m for m, e in outcomes])
    assert np.all(moved > 0.01), moved  # the robot is moving: 0.3 m/s or rad/s and more
    assert np.all(share < 0.33), share
    assert np.median(share) < 0.2, share


def test_run_episode_without_plan_delay_is_unchanged_and_refuses_a_delay_past_the_period(scene):
    def episode(**kw):
        c = sabre.Controller(scene, sabre.tasks.OpenObject(), sabre.ControllerConfig(seed=2, rollouts=16))
        return sabre.run_episode(scene, c, 0.3, replan_rate=20.0, progress=False, **kw)

    plain, zero = episode(), episode(plan_delay=0.0)
    np.testing.assert_array_equal(plain.state, zero.state)
    np.testing.assert_array_equal(plain.command, zero.command)
    delayed = episode(plan_delay=0.02)
    assert delayed.state.shape == plain.state.shape and not np.array_equal(delayed.state, plain.state)
    with pytest.raises(InvalidValueError, match="plan_delay"):
        episode(plan_delay=0.06)


def test_with_a_planning_delay_the_compensated_planner_opens_the_dishwasher_about_as_fast_as_without():
    """Each plan takes over 35 ms after the state it was made from (the bridge's planner runs at
    about that rate on two cores), the previous plan running meanwhile. Planning from the state
    predicted for the takeover opens the dishwasher within 15 % of the undelayed run's time;
    planning from the measured state takes more than half as long again (the hand lets go of the
    falling door late and hauls it back)."""
    scene = sabre.Scene.load(obj="dishwasher")
    rate = 1 / 0.035

    def time_to_open(duration, **kw):
        c = sabre.Controller(scene, sabre.tasks.OpenObject(), sabre.ControllerConfig(seed=1, variant="IO"))
        ep = sabre.run_episode(scene, c, duration, seed=1, replan_rate=rate, progress=False, **kw)
        return ep.time_to_success if ep.success else math.inf

    undelayed = time_to_open(20.0)
    compensated = time_to_open(20.0, plan_delay=0.035)
    uncompensated = time_to_open(1.5 * undelayed + 0.5, plan_delay=0.035, delay_compensation=False)
    print(f"time to open: undelayed {undelayed:.2f} s, compensated {compensated:.2f} s, uncompensated {uncompensated:.2f} s")
    assert undelayed < 20.0
    assert compensated <= 1.15 * undelayed
    assert uncompensated > 1.5 * undelayed


class _RecordingReach(sabre.tasks.Reach):
    """A Reach that records the state its phase switch and its costs are given."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.phase_states: list[np.ndarray] = []

    def next_phase(self, scene, x, t, phase):
        self.phase_states.append(np.array(x))
        return phase


def test_a_plan_from_a_prediction_switches_phase_on_the_measured_state(scene):
    """With a compensated delay, run_episode plans from the state predicted for the takeover, and the
    task's phase switch reads the plant's state it was predicted from (a slip or a stalled hook is a
    measured contact event); without ``observed``, update reads the state it plans from."""
    task = _RecordingReach(target_pose=scene.fk(scene.default_state()[: scene.nq], "grasp"))
    controller = sabre.Controller(scene, task, sabre.ControllerConfig(rollouts=8, seed=0))
    measured = []
    sabre.run_episode(
        scene,
        controller,
        0.2,
        x0=scene.default_state(),
        replan_rate=20.0,
        plan_delay=0.02,
        progress=False,
        on_replan=lambda t, x, p, c: measured.append(np.array(x)),
    )
    assert len(task.phase_states) == len(measured) >= 3
    for seen, x in zip(task.phase_states, measured):
        np.testing.assert_array_equal(seen, x)
    x, t = task.phase_states[-1], 0.2
    predicted, _ = controller.predict(x, t, 0.02)
    assert not np.allclose(predicted, x)  # the prediction moved: the test tells the two apart
    task.phase_states.clear()
    controller.update(predicted, t + 0.02, observed=x)
    controller.update(predicted, t + 0.04)
    np.testing.assert_array_equal(task.phase_states[0], x)
    np.testing.assert_array_equal(task.phase_states[1], predicted)
