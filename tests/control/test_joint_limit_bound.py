"""The hard joint-limit bound: its settings checked where they enter, random plans pushing out on both
plants never bringing a joint onto its URDF limit, and the plan a controller hands over keeping it."""

from __future__ import annotations

import math

import numpy as np
import pytest

import sabre
from sabre import _core
from sabre.errors import InvalidValueError
from sabre.inner_loop import follow_plant, inner_cascade

# Franka's acceleration limits (rad/s²), joints 1–7.
FRANKA_ACCELERATION = np.array([15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0])
# The simulated robot's low-level gains behind the bridge: the last wrist joint (0.007 kg m²) holds its
# command against its neighbours only with a floor.
FLOOR = 0.03


@pytest.fixture(scope="module")
def scene():
    return sabre.Scene.load(obj="shelf")


def test_settings_mirror_the_core_and_bad_ones_are_refused(scene):
    core = _core.LimitBoundConfig()
    config = sabre.SafetyConfig()
    assert (config.limit_margin, config.prismatic_limit_margin, config.limit_deceleration) == (
        core.margin,
        core.prismatic_margin,
        core.deceleration,
    )
    for bad in (
        {"limit_margin": -0.01},
        {"limit_margin": math.nan},
        {"prismatic_limit_margin": math.inf},
        {"limit_deceleration": 0.0},
        {"limit_deceleration": "fast"},
    ):
        with pytest.raises(InvalidValueError, match=next(iter(bad))):
            sabre.SafetyConfig(**bad)
    # panda_joint4's range is 3.0 rad: a margin beyond half of it leaves nothing to move in
    wide = sabre.SafetyConfig(limit_margin=1.51)
    with pytest.raises(InvalidValueError, match=r"limit_margin.*panda_joint4"):
        sabre.SafetyFilter(scene, wide)
    low = sabre.LowLevelController(scene)
    with pytest.raises(InvalidValueError, match="limit_margin"):
        inner_cascade(low, limits=wide)
    with pytest.raises(InvalidValueError, match="prismatic_limit_margin"):
        inner_cascade(low, limits=sabre.SafetyConfig(prismatic_limit_margin=10.5))
    with pytest.raises(TypeError):
        inner_cascade(low, limits={"limit_margin": 0.1})
    assert sabre.SafetyConfig(limit_margin=1.5).limit_margin == 1.5


def _start(scene):
    """The start posture with panda_joint6 2 mrad inside its margin (where the scripted pull leaves it)."""
    x = scene.start_state()
    i = scene.joint_names.index("panda_joint6")
    x[i] = scene.q_upper[i] - sabre.SafetyConfig().limit_margin - 0.002
    return x


def _plans(rng, scene, x, now, t0):
    """A plan of six 50 ms steps from the reference ``now``: each arm joint toward a random target within
    its velocity limit, half of them toward the nearer limit, at half Franka's acceleration limits (what the
    simulated Panda's efforts can follow with several joints at once); one in seven ramps to rest."""
    arm = np.arange(3, scene.nq)
    q, lower, upper, speed = x[: scene.nq], np.asarray(scene.q_lower), np.asarray(scene.q_upper), scene.dq_limit
    outward = np.where(upper - q < q - lower, 1.0, -1.0)
    target = np.zeros(scene.nq)
    if rng.random() >= 1.0 / 7.0:
        size = rng.uniform(0.0, 1.0, scene.nq) * np.asarray(speed)
        target[arm] = np.where(rng.random(scene.nq) < 0.5, outward * size, rng.uniform(-1.0, 1.0, scene.nq) * size)[arm]
    slope = np.zeros(scene.nq)
    slope[arm] = 0.5 * FRANKA_ACCELERATION * 0.05
    rows, value = [], now.copy()
    for _ in range(6):
        rows.append(value.copy())
        value = value + np.clip(target - value, -slope, slope)
    return sabre.PlanSnapshot.of(np.array(rows), t0, 0.05)


def _run(scene, plant, with_filter, seed):
    """Random plans on ``plant`` through the cascade (filter and tank or neither); returns the closest any
    robot joint came to a URDF limit (m or rad), asserting after every plan that none reached one."""
    rng = np.random.default_rng(seed)
    low = sabre.LowLevelController(scene, dt=plant.dt, gain_inertia_floor=FLOOR)
    safety = sabre.SafetyFilter(scene) if with_filter else None
    tank = sabre.EnergyTank(10.0, 2.0) if with_filter else None
    cascade = inner_cascade(low, safety, tank)
    plant.reset(_start(scene))
    lower, upper = np.asarray(scene.q_lower), np.asarray(scene.q_upper)
    closest, now = math.inf, np.zeros(scene.nq)
    for _ in range(16):
        t = float(plant.time)
        plan = _plans(rng, scene, np.asarray(plant.state), now, t)
        cascade.hand_over(plan.plan)
        steps = int(rng.integers(50, 300))
        trace = follow_plant(cascade, plant, steps, 1)
        now = plan.reference(float(plant.time))
        q = trace.state[:, : scene.nq]
        inside = np.minimum(upper - q, q - lower)
        # No tolerance: a plant's own limit holds a joint pressed against it at or past the limit.
        assert inside.min() > 0.0, f"joint {scene.joint_names[int(np.argmin(inside.min(axis=0)))]} reached its limit"
        closest = min(closest, float(inside.min()))
    assert cascade.limit_holds > 0
    return closest


def _check(closest):
    """The plans pushed a joint near its limit, and the bound kept it off by at least half the margin: the
    rest is what the plant lags its command by."""
    margin = sabre.SafetyConfig().limit_margin
    assert closest < margin + 0.01, "the plans never pushed a joint near its limit"
    assert closest >= 0.5 * margin, f"a joint came within {closest} of its limit"


@pytest.mark.parametrize(("with_filter", "seed"), [(False, 3), (True, 5)], ids=["unfiltered", "filter_and_tank"])
def test_random_plans_on_the_rust_plant_never_bring_a_joint_onto_its_limit(scene, with_filter, seed):
    _check(_run(scene, sabre.Plant(scene), with_filter, seed))


def test_random_plans_on_mujocos_plant_never_bring_a_joint_onto_its_limit(scene):
    pytest.importorskip("mujoco")
    _check(_run(scene, sabre.MujocoPlant(scene, gain_inertia_floor=FLOOR), False, seed=7))


def test_the_handed_plan_keeps_the_bound_while_the_samplers_nominal_drives_through(scene):
    """A Reach beyond panda_joint4's upper limit (variant N): the sampler's nominal integrates past the limit,
    the snapshot the inner loop follows stops inside its margin."""
    x = scene.default_state()
    i = scene.joint_names.index("panda_joint4")
    x[i] = scene.q_upper[i] - 0.05
    q_goal = x[: scene.nq].copy()
    q_goal[i] = scene.q_upper[i] + 0.5
    task = sabre.tasks.Reach(
        target_pose=scene.fk(q_goal, "grasp"),
        safety=sabre.tasks.SafetyWeights(joint_limit=0.0, joint_limit_slope=0.0),
    )
    config = sabre.ControllerConfig(variant="N", seed=1, rollouts=16, safety=sabre.SafetyConfig(base_box=None))
    controller = sabre.Controller(scene, task, config)
    for k in range(15):
        controller.update(x, k * 0.015)
    dt, margin = controller.config.dt, config.safety_config.limit_margin
    nominal = x[i] + np.cumsum(controller.nominal[:, i]) * dt
    handed = x[i] + np.cumsum(controller.snapshot().nominal[:, i]) * dt
    assert nominal.max() > scene.q_upper[i]
    assert handed.max() <= scene.q_upper[i] - margin + 1e-12
