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


class _EagerGuides(sabre.tasks.OpenObject):
    """OpenObject whose guides reach the controller as arrays, built before the rollouts."""

    def guide_plan(self, scene, x, phase, steps, dt):
        return None


def _hooked(scene):
    motion = sabre.hook_and_pull(scene)
    start = int(np.argmax(motion.phases == 3)) + 20
    return sabre.RolloutModel(scene).rollout(scene.default_state(), motion.U[None, :start]).states[0, -1]


@pytest.mark.parametrize("threads", [1, 2])
def test_guides_integrated_by_the_rollout_workers_plan_as_the_guides_built_first(scene, threads):
    """Opening from the hooked state, where the task proposes two guides: a controller whose
    workers integrate them (the task's guide plan) and one given them as arrays end every
    iteration with the same policy and statistics, to the bit."""
    x = _hooked(scene)
    task = sabre.tasks.OpenObject()
    guides = task.guides(scene, x, "open", 66, 0.015)
    plan = task.guide_plan(scene, x, "open", 66, 0.015)
    assert guides is not None and len(guides) >= 2
    assert plan.shape == guides.shape
    np.testing.assert_array_equal(plan.evaluate(), guides)
    controllers = [sabre.Controller(scene, t, sabre.ControllerConfig(seed=3, threads=threads)) for t in (task, _EagerGuides())]
    for c in controllers:
        c.set_phase("open")
    for i in range(4):
        planned, eager = (c.update(x, 0.01 * i) for c in controllers)
        np.testing.assert_array_equal(controllers[0].nominal, controllers[1].nominal)
        assert (planned.nominal_cost, planned.cost_mean, planned.failed_rollouts) == (
            eager.nominal_cost,
            eager.cost_mean,
            eager.failed_rollouts,
        )


def test_a_batch_takes_the_planned_guides_it_has_room_for(scene):
    """Three rollouts hold the nominal, the zero sequence and one guide: the first of the plan's."""
    x = _hooked(scene)
    q0 = x[: scene.nq]
    controller = sabre.Controller(scene, sabre.tasks.OpenObject(), sabre.ControllerConfig(rollouts=3))
    steps = controller.config.horizon_steps
    plan = sabre.guides.servo_guide_plan(scene, q0, _sequences(scene, q0, 2, steps), controller.config.dt)
    controller._planner.set_guide_plan(plan)
    batch = controller._planner.sample(0.0)
    np.testing.assert_array_equal(batch[2], np.clip(plan.evaluate()[0], -scene.dq_limit, scene.dq_limit))


def test_a_subclass_with_guides_of_its_own_gets_them_and_a_bad_plan_is_refused(scene):
    class OwnGuides(sabre.tasks.OpenObject):
        def guides(self, scene, x, phase, steps, dt):
            return np.zeros((1, steps, scene.nu))

    x = scene.default_state()
    assert OwnGuides().guide_plan(scene, x, "approach", 66, 0.015) is None
    assert sabre.tasks.OpenObject().guide_plan(scene, x, "approach", 66, 0.015) is not None

    class BadPlan(sabre.tasks.OpenObject):
        def guide_plan(self, scene, x, phase, steps, dt):
            return np.zeros((1, steps, scene.nu))

    with pytest.raises(sabre.InvalidValueError, match="guide_plan"):
        sabre.Controller(scene, BadPlan()).update(x, 0.0)
