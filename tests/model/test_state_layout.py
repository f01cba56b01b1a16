"""Scene.split_state against the state layout x = [q, q̇, o, ȯ] that Scene documents and the rollout model integrates."""

from __future__ import annotations

import numpy as np
import pytest

import sabre
from sabre.scene import StateParts


def test_the_parts_are_the_documented_slices(scene: sabre.Scene) -> None:
    nq, no = scene.nq, scene.no
    assert scene.nx == 2 * (nq + no)
    parts = scene.split_state(np.arange(scene.nx, dtype=float))
    assert isinstance(parts, StateParts)
    np.testing.assert_array_equal(parts.q, np.arange(nq))
    np.testing.assert_array_equal(parts.q_dot, np.arange(nq, 2 * nq))
    np.testing.assert_array_equal(parts.o, np.arange(2 * nq, 2 * nq + no))
    np.testing.assert_array_equal(parts.o_dot, np.arange(2 * nq + no, scene.nx))


def test_the_default_state_splits_into_home_pose_at_rest_and_closed_object(scene: sabre.Scene) -> None:
    q, q_dot, o, o_dot = scene.split_state(scene.default_state())
    np.testing.assert_array_equal(q, scene.home_configuration())
    np.testing.assert_array_equal(o, np.clip(0.0, scene.o_lower, scene.o_upper))
    assert not q_dot.any() and not o_dot.any()


def test_the_parts_are_where_the_rollout_model_integrates_them() -> None:
    scene = sabre.Scene.load(obj="drawer")
    model = sabre.RolloutModel(scene)
    x0 = scene.default_state()
    start = scene.split_state(x0)
    steps = 20
    U = np.zeros((1, steps, scene.nu))
    U[..., 0] = 0.2  # base forward at 0.2 m/s, nothing else commanded
    states = model.rollout(x0, U).states[0]
    q, q_dot, o, o_dot = scene.split_state(states)
    assert q_dot[-1, 0] > 0.1
    assert q[-1, 0] - start.q[0] == pytest.approx(np.sum(q_dot[1:, 0]) * model.dt, rel=0.2)
    np.testing.assert_allclose(q[:, 3:], np.broadcast_to(start.q[3:], q[:, 3:].shape), atol=1e-2)
    np.testing.assert_allclose(o, np.broadcast_to(start.o, o.shape), atol=1e-9)
    np.testing.assert_allclose(o_dot, 0.0, atol=1e-9)


def test_the_parts_are_views_that_write_through(scene: sabre.Scene) -> None:
    x = scene.default_state()
    parts = scene.split_state(x)
    for part in parts:
        assert np.shares_memory(part, x)
    parts.o[0] = 0.25
    parts.q_dot[:] = 1.0
    assert x[2 * scene.nq] == 0.25
    np.testing.assert_array_equal(x[scene.nq : 2 * scene.nq], 1.0)


def test_a_batch_keeps_its_leading_axes(scene: sabre.Scene, rng: np.random.Generator) -> None:
    states = rng.normal(size=(3, 5, scene.nx))
    q, q_dot, o, o_dot = scene.split_state(states)
    assert q.shape == q_dot.shape == (3, 5, scene.nq)
    assert o.shape == o_dot.shape == (3, 5, scene.no)
    np.testing.assert_array_equal(np.concatenate([q, q_dot, o, o_dot], axis=-1), states)
    for i in range(3):
        np.testing.assert_array_equal(scene.split_state(states[i, 2]).o, o[i, 2])


@pytest.mark.parametrize("shape", [(), (1,), (30,), (2, 23), (23, 2)])
def test_a_wrong_last_axis_is_refused(scene: sabre.Scene, shape: tuple[int, ...]) -> None:
    assert scene.nx not in shape[-1:]
    with pytest.raises(sabre.ShapeError, match="nx"):
        scene.split_state(np.zeros(shape))
