"""Fuzzing the public API with Hypothesis: whatever the input, a call returns finite numbers or raises
a SabreError; it never crashes, hangs, raises another exception or returns NaN."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

import sabre
from sabre import costs
from sabre.errors import SabreError

FUZZ = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])

SCENE = sabre.Scene.load("royalpanda", "shelf")

# Floats a hostile caller would send: ordinary values, huge ones, NaN and ±inf.
any_float = st.one_of(
    st.floats(-10.0, 10.0),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, 1e-300, 1e300, -1e155, 1e155, 5e-324]),
)


def vectors(n: int) -> st.SearchStrategy[np.ndarray]:
    return hnp.arrays(np.float64, st.one_of(st.just(n), st.integers(0, n + 2)), elements=any_float)


def near_default_states() -> st.SearchStrategy[np.ndarray]:
    """States around the default one: most inside the model's range, some far outside it."""
    x0 = SCENE.default_state()
    return hnp.arrays(np.float64, SCENE.nx, elements=st.floats(-1.0, 1.0)).map(lambda d: x0 + d) | vectors(SCENE.nx)


def finite_or_sabre_error(call):
    try:
        out = call()
    except SabreError:
        return None
    for value in out if isinstance(out, tuple) else (out,):
        assert np.all(np.isfinite(np.asarray(value, dtype=float))), out
    return out


@FUZZ
@given(q=vectors(SCENE.nq), frame=st.sampled_from(["grasp", "base_link", "nope", ""]))
def test_kinematics(q, frame):
    finite_or_sabre_error(lambda: SCENE.fk(q, frame))
    finite_or_sabre_error(lambda: SCENE.jacobian(q, frame))
    finite_or_sabre_error(lambda: SCENE.mass_matrix(q))


@FUZZ
@given(x=near_default_states(), tau=vectors(SCENE.nq), steps=st.integers(1, 5))
def test_plant_reset_and_step(x, tau, steps):
    plant = sabre.Plant(SCENE)
    try:
        plant.reset(x)
    except SabreError:
        return
    for _ in range(steps):
        try:
            plant.step(tau)
        except SabreError:
            return
        assert np.all(np.isfinite(plant.state))


@FUZZ
@given(x=near_default_states(), u=vectors(SCENE.nq), energy=any_float)
def test_safety_filter(x, u, energy):
    f = sabre.SafetyFilter(SCENE, sabre.SafetyConfig())
    finite_or_sabre_error(lambda: f.filter(x, u).u)
    finite_or_sabre_error(lambda: f.filter(x, u, tau_ext=np.zeros(SCENE.nq), tank_energy=energy).u)


@FUZZ
@given(initial=any_float | st.none() | st.text(max_size=3), floor=any_float, tau=vectors(SCENE.nq), dt=any_float)
def test_energy_tank(initial, floor, tau, dt):
    try:
        tank = sabre.EnergyTank(initial=initial, floor=floor)
    except SabreError:
        return
    finite_or_sabre_error(lambda: tank.step(tau, np.ones(SCENE.nq), dt))
    assert np.isfinite(tank.energy)


@FUZZ
@given(
    costs_=hnp.arrays(np.float64, st.integers(1, 50), elements=any_float),
    mapping=st.sampled_from(["naive", "baseline", "invariant", "other"]),
    parameter=any_float,
)
def test_likelihood_weights(costs_, mapping, parameter):
    w = finite_or_sabre_error(lambda: sabre.paper.likelihood_weights(costs_, mapping, parameter))
    if w is not None:
        assert np.all(w >= 0.0)
        assert np.isclose(w.sum(), 1.0) or w.sum() == 0.0


@FUZZ
@given(rollouts=st.integers(-5, 2**63), horizon=any_float, dt=any_float, seed=st.integers(-1, 2**65))
def test_controller_configuration(rollouts, horizon, dt, seed):
    try:
        config = sabre.ControllerConfig(rollouts=rollouts, horizon=horizon, dt=dt, seed=seed, threads=1)
    except SabreError:
        return
    # building allocates what the configuration implies: refused above the documented bounds
    try:
        controller = sabre.Controller(SCENE, sabre.tasks.OpenObject(), config)
    except SabreError:
        return
    if config.rollouts * config.horizon_steps <= 2000:
        controller.update(SCENE.default_state(), 0.0)
        assert np.all(np.isfinite(controller.nominal))


@FUZZ
@given(lower=vectors(2), upper=vectors(2), radius=any_float, spacing=any_float)
def test_cost_terms(lower, upper, radius, spacing):
    for make in (
        lambda: costs.BaseBox(lower=lower, upper=upper),
        lambda: costs.Obstacles(centers=[[0.0, 0.0, 1.0]], radii=[radius]),
        lambda: costs.BaseClearance(spacing=spacing),
    ):
        try:
            make().compile(SCENE)
        except SabreError:
            pass


URDF_PIECES = st.sampled_from(
    [
        '<robot name="r">',
        "</robot>",
        '<link name="a"/>',
        '<link name="b">',
        "</link>",
        '<joint name="j" type="revolute">',
        "</joint>",
        '<parent link="a"/>',
        '<child link="b"/>',
        '<limit lower="-1" upper="1" effort="1" velocity="1"/>',
        '<origin xyz="nan 0 0"/>',
        '<inertial><mass value="-1"/></inertial>',
        "<a>",
        "</a>",
        "<",
        "&amp;",
        "\x00",
    ]
)


@FUZZ
@given(pieces=st.lists(URDF_PIECES, max_size=30))
def test_urdf_strings(pieces):
    text = "".join(pieces)
    try:
        sabre.Scene.from_urdf_strings(text, text)
    except SabreError:
        pass


@pytest.mark.parametrize("threads", [1, 2])
def test_fuzzed_rollouts_are_finite_or_marked_failed(threads):
    rng = np.random.default_rng(7)
    model = sabre.RolloutModel(SCENE, 0.015)
    U = rng.normal(0.0, 50.0, size=(6, 10, SCENE.nu))  # far beyond every velocity limit
    r = model.rollout(SCENE.default_state(), U, threads=threads)
    assert np.all(np.isfinite(r.states[~r.failed]))
