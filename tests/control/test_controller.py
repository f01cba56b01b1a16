"""The sampler, its likelihood mapping, cost composition and the controller on small tasks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from se3_reference import se3_log

import sabre
from sabre import costs, guides
from sabre.errors import InvalidValueError

ASSETS = Path(__file__).resolve().parents[2] / "assets"


@pytest.fixture(scope="module")
def scene():
    return sabre.Scene.load(obj="shelf")


def _ess(w: np.ndarray) -> float:
    return 1.0 / np.sum(w**2) if np.any(w > 0) else 0.0


@pytest.mark.parametrize("scale", [1.0, 100.0, 1e4])
def test_likelihood_mapping_at_high_cost_scale(scale):
    """Paper Fig. 3: costs uniform between J_max·0.8 and J_max. With λ = h = 10, once J_max is large the
    naive and baseline-subtracted mappings put all weight on one sample, the invariant one does not."""
    costs_ = np.linspace(0.8 * scale, scale, 40)
    naive = sabre.paper.likelihood_weights(costs_, "naive", 10.0)
    baseline = sabre.paper.likelihood_weights(costs_, "baseline", 10.0)
    invariant = sabre.paper.likelihood_weights(costs_, "invariant", 10.0)
    # Independent reference for (55): exp(−h (J − J_min)/(J_max − J_min)) normalised.
    reference = np.exp(-10.0 * (costs_ - costs_.min()) / (costs_.max() - costs_.min()))
    np.testing.assert_allclose(invariant, reference / reference.sum(), rtol=1e-12)
    assert _ess(invariant) > 7.0  # ≈ 7.6 for 40 uniform costs, whatever the scale
    if scale >= 100.0:
        assert _ess(baseline) < 1.05
        # exp(−10 · J) underflows or collapses: the naive mapping keeps at most one sample.
        assert _ess(naive) <= 1.05
    else:
        assert _ess(baseline) > 1.5


def test_invariant_weights_ignore_non_finite_costs():
    w = sabre.paper.likelihood_weights([1.0, np.nan, 2.0, np.inf, 3.0], "invariant", 10.0)
    assert w[1] == 0.0 and w[3] == 0.0
    assert w.sum() == pytest.approx(1.0)
    with pytest.raises(InvalidValueError):
        sabre.paper.likelihood_weights([1.0, 2.0], "exotic", 1.0)


def test_costs_compose_and_validate(scene):
    cost = costs.TargetPose(np.eye(4)) + costs.JointLimits() + costs.Power()
    assert isinstance(cost, costs.Cost) and len(cost.terms) == 3
    compiled = cost.compile(scene)
    assert compiled.core.num_terms == 3 and not compiled.python_terms
    assert len((sum([costs.Contact(), costs.Power()])).terms) == 2
    with pytest.raises(sabre.UnknownFrameError):
        costs.TargetPose(np.eye(4), frame="no_such_frame").compile(scene)
    with pytest.raises(sabre.ShapeError):
        costs.ObjectState([0.1, 0.2]).compile(scene)
    with pytest.raises(InvalidValueError):
        costs.Contact(weight=-1.0).compile(scene)
    with pytest.raises(InvalidValueError):
        costs.PythonTerm(function=None)


def _reach(scene, seed=0, threads=None, extra=None, rollouts=24):
    extra = costs.Cost() if extra is None else extra
    q0 = scene.home_configuration()
    target = scene.fk(q0, "grasp")
    target[:3, 3] += [0.15, 0.10, -0.05]  # 19 cm away, same orientation
    task = sabre.tasks.Reach(frame="grasp", target_pose=target, extra=extra)
    controller = sabre.Controller(scene, task, sabre.ControllerConfig(seed=seed, threads=threads, rollouts=rollouts))
    return task, controller, target


def test_controller_closes_70_percent_of_the_distance_to_a_target_in_the_rollout_model(scene):
    """Closed loop on the rollout model itself (update, then apply the reference for one step):
    after 300 iterations the grasp frame is within 30 % of its starting distance to the target."""
    _task, controller, target = _reach(scene)
    model = sabre.RolloutModel(scene)
    x = scene.default_state()
    start = np.linalg.norm(scene.fk(x[: scene.nq], "grasp")[:3, 3] - target[:3, 3])
    for i in range(300):
        t = i * model.dt
        controller.update(x, t)
        x = model.rollout(x, controller.nominal[None, :1]).states[0, -1]
    end = np.linalg.norm(scene.fk(x[: scene.nq], "grasp")[:3, 3] - target[:3, 3])
    assert end < 0.3 * start
    stats = controller.stats
    assert stats.iteration == 300
    assert 1.0 < stats.effective_sample_size < 24.0 and stats.failed_rollouts == 0
    assert 0 <= stats.engine_steps <= controller.config.rollouts * controller.config.horizon_steps
    assert (stats.engine_time > 0.0) == (stats.engine_steps > 0)
    assert 0.0 < stats.rollout_time <= stats.iteration_time


def test_planning_is_deterministic_for_a_seed_whatever_the_thread_count(scene):
    x = scene.default_state()
    noms = []
    for threads in (1, 2):
        _, controller, _ = _reach(scene, seed=5, threads=threads)
        for i in range(5):
            controller.update(x, 0.02 * i)
        noms.append(controller.nominal.copy())
    np.testing.assert_array_equal(noms[0], noms[1])
    _, other, _ = _reach(scene, seed=6)
    for i in range(5):
        other.update(x, 0.02 * i)
    assert not np.array_equal(other.nominal, noms[0])


class _Recording(sabre.tasks.Task):
    """One phase whose only cost is a PythonTerm that records every batch's inputs (N, K, nu) and
    returns ``cost(inputs)``; a fixed noise scale, and guides offered for the next batch only."""

    phases = ("main",)

    def __init__(self, cost=None, noise_scale=1.0, guides=None):
        self.batches = []
        self.cost_of = cost if cost is not None else (lambda u: np.zeros(u.shape[0]))
        self.scale = noise_scale
        self.pending_guides = guides

    def _record(self, batch):
        self.batches.append(batch.inputs.copy())
        return self.cost_of(batch.inputs)

    def cost(self, scene, phase):
        return costs.Cost([costs.PythonTerm(function=self._record)])

    def noise_scale(self, scene, x, phase):
        return self.scale

    def guides(self, scene, x, phase, steps, dt):
        guides, self.pending_guides = self.pending_guides, None
        return guides


def _first_batch(scene, task, **config):
    """The batch of one planning iteration from the default state at t = 0."""
    controller = sabre.Controller(scene, task, sabre.ControllerConfig(**config))
    controller.update(scene.default_state(), 0.0)
    return task.batches[-1]


def test_nominal_and_zero_sequences_are_always_sampled(scene):
    task = _Recording(cost=lambda u: u.sum(axis=(1, 2)))  # any cost that moves the nominal
    controller = sabre.Controller(scene, task, sabre.ControllerConfig(rollouts=24, seed=0))
    x = scene.default_state()
    controller.update(x, 0.0)
    nominal = controller.nominal.copy()
    assert np.any(nominal != 0.0)
    controller.update(x, 0.0)  # same time: no shift
    batch = task.batches[-1]
    np.testing.assert_array_equal(batch[0], nominal)
    np.testing.assert_array_equal(batch[1], 0.0)
    assert np.all(np.abs(batch) <= scene.dq_limit + 1e-12)  # projected onto the input limits


def test_a_nominal_set_by_hand_is_the_one_the_next_batch_samples_around(scene):
    """set_nominal replaces the plan (nominal, nominal_t0 and the reference report it) and the next
    update at that time samples it as its first rollout; a wrong shape or a NaN is refused."""
    task = _Recording(cost=lambda u: u.sum(axis=(1, 2)))
    controller = sabre.Controller(scene, task, sabre.ControllerConfig(rollouts=24, seed=0))
    k, nu = controller.config.horizon_steps, scene.nu
    plan = np.clip(np.random.default_rng(3).normal(0.0, 0.1, (k, nu)), -scene.dq_limit, scene.dq_limit)
    controller.set_nominal(plan, 2.0)
    np.testing.assert_array_equal(controller.nominal, plan)
    assert controller.nominal_t0 == 2.0
    np.testing.assert_allclose(controller.reference(2.0 + 1.5 * controller.config.dt), 0.5 * (plan[1] + plan[2]), rtol=1e-9)
    controller.update(scene.default_state(), 2.0)
    np.testing.assert_array_equal(task.batches[-1][0], plan)
    with pytest.raises(sabre.ShapeError):
        controller.set_nominal(plan[:-1], 0.0)
    bad = plan.copy()
    bad[0, 0] = np.nan
    with pytest.raises(InvalidValueError):
        controller.set_nominal(bad, 0.0)
    with pytest.raises(InvalidValueError):
        controller.set_nominal(plan, float("inf"))


def test_reference_interpolates_the_nominal_linearly(scene):
    _, controller, _ = _reach(scene)
    controller.update(scene.default_state(), 1.0)
    u, t0, dt = controller.nominal, controller.nominal_t0, controller.config.dt
    np.testing.assert_allclose(controller.reference(t0 + 2.5 * dt), 0.5 * (u[2] + u[3]), rtol=1e-12)
    np.testing.assert_allclose(controller.reference(t0 - 1.0), u[0])
    np.testing.assert_allclose(controller.reference(t0 + 100.0), u[-1])


def test_python_term_is_added_to_the_rollout_costs(scene):
    """A user term that heavily penalises any base motion keeps the base still while reaching."""
    calls = []

    def no_base_motion(batch: costs.Batch) -> np.ndarray:
        calls.append(batch.states.shape)
        assert batch.frames["grasp"].shape == batch.states.shape[:2] + (4, 4)
        return 1e4 * np.abs(batch.states[:, :, :2] - batch.states[:, :1, :2]).sum(axis=(1, 2))

    x0 = scene.default_state()
    results = {}
    for label, extra in (("free", costs.Cost()), ("held", costs.Cost([costs.PythonTerm(no_base_motion, frames=("grasp",))]))):
        _, controller, _ = _reach(scene, extra=extra)
        model = sabre.RolloutModel(scene)
        x = x0.copy()
        for i in range(60):
            controller.update(x, i * model.dt)
            x = model.rollout(x, controller.nominal[None, :1]).states[0, -1]
        results[label] = np.linalg.norm(x[:2] - x0[:2])
        # With a Python term the rollouts run apart from the update; they are timed all the same.
        assert 0.0 < controller.stats.rollout_time <= controller.stats.iteration_time
    assert calls and calls[0][0] == 24
    assert results["held"] < 0.5 * results["free"]


def test_controller_config_validation():
    with pytest.raises(InvalidValueError):
        sabre.ControllerConfig(rollouts=2)
    with pytest.raises(InvalidValueError):
        sabre.ControllerConfig(horizon=0.001)
    with pytest.raises(InvalidValueError):
        sabre.ControllerConfig(keep_fraction=1.5)
    with pytest.raises(InvalidValueError):
        sabre.ControllerConfig(sigma=(1.0, -1.0))
    assert sabre.ControllerConfig().horizon_steps == 67


def test_open_object_phases_switch_on_the_approach_pose(scene):
    task = sabre.tasks.OpenObject()
    x = scene.default_state()
    assert task.next_phase(scene, x, 0.0, "approach") == "approach"
    assert task.target_opening(scene) == pytest.approx(0.75 * scene.o_upper[0])
    assert not task.success(scene, x)
    x_open = x.copy()
    x_open[2 * scene.nq] = 0.95 * task.target_opening(scene)
    assert task.success(scene, x_open)


def test_run_episode_closes_the_loop_on_the_plant(scene):
    """A short closed-loop reach on the 1 kHz plant: traces have the documented shapes, time runs at
    the plant rate, the plant follows the controller's reference, and the grasp frame approaches."""
    _task, controller, target = _reach(scene, rollouts=16)
    x0 = scene.default_state()
    episode = sabre.run_episode(scene, controller, 1.5, x0=x0, replan_rate=50.0, record_every=5, progress=False)
    m = len(episode.time)
    assert m == 300  # 1.5 s at 1 kHz, every 5th step
    np.testing.assert_allclose(np.diff(episode.time), 0.005, atol=1e-9)
    assert episode.state.shape == (m, scene.nx) and episode.reference.shape == (m, scene.nu)
    assert episode.wrench.shape == (m, 6) and episode.tau_ext.shape == (m, scene.nq)
    assert episode.phase.shape == (m,) and set(episode.phase) == {0}
    assert len(episode.planning_times) == 75
    # The low-level controller tracks the reference: velocities lag it by little.
    late = slice(m // 2, None)
    err = np.abs(episode.state[late, scene.nq : 2 * scene.nq] - episode.reference[late])
    assert np.median(err) < 0.02
    start = np.linalg.norm(scene.fk(x0[: scene.nq], "grasp")[:3, 3] - target[:3, 3])
    end = np.linalg.norm(scene.fk(episode.state[-1, : scene.nq], "grasp")[:3, 3] - target[:3, 3])
    assert end < 0.8 * start


def test_paper_start_state(scene):
    x = sabre.paper.paper_start_state(scene)
    assert x.shape == (scene.nx,)
    assert x[0] == -3.0 and x[1] == -3.0
    q = x[: scene.nq]
    assert np.all(q >= scene.q_lower) and np.all(q <= scene.q_upper)
    # Near the joint limits: the elbow within 0.15 rad of its fully folded limit.
    assert q[6] - scene.q_lower[6] < 0.15


def test_input_limit_bounds_every_sample(scene):
    limit = [0.2, 0.2, 1.0] + [1.0] * 7
    samples = _first_batch(scene, _Recording(), rollouts=40, input_limit=tuple(limit))
    assert np.all(np.abs(samples) <= np.asarray(limit) + 1e-12)
    # With σ = 1 on the arm, the bound is reached: the projection is doing the work.
    assert np.isclose(np.abs(samples[..., 5]).max(), 1.0)
    with pytest.raises(InvalidValueError):
        sabre.ControllerConfig(input_limit=(0.2, -1.0))
    with pytest.raises(sabre.errors.ShapeError):
        sabre.Controller(scene, _Recording(), sabre.ControllerConfig(input_limit=(1.0,) * 3))


def test_noise_scale_scales_the_fresh_samples(scene):
    """Around a zero nominal, fresh samples are N(0, s·Σ): their spread scales with √s."""
    spreads = []
    sigma = (0.01,) * 3 + (0.04,) * 7  # far inside the velocity limits: no projection
    for s in (1.0, 0.01):
        batch = _first_batch(scene, _Recording(noise_scale=s), rollouts=40, sigma=sigma)
        fresh = batch[2:]  # after the nominal and the zero sequence
        spreads.append(fresh.reshape(-1, scene.nu).std(axis=0))
    ratio = spreads[1] / spreads[0]
    np.testing.assert_allclose(ratio, 0.1, rtol=0.05)
    np.testing.assert_allclose(spreads[0], np.sqrt(sigma), rtol=0.05)
    controller = sabre.Controller(scene, _Recording(noise_scale=-1.0))
    with pytest.raises(InvalidValueError):
        controller.update(scene.default_state(), 0.0)


class _ZeroSequenceCost:
    """The cost of holding still for one rollout step from x under a single cost term: the first
    iteration of a freshly reset one-step planner rolls its zero nominal out as sample 0, and its
    statistics report that sample's cost."""

    def __init__(self, scene, term):
        task = _Recording()
        task.cost = lambda scene, phase: costs.Cost([term])
        self.controller = sabre.Controller(scene, task, sabre.ControllerConfig(rollouts=3, horizon=0.015))

    def __call__(self, x):
        self.controller.reset()
        return self.controller.update(x, 0.0).nominal_cost


@pytest.mark.parametrize(
    "opening, lead, limit, expected",
    [(0.1, 0.0, 10.0, 0.1), (0.1, 0.2, 10.0, 0.3), (0.1, 0.2, 0.25, 0.25), (0.4, 0.2, 0.25, 0.4)],
)
def test_pose_target_leads_along_the_articulation(scene, opening, lead, limit, expected):
    """The pose cost of a one-step horizon from rest equals ‖log(T⁻¹ T*)‖²_W with T* the handle
    frame at the leading opening (capped at the limit unless already past it)."""
    offset = np.eye(4)
    offset[:3, 3] = [0.0, 0.0, -0.05]
    weights = (1.0, 2.0, 3.0, 4.0, 5.0, 6.0)
    term = costs.TargetPose(offset, "grasp", "handle_frame", weights=weights, lead=lead, lead_limit=limit)
    x = scene.default_state()
    x[2 * scene.nq] = opening
    cost = _ZeroSequenceCost(scene, term)(x)  # the robot holds still
    target = scene.object_fk(np.array([expected]), "handle_frame") @ offset
    xi = se3_log(np.linalg.solve(scene.fk(x[: scene.nq], "grasp"), target))
    assert cost == pytest.approx(float(np.sum(np.asarray(weights) * xi**2)), rel=2e-3)
    with pytest.raises(InvalidValueError):
        costs.TargetPose(offset, "grasp", None, lead=0.1).spec(scene)


def test_guides_enter_the_next_batch_once(scene):
    """Guides sit after the nominal and the zero sequence in the next batch only, projected onto
    the input limits like every sample; wrong shapes and non-finite values are refused, and no
    more than rollouts − 2 guides are used."""
    config = sabre.ControllerConfig(rollouts=8, keep_fraction=0.0, seed=0)
    k = config.horizon_steps
    rng = np.random.default_rng(0)
    guides = 0.1 * rng.standard_normal((3, k, scene.nu))
    guides[0, 0, 3] = 100.0  # beyond every velocity limit
    task = _Recording(guides=guides)
    controller = sabre.Controller(scene, task, config)
    x = scene.default_state()
    controller.update(x, 0.0)
    controller.update(x, 0.0)
    first, again = task.batches
    expected = np.clip(guides, -scene.dq_limit, scene.dq_limit)
    np.testing.assert_array_equal(first[2:5], expected)
    assert not any(np.allclose(again[i], expected[j]) for i in range(2, 8) for j in range(3))
    many = 0.05 * rng.standard_normal((7, k, scene.nu))
    task.pending_guides = many
    controller.update(x, 0.0)
    np.testing.assert_array_equal(task.batches[-1][2:], many[:6])
    task.pending_guides = np.zeros((1, k + 1, scene.nu))
    with pytest.raises(sabre.errors.ShapeError):
        controller.update(x, 0.0)
    bad = np.zeros((1, k, scene.nu))
    bad[0, 3, 2] = np.nan
    task.pending_guides = bad
    with pytest.raises(sabre.errors.SabreError):
        controller.update(x, 0.0)


@pytest.fixture(scope="module")
def hooked(scene):
    """The plant after the scripted approach and hook (level hand), tip against the bar."""
    return sabre.paper.scenarios.hooked_state(scene)


def test_servo_guide_tracks_a_moving_target_on_the_kinematics(scene, hooked):
    """Integrating the guide's velocities (explicit Euler, as the guide assumes) brings the grasp
    frame onto a target moving along a circle, and never takes a joint past its limits."""
    from sabre.guides import servo_guide

    x = hooked
    start = scene.fk(x[: scene.nq], "grasp")
    dt, k = 0.015, 66
    # The target starts at the grasp frame and swings 0.4 rad about a vertical axis 0.27 m to the side.
    pivot = start[:3, 3] + np.array([0.0, 0.27, 0.0])
    targets = []
    for a in np.linspace(0.0, 0.4, k + 1):
        rot = np.eye(4)
        rot[:3, :3] = [[np.cos(a), np.sin(a), 0], [-np.sin(a), np.cos(a), 0], [0, 0, 1]]
        rot[:3, 3] = pivot - rot[:3, :3] @ pivot
        targets.append(rot @ start)
    targets = np.array(targets)
    u = servo_guide(scene, x[: scene.nq], targets, dt, max_linear=1.0, max_angular=2.0)
    assert u.shape == (k, scene.nu)
    q = x[: scene.nq] + dt * np.cumsum(u, axis=0)
    assert np.all(q >= scene.q_lower - 1e-9) and np.all(q <= scene.q_upper + 1e-9)
    assert np.all(np.abs(u) <= scene.dq_limit + 1e-12)
    final = scene.fk(q[-1], "grasp")
    assert np.linalg.norm(final[:3, 3] - targets[-1][:3, 3]) < 0.005
    cos = (np.trace(targets[-1][:3, :3].T @ final[:3, :3]) - 1.0) / 2.0
    assert np.arccos(np.clip(cos, -1.0, 1.0)) < 0.02
    # Without the feed-forward term (a target that jumps to the end) the servo lags behind.
    lagging = servo_guide(
        scene, x[: scene.nq], np.broadcast_to(targets[-1], targets.shape), dt, gain=0.5, max_linear=1.0, max_angular=2.0
    )
    q_lag = x[: scene.nq] + dt * lagging.sum(axis=0)
    assert np.linalg.norm(scene.fk(q_lag, "grasp")[:3, 3] - targets[-1][:3, 3]) > 0.02


def test_open_object_guides_follow_the_handle(scene, hooked):
    """From a hooked state, the opening guides, rolled out with the rollout model, open the door
    about as far as their handle speeds say (standing still does not); the approach guide moves
    the grasp frame toward its target."""
    task = sabre.tasks.OpenObject(approach=sabre.tasks.ApproachConfig(pitch=0.0))
    k, dt = 66, 0.015
    guides = task.guides(scene, hooked, "open", k, dt)
    assert guides.shape == (len(task.open.speeds), k, scene.nu)
    result = sabre.RolloutModel(scene).rollout(hooked, np.concatenate([guides, np.zeros((1, k, scene.nu))]))
    opened = result.states[:, -1, 2 * scene.nq] - hooked[2 * scene.nq]
    expected = np.asarray(task.open.speeds) * k * dt / task.handle_travel(scene, 0.0)
    np.testing.assert_allclose(opened[:2], expected, rtol=0.35)
    assert abs(opened[2]) < 0.02
    (approach,) = task.guides(scene, scene.default_state(), "approach", k, dt)
    start = task.approach_error(scene, scene.default_state(), "approach")
    distance, angle = start.distance, start.angle
    x_end = scene.default_state()
    x_end[: scene.nq] += dt * approach.sum(axis=0)
    end = task.approach_error(scene, x_end, "approach")
    distance_end, angle_end = end.distance, end.angle
    assert distance_end < distance - 0.05 and angle_end < 0.5 * angle
    assert (
        sabre.tasks.OpenObject(guide=sabre.tasks.GuideConfig(speed=0.0)).guides(scene, scene.default_state(), "approach", k, dt)
        is None
    )


def test_object_setpoint_clears_the_power_balance_within_the_objects_travel(scene):
    """The object cost's set-point lies beyond the requested opening by twice the gap where the
    power cost (36) cancels the object cost's pull: w_p τ_r / (W_o T), τ_r from the URDF; never past
    the object's upper limit (the shelf's balance lies past its stop, the microwave's short of it)."""
    task = sabre.tasks.OpenObject()
    travel = task.handle_travel(scene, 0.0)
    # Handle radius about the hinge from the URDF: bar 0.061 m out and 0.265 m across.
    assert travel == pytest.approx(np.hypot(0.061, 0.265), rel=1e-3)
    resisting = 4.0 + 2.0 * task.open.speeds[0] / travel  # shelf friction 4 N·m, damping 2
    gap = 10.0 * resisting / (100.0 * 1.0)
    assert task.target_opening(scene) + 2 * gap > 1.57
    assert task.object_setpoint(scene) == 1.57  # the shelf's URDF limit
    microwave = sabre.Scene.load(obj="microwave")
    gap = 10.0 * (0.5 + 1.0 * task.open.speeds[0] / task.handle_travel(microwave, 0.0)) / 100.0  # friction 0.5, damping 1
    assert task.object_setpoint(microwave) == pytest.approx(task.target_opening(microwave) + 2 * gap, rel=1e-3)
    assert task.object_setpoint(microwave) < 1.57
    assert sabre.tasks.OpenObject(open=sabre.tasks.OpenConfig(object_overshoot=0.1)).object_setpoint(scene) == pytest.approx(
        task.target_opening(scene) + 0.1
    )
    assert sabre.tasks.OpenObject(open=sabre.tasks.OpenConfig(object_overshoot=1.0)).object_setpoint(scene) == 1.57


def test_base_clearance_keeps_the_base_out_of_a_falling_door():
    """Dishwasher door lying open (at its limit): the base clearance cost switches on where the
    base's footprint cylinder (radius 0.53 m in the URDF, plus the margin) reaches the door's tip,
    computed here from the door box of the URDF (the points include the box's corners), and grows as
    w + w_s·p² with the penetration p."""
    scene = sabre.Scene.load(obj="dishwasher")
    term = costs.BaseClearance(margin=0.05, spacing=0.1, weight=100.0, weight_slope=1e4)
    zero_sequence_cost = _ZeroSequenceCost(scene, term)
    opening = scene.o_upper[0]
    tip = scene.object_fk(np.array([opening]), "door") @ np.array([0.015, 0.0, 0.58, 1.0])  # far edge of the door box
    reach = 0.53 + 0.05

    def cost(base_x):
        x = scene.default_state()
        x[0] = base_x
        x[2 * scene.nq] = opening
        return zero_sequence_cost(x)

    assert cost(tip[0] - reach - 0.2) == 0.0
    lo, hi = tip[0] - reach - 0.2, tip[0] - reach + 0.2
    assert cost(hi) > 0.0
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if cost(mid) == 0.0 else (lo, mid)
    assert abs(hi - (tip[0] - reach)) <= 2e-3
    # 0.1 m past the boundary the penetration is 0.1 m (to the step's drift of the door and base).
    deeper = cost(hi + 0.1)
    assert 100.0 + 1e4 * 0.098**2 <= deeper <= 100.0 + 1e4 * 0.102**2
    # A door that is closed is out of the way of a base in front of it.
    x = scene.default_state()
    x[0] = tip[0] - reach
    assert zero_sequence_cost(x) == 0.0
    with pytest.raises(InvalidValueError):
        costs.BaseClearance(spacing=0.0).compile(scene)
    with pytest.raises(sabre.UnknownFrameError):
        costs.BaseClearance(link="chassis").compile(scene)


def test_a_door_that_falls_open_is_released_not_held():
    """The dishwasher door (4 kg, centre of mass 0.29 m above the hinge and 0.015 m in front of it,
    0.5 N·m friction, from the URDF) opens by itself where gravity's torque beats friction; opening
    it then leads to the release phase, whose guide slides the finger out of the pocket and backs
    the hand off, and release ends when the door no longer opens by itself. A shelf door (vertical
    hinge) never falls open."""
    scene = sabre.Scene.load(obj="dishwasher")
    task = sabre.tasks.OpenObject()
    nq = scene.nq
    for opening in (0.0, 0.05, 0.3, 0.6, 1.0):
        x = scene.default_state()
        x[2 * nq] = opening
        net = 4.0 * 9.81 * (0.29 * np.sin(opening) - 0.015 * np.cos(opening)) - 0.5
        assert task.self_opening(scene, x) == (net > 0.0), opening
    x = scene.default_state()
    x[2 * nq] = 0.6  # hand far from the handle: slipped
    assert task.next_phase(scene, x, 0.0, "open") == "release"
    assert task.next_phase(scene, x, 0.0, "approach") == "release"
    assert task.next_phase(scene, x, 0.0, "release") == "release"
    # Far from the pocket there is no hook to undo: the hand backs straight off, half away from the
    # door (grasp −z), half away from the hinge axis (world y, at z = 0.07 m and the dishwasher's
    # x = 1.2 m), out of the door's sweep.
    (guide,) = task.guides(scene, x, "release", 66, 0.015)
    start = scene.fk(x[:nq], "grasp")
    end = scene.fk(x[:nq] + 0.015 * guide.sum(axis=0), "grasp")
    radial = start[:3, 3] - np.array([1.2, start[1, 3], 0.07])
    way = -start[:3, 2] + radial / np.linalg.norm(radial)
    way /= np.linalg.norm(way)
    expected = min(task.release.speed * 66 * 0.015, task.release.distance)
    np.testing.assert_allclose(end[:3, 3] - start[:3, 3], expected * way, atol=0.01)

    # The finger in the pocket, the door at 0.3 rad (past its balance point): released while
    # still hooked. The grasp frame is put on the open phase's target by running the servo guide.
    x[2 * nq] = 0.3
    handle = task.handle_pose(scene, x[2 * nq : 2 * nq + 1])
    target = handle @ task.grasp_offset(scene, "open")
    for _ in range(3):
        servo = guides.servo_guide(
            scene, x[:nq], np.repeat(target[None], 301, axis=0), 0.02, gain=3.0, max_linear=0.5, max_angular=1.0
        )
        x[:nq] += 0.02 * servo.sum(axis=0)
    start = scene.fk(x[:nq], "grasp")
    np.testing.assert_allclose(np.linalg.solve(handle, start), task.grasp_offset(scene, "open"), atol=1e-3)
    assert task.next_phase(scene, x, 0.0, "open") == "release"
    # The way it came in, in the handle's frame: first across the bar (y) to the insert offset's
    # sideways position, out of the pocket, then back (−z) to the pre-grasp offset's depth, clear of
    # the bar, the hand's orientation kept; then the straight back-off from there.
    relative = np.linalg.solve(handle, start)
    sideways = task.approach.insert_offset[1] - relative[1, 3]
    clear = relative[2, 3] - task.approach.pregrasp_offset[2]
    assert 0.0 < abs(sideways) < 0.05 and clear > 0.0
    step = task.release.speed * 0.015
    travel = np.minimum(step * np.arange(67), abs(sideways) + clear + task.release.distance)
    out = int(np.ceil((abs(sideways) + clear) / step - 1e-9))  # the first step clear of the bar
    assert 0 < out < 66
    path = task.release_path(scene, x, 66, 0.015)
    in_handle = np.linalg.solve(handle, path)
    np.testing.assert_allclose(
        in_handle[:out, 1, 3], relative[1, 3] + np.sign(sideways) * np.minimum(travel[:out], abs(sideways)), atol=1e-12
    )
    np.testing.assert_allclose(
        in_handle[:out, 2, 3], relative[2, 3] - np.clip(travel[:out] - abs(sideways), 0.0, clear), atol=1e-12
    )
    np.testing.assert_allclose(path[:, :3, :3], np.broadcast_to(start[:3, :3], (67, 3, 3)), atol=1e-12)
    corner = relative.copy()
    corner[1, 3] += sideways
    corner[2, 3] -= clear
    back = path[out:, :3, 3] - (handle @ corner)[:3, 3]
    np.testing.assert_allclose(back, np.outer(travel[out:] - abs(sideways) - clear, task.release_direction(scene, x)), atol=1e-12)
    (guide,) = task.guides(scene, x, "release", 66, 0.015)
    end = scene.fk(x[:nq] + 0.015 * guide.sum(axis=0), "grasp")
    np.testing.assert_allclose(end[:3, 3], path[-1, :3, 3], atol=0.01)
    # While unhooking, the targets ride on a door that keeps opening.
    x[2 * nq + 1] = 2.0
    moving = task.release_path(scene, x, 66, 0.015)
    ahead = task.handle_pose(scene, [0.3 + 2.0 * 0.015 * 2])
    np.testing.assert_allclose(np.linalg.solve(ahead, moving[2]), in_handle[2], atol=1e-9)
    x[2 * nq + 1] = 0.0
    x[2 * nq] = 0.0
    assert task.next_phase(scene, x, 0.0, "release") == "approach"
    shelf = sabre.Scene.load(obj="shelf")
    y = shelf.default_state()
    y[2 * shelf.nq] = 0.6
    assert not task.self_opening(shelf, y)
    assert task.next_phase(shelf, y, 0.0, "open") == "approach"


def test_stats_count_the_steps_that_went_through_the_physics_engine(scene, hooked):
    """From the hook on the handle the rollouts touch the door, so steps go through Rapier; the
    engine time summed over the workers fits inside their wall time, and the count is the same
    for any thread count (a count, not a timing)."""
    counts = []
    for threads in (1, 2):
        config = sabre.ControllerConfig(seed=4, threads=threads)
        controller = sabre.Controller(scene, sabre.tasks.OpenObject(), config)
        stats = controller.update(hooked, 0.0)
        assert 0 < stats.engine_steps <= config.rollouts * config.horizon_steps
        assert 0.0 < stats.engine_time <= threads * stats.rollout_time
        counts.append(stats.engine_steps)
    assert counts[0] == counts[1]
