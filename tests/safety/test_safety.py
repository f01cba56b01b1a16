"""The safety filter, energy tank, Sequential FILTER-QP and filtered inner loop through the Python API.

Independent references: the exported QP's own optimality conditions, finite differences of the
barriers, closed-form tank energies, and rollouts/plant runs of the filtered commands.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import sabre
from sabre.errors import InvalidValueError, ShapeError


@pytest.fixture
def safety_filter(scene, rng) -> sabre.SafetyFilter:
    f = sabre.SafetyFilter(scene)
    for _ in range(8):
        f.add_obstacle(rng.uniform([-0.5, -1.0, 0.2], [1.5, 1.0, 1.5]), rng.uniform(0.05, 0.3))
    return f


def random_state(scene, rng) -> np.ndarray:
    """A third of the coordinates near (or up to 5 cm beyond) a limit; base within ±2.2 m."""
    x = np.asarray(scene.default_state(), dtype=float)
    lower = np.maximum(scene.q_lower, -6.0)
    upper = np.minimum(scene.q_upper, 6.0)
    lower[:2], upper[:2] = -2.2, 2.2
    q = rng.uniform(lower, upper)
    near = rng.random(scene.nq) < 0.33
    side = rng.random(scene.nq) < 0.5
    q[near & side] = lower[near & side] + rng.uniform(-0.05, 0.1, (near & side).sum())
    q[near & ~side] = upper[near & ~side] - rng.uniform(-0.05, 0.1, (near & ~side).sum())
    x[: scene.nq] = q
    x[scene.nq : 2 * scene.nq] = rng.uniform(-0.5, 0.5, scene.nq)
    return x


def test_config_defaults_follow_table_one_and_validate(scene):
    c = sabre.SafetyConfig()
    assert dict(c.penalty) == {
        "joint_limits": 10.0,
        "self_collision": 100.0,
        "arm_reach": 100.0,
        "base_box": 100.0,
        "obstacles": 100.0,
        "passivity": 100.0,
    }
    assert c.passivity_alpha == 1.0 and c.tank_floor == 2.0 and c.base_box == (-2.0, 2.0, -2.0, 2.0)
    c = sabre.SafetyConfig(gamma={"joint_limits": 20.0}, enabled={"obstacles": False}, base_box=None)
    assert c.gamma["joint_limits"] == 20.0 and c.gamma["self_collision"] == 10.0
    assert c.enabled["base_box"] is False
    with pytest.raises(TypeError):
        c.gamma["joint_limits"] = 1.0  # read-only
    with pytest.raises(dataclasses.FrozenInstanceError):
        c.tank_floor = 1.0  # frozen
    names = sabre.SafetyFilter(scene, c).row_names
    assert not any(n.startswith(("obstacle", "base_box")) for n in names)
    for bad in (
        dict(gamma={"joint_limit": 1.0}),
        dict(gamma={"passivity": 1.0}),
        dict(penalty={"self_collision": -1.0}),
        dict(margin={"obstacles": float("nan")}),
        dict(base_box=(1.0, -1.0, 0.0, 1.0)),
        dict(passivity_alpha=0.0),
        dict(max_iterations=0),
        dict(tolerance=2.0),
        dict(enabled={"passivity": "yes"}),
    ):
        with pytest.raises(InvalidValueError):
            sabre.SafetyConfig(**bad)
    with pytest.raises(ShapeError):
        sabre.SafetyConfig(base_box=(1.0, 2.0))


def test_random_states_meet_input_limits_exactly_and_rows_up_to_slack(scene, rng, safety_filter):
    f = safety_filter
    v = f.input_limits
    for _ in range(200):
        x = random_state(scene, rng)
        u_ref = rng.uniform(-1.5, 1.5, scene.nq) * v
        tau = rng.uniform(-5, 5, scene.nq)
        energy = rng.uniform(1.5, 10.0)
        r = f.filter(x, u_ref, tau_ext=tau, tank_energy=energy)
        assert r.status != "fallback"
        assert np.all(np.abs(r.u) <= v + 1e-9)
        rows = f.constraint_rows(x, tau_ext=tau, tank_energy=energy)
        a, b = rows.a, rows.b
        assert np.all(a @ r.u + r.slack >= b - 1e-6), f.row_names[int(np.argmin(a @ r.u + r.slack - b))]
        assert np.all(r.slack >= 0)
    assert f.stats.calls == 200 and f.stats.fallbacks == 0


def test_safe_command_far_from_limits_is_unchanged(scene):
    for screening in (True, False):
        f = sabre.SafetyFilter(scene, sabre.SafetyConfig(screening=screening))
        u_ref = np.array([0.1, -0.1, 0.05, 0.2, -0.2, 0.1, 0.1, -0.1, 0.2, 0.1])
        r = f.filter(scene.default_state(), u_ref, tau_ext=np.full(10, 0.1), tank_energy=10.0)
        np.testing.assert_allclose(r.u, u_ref, atol=1e-6)
        assert r.active == () and r.status == "solved"
        assert r.method == ("projection" if screening else "interior_point")


def test_exported_qp_optimality_conditions_hold_at_the_filtered_command(scene, rng, safety_filter):
    """KKT of min ½zᵀPz + qᵀz s.t. Az ≤ b at z = [u; δ], with the multipliers rebuilt from the
    primal: slack stationarity gives z_r = Γ_r δ_r for each soft row, the input bounds' multipliers
    follow from stationarity in u and must be non-negative."""
    f = safety_filter
    nu = scene.nq
    for _ in range(40):
        x = random_state(scene, rng)
        u_ref = rng.uniform(-1.5, 1.5, nu) * f.input_limits
        tau, energy = rng.uniform(-5, 5, nu), rng.uniform(1.5, 10.0)
        r = f.filter(x, u_ref, tau_ext=tau, tank_energy=energy)
        qp = f.qp_matrices(x, u_ref, tau_ext=tau, tank_energy=energy)
        P, q, A, b = qp.P, qp.q, qp.A, qp.b
        R = len(r.slack)
        z = np.concatenate([r.u, r.slack])
        gap = b - A @ z
        assert np.all(gap >= -1e-6)
        mult = np.zeros(len(b))
        mult[:R] = np.diag(P)[nu:] * r.slack
        assert np.all(mult[:R] * np.abs(gap[:R]) < 1e-5)
        g = (P @ z + q + A.T @ mult)[:nu]  # stationarity in u without the bound multipliers
        at_upper = r.u >= f.input_limits - 1e-5
        at_lower = r.u <= -f.input_limits + 1e-5
        assert np.all(np.abs(g[~(at_upper | at_lower)]) < 1e-5)
        assert np.all(g[at_upper] <= 1e-5) and np.all(g[at_lower] >= -1e-5)


def test_row_gradients_match_finite_differences(scene, rng, safety_filter):
    f = safety_filter
    eps = 1e-6
    for _ in range(20):
        x = random_state(scene, rng)
        d = np.zeros_like(x)
        d[: scene.nq] = rng.uniform(-1, 1, scene.nq)
        rows = f.constraint_rows(x)
        a, h = rows.a, rows.h
        hp = f.constraint_rows(x + eps * d).h
        hm = f.constraint_rows(x - eps * d).h
        live = np.isfinite(h)
        assert live.sum() == len(h) - 1  # all but passivity (no tank given)
        numeric = (hp - hm)[live] / (2 * eps)
        analytic = (a @ d[: scene.nq])[live]
        np.testing.assert_allclose(analytic, numeric, atol=1e-6, rtol=1e-6)


def test_passivity_row_at_the_tank_floor(scene, rng):
    f = sabre.SafetyFilter(scene, sabre.SafetyConfig(penalty={"passivity": 1e6}))
    x = scene.default_state()
    for _ in range(20):
        tau = rng.uniform(-10, 10, scene.nq)
        u_ref = -0.05 * np.sign(tau)  # pushes against τ_ext: P_diss = −τᵀu > 0
        r = f.filter(x, u_ref, tau_ext=tau, tank_energy=f.config.tank_floor)
        assert -tau @ r.u <= 1e-4
        assert "passivity" in r.active
        r = f.filter(x, u_ref, tau_ext=tau, tank_energy=3.0)
        assert -tau @ r.u <= 1.0 + 1e-4  # α (S − ε) = 1 W
    with pytest.raises(InvalidValueError):
        f.filter(x, u_ref, tau_ext=tau)


def test_tank_integrates_constant_power(scene):
    tank = sabre.EnergyTank()
    assert tank.energy == 10.0 and tank.floor == 2.0
    tau, u = np.array([2.0, -1.0, 0.5]), np.array([-0.2, 0.1, 0.2])  # τᵀu = −0.4 W
    for _ in range(500):
        tank.step(tau, u, 1e-3)
    assert tank.energy == pytest.approx(10.0 - 0.2, abs=1e-12)
    np.testing.assert_allclose(tank.history, 10.0 - 0.4 * 1e-3 * np.arange(501), atol=1e-12)
    assert tank.residual == pytest.approx(7.8)
    capped = sabre.EnergyTank(10.0, 2.0, ceiling=10.5, record_history=False)
    for _ in range(1000):
        capped.step([1.0], [1.0], 1e-3)
    assert capped.energy == 10.5 and capped.history.size == 0
    with pytest.raises(ShapeError):
        tank.step(tau, u[:2], 1e-3)
    with pytest.raises(InvalidValueError):
        tank.step([np.nan, 0, 0], u, 1e-3)
    with pytest.raises(InvalidValueError):
        sabre.EnergyTank(initial=1.0, floor=2.0)


def test_fallback_is_the_safe_stop_and_is_counted(scene):
    f = sabre.SafetyFilter(scene, sabre.SafetyConfig(max_iterations=1))
    x = np.asarray(scene.default_state())
    j4 = scene.joint_names.index("panda_joint4")
    x[j4] = -0.08
    u = np.zeros(scene.nq)
    u[j4] = 2.0
    r = f.filter(x, u)
    assert r.status == "fallback" and r.fallback
    np.testing.assert_array_equal(r.u, 0.0)
    assert f.stats.fallbacks == 1


def test_sequential_filter_keeps_the_rollout_within_limits(scene):
    model = sabre.RolloutModel(scene)
    f = sabre.SafetyFilter(scene)
    j4 = scene.joint_names.index("panda_joint4")
    upper = scene.q_upper[j4]
    x0 = np.asarray(scene.default_state())
    x0[j4] = upper - 0.4
    U = np.zeros((66, scene.nq))
    U[:, j4] = 1.5
    raw = model.rollout(x0, U[None]).states[0]
    assert raw[:, j4].max() >= upper - 1e-9  # hits the model's hard stop
    out = f.filter_sequence(x0, U, model)
    assert out.U.shape == (66, scene.nq) and out.states.shape == (67, scene.nx)
    assert out.fallbacks == 0 and set(out.status) <= {"solved", "almost_solved"}
    assert out.states[:, j4].max() < upper - 1e-3
    np.testing.assert_allclose(model.rollout(x0, out.U[None]).states[0], out.states, atol=1e-12)


def test_plant_follow_with_filter_and_tank(scene):
    plant = sabre.Plant(scene)
    controller = sabre.LowLevelController(scene)
    f = sabre.SafetyFilter(scene)
    tank = sabre.EnergyTank()
    j4 = scene.joint_names.index("panda_joint4")
    x0 = np.asarray(scene.default_state())
    x0[j4] = scene.q_upper[j4] - 0.15
    plant.reset(x0)
    reference = np.zeros((10, scene.nq))
    reference[:, j4] = 1.0
    trace = controller.follow(plant, reference, 0.0, 0.015, 300, record_every=2, safety=f, tank=tank)
    assert trace.filtered.shape == (150, scene.nq) and trace.tank_energy.shape == (150,)
    assert len(trace.filter_status) == 150 and not trace.fallback.any()
    assert trace.filtered[-1, j4] < 0.2 < trace.reference[-1, j4]
    assert np.all(trace.state[:, j4] < scene.q_upper[j4])
    np.testing.assert_allclose(trace.tank_energy, 10.0, atol=1e-9)  # no contact
    assert f.stats.calls == 300
    # Consecutive 1 kHz calls mostly re-solve the previous active set instead of running Clarabel.
    assert f.stats.interior_point_calls < 30
    plant.reset(x0)
    plain = controller.follow(plant, reference, 0.0, 0.015, 10)
    assert plain.filtered is None and plain.tank_energy is None and plain.fallback is None
    books = controller.follow(plant, reference, 0.0, 0.015, 10, tank=sabre.EnergyTank())
    assert books.filtered is None and books.tank_energy.shape == (10,)


def test_obstacles_and_bad_input(scene):
    f = sabre.SafetyFilter(scene, sabre.SafetyConfig(max_obstacles=2))
    a = f.add_obstacle([1.0, 0.0, 1.0], 0.1)
    b = f.add_obstacle(np.array([0.0, 1.0, 1.0]), 0.2)
    assert f"obstacle:{a}:panda_hand" in f.row_names
    with pytest.raises(InvalidValueError):
        f.add_obstacle([0, 0, 0], 0.1)  # slots full
    f.move_obstacle(a, [2.0, 0.0, 1.0])
    f.remove_obstacle(a)
    assert [o.id for o in f.obstacles] == [b]
    with pytest.raises(InvalidValueError):
        f.remove_obstacle(a)
    with pytest.raises(InvalidValueError):
        f.add_obstacle([0, 0, 0], -1.0)
    with pytest.raises(ShapeError):
        f.add_obstacle([0, 0], 0.1)
    x = scene.default_state()
    with pytest.raises(ShapeError):
        f.filter(x[:5], np.zeros(scene.nq))
    with pytest.raises(ShapeError):
        f.filter(x, np.zeros(3))
    with pytest.raises(InvalidValueError):
        f.filter(x, np.full(scene.nq, np.nan))
    with pytest.raises(ShapeError):
        f.filter(x, np.zeros(scene.nq), tau_ext=np.zeros(2), tank_energy=5.0)
    with pytest.raises(InvalidValueError):
        f.filter(x, np.zeros(scene.nq), tau_ext=np.zeros(scene.nq), tank_energy=float("inf"))
    with pytest.raises(TypeError):
        sabre.SafetyFilter("shelf")
    with pytest.raises(ShapeError):
        f.filter_sequence(x, np.zeros((5, 3)), sabre.RolloutModel(scene))


@pytest.mark.parametrize("with_passivity", [False, True], ids=["outer", "inner_with_tank"])
def test_no_command_moves_a_joint_further_beyond_its_hard_limit(with_passivity):
    """Joints 0–0.05 rad beyond a URDF limit, every input saturated: the joint-limit rows are soft
    (ZBF with slack, Remark 1), yet the command never drives such a joint further out."""
    scene = sabre.Scene.load("royalpanda", "shelf")
    f = sabre.SafetyFilter(scene, sabre.SafetyConfig())
    rng = np.random.default_rng(0)
    nq = scene.nq
    arm = np.arange(3, nq)
    for _ in range(300):
        x = scene.default_state()
        q = x[:nq]
        beyond = rng.random(arm.size) < 0.5
        upper_side = rng.random(arm.size) < 0.5
        depth = rng.uniform(0.0, 0.05, arm.size)
        q[arm] = np.where(beyond, np.where(upper_side, scene.q_upper[arm] + depth, scene.q_lower[arm] - depth), q[arm])
        u_ref = rng.choice([-1.0, 1.0], nq) * scene.dq_limit * rng.uniform(1.0, 3.0, nq)
        if with_passivity:
            r = f.filter(x, u_ref, tau_ext=rng.normal(0.0, 5.0, nq), tank_energy=rng.uniform(0.5, 10.0))
        else:
            r = f.filter(x, u_ref)
        u = np.asarray(r.u)
        out_up = q >= scene.q_upper
        out_down = q <= scene.q_lower
        assert np.all(u[out_up] <= 1e-12), (q[out_up] - scene.q_upper[out_up], u[out_up])
        assert np.all(u[out_down] >= -1e-12), (scene.q_lower[out_down] - q[out_down], u[out_down])
        assert np.all(np.abs(u) <= scene.dq_limit + 1e-12)
    # the guard acted: without it the QP's command moved some joint further out
    assert f.stats.hard_limit_holds > 0
