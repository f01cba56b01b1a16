"""Failure paths: a rollout whose physics diverges, the planner around it, and the plant's refusal.

A state whose object joint moves at 1000 rad/s (finite and within the coordinate range, but ten
times faster than anything the simulation calls physical) makes every rollout from it diverge in its
first step, and the plant refuse it outright.
"""

from __future__ import annotations

import numpy as np
import pytest

import sabre
from sabre import costs, tasks

ABSURD = 1e3  # rad/s of the object joint: beyond the divergence bound of 100 rad/s


def absurd_state(scene: sabre.Scene, value: float = ABSURD) -> np.ndarray:
    x = scene.default_state()
    x[2 * scene.nq + scene.no] = value
    assert np.all(np.isfinite(x))
    return x


def test_diverging_rollout_is_marked_failed_and_nan_from_the_failing_step(scene):
    model = sabre.RolloutModel(scene, 0.015)
    n, k = 3, 4
    healthy = model.rollout(scene.default_state(), np.zeros((n, k, scene.nu)), threads=1)
    assert not healthy.failed.any() and np.all(np.isfinite(healthy.states))

    x0 = absurd_state(scene)
    r = model.rollout(x0, np.zeros((n, k, scene.nu)), threads=1)
    assert r.failed.tolist() == [True] * n
    np.testing.assert_array_equal(r.states[:, 0], np.broadcast_to(x0, (n, scene.nx)))
    assert np.all(np.isnan(r.states[:, 1:]))
    assert np.all(np.isnan(r.tau_ext)) and np.all(np.isnan(r.wrench))
    assert not r.contact.any()


class Recorded(tasks.Task):
    """Reach's cost (Rust terms) plus a Python term that records the costs the planner weighs."""

    phases = ("main",)

    def __init__(self, scene: sabre.Scene) -> None:
        self.reach = tasks.Reach(frame="grasp", target_pose=scene.fk(scene.default_state()[: scene.nq], "grasp"))
        self.seen_states: list[np.ndarray] = []

    def _record(self, batch: costs.Batch) -> np.ndarray:
        self.seen_states.append(batch.states.copy())
        return np.zeros(batch.states.shape[0])

    def cost(self, scene: sabre.Scene, phase: str) -> costs.Cost:
        base = self.reach.cost(scene, "reach")
        return costs.Cost(list(base.terms) + [costs.PythonTerm(function=self._record)])


@pytest.mark.parametrize("python_terms", [False, True], ids=["rust_cost", "rust_and_python_cost"])
def test_failed_rollouts_get_infinite_cost_zero_weight_and_a_finite_command(scene, python_terms):
    task = (
        Recorded(scene)
        if python_terms
        else tasks.Reach(frame="grasp", target_pose=scene.fk(scene.default_state()[: scene.nq], "grasp"))
    )
    config = sabre.ControllerConfig(rollouts=12, horizon=0.3, seed=1, threads=1)
    controller = sabre.Controller(scene, task, config)
    controller.update(scene.default_state(), 0.0)
    before = controller.nominal.copy()
    assert np.any(before != 0.0)

    stats = controller.update(absurd_state(scene), 0.0)
    assert stats.failed_rollouts == config.rollouts
    assert stats.nominal_cost == np.inf
    assert stats.effective_sample_size == 0.0  # every weight is zero
    # no weight, no step: the nominal is the previous one, and the command stays finite
    np.testing.assert_array_equal(controller.nominal, before)
    assert np.all(np.isfinite(controller.reference(0.0)))
    if python_terms:
        assert np.all(np.isnan(task.seen_states[-1][:, 1:]))


def test_plant_refuses_a_state_moving_beyond_the_divergence_bound(scene):
    plant = sabre.Plant(scene)
    with pytest.raises(sabre.InvalidValueError, match="moves at 1000"):
        plant.reset(absurd_state(scene))
    # nothing was changed: the plant still steps from its previous state
    plant.step(np.zeros(scene.nq))
    assert np.all(np.isfinite(plant.state))


def test_run_episode_refuses_a_start_state_the_plant_cannot_take(scene):
    task = tasks.Reach(frame="grasp", target_pose=scene.fk(scene.default_state()[: scene.nq], "grasp"))
    controller = sabre.Controller(scene, task, sabre.ControllerConfig(rollouts=6, horizon=0.3, threads=1))
    with pytest.raises(sabre.InvalidValueError):
        sabre.run_episode(scene, controller, 0.1, x0=absurd_state(scene), progress=False)
