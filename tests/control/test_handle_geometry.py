"""The open-object geometry (run in the core) against the same quantities computed here with NumPy
from the scene's forward kinematics: states asked about in turn, and an array changed in place."""

from __future__ import annotations

import numpy as np
import pytest

import sabre
from sabre.tasks.open_object import geometry


def _reference(scene, handle, x, offset):
    """(distance, angle, across, along, depth, sideways) of the grasp frame from the target, with NumPy."""
    q, _, o, _ = scene.split_state(x)
    frame, frame_offset = geometry.handle_frame(scene, handle)
    pose = scene.object_fk(o, frame) @ frame_offset
    tool = scene.fk(q, geometry.tool_frame(scene))
    target = pose @ offset
    error = tool[:3, 3] - target[:3, 3]
    cos = (np.trace(target[:3, :3].T @ tool[:3, :3]) - 1.0) / 2.0
    local = pose[:3, :3].T @ error
    grasp = np.linalg.solve(pose, tool)
    return (
        np.linalg.norm(error),
        np.arccos(np.clip(cos, -1.0, 1.0)),
        np.hypot(local[1], local[2]),
        abs(local[0]),
        pose[:3, 2] @ error,
        grasp[1, 3],
    )


def _measured(scene, handle, x, offset):
    approach = geometry.approach_error(scene, handle, x, offset)
    pocket = geometry.pocket_error(scene, handle, x, offset)
    return (
        approach.distance,
        approach.angle,
        pocket.across,
        pocket.along,
        geometry.depth_error(scene, handle, x, offset),
        geometry.lateral_error(scene, handle, x, 0.0),
    )


@pytest.mark.parametrize("obj", ["shelf", "drawer"])
def test_errors_match_numpy_for_states_asked_about_in_turn(obj):
    scene = sabre.Scene.load(obj=obj)
    task = sabre.tasks.OpenObject()
    rng = np.random.default_rng(3)
    states = []
    for _ in range(4):
        x = scene.default_state()
        x[: scene.nq] += rng.uniform(-0.2, 0.2, scene.nq)
        x[2 * scene.nq] = rng.uniform(scene.o_lower[0], scene.o_upper[0])
        states.append(x)
    for phase in ("approach", "hook", "open"):
        offset = task.grasp_offset(scene, phase)
        for x in states + states[::-1]:
            np.testing.assert_allclose(
                _measured(scene, task.handle, x, offset), _reference(scene, task.handle, x, offset), rtol=1e-9, atol=1e-9
            )
    x = states[0].copy()
    offset = task.grasp_offset(scene, "open")
    geometry.approach_error(scene, task.handle, x, offset)
    x[0] += 0.2  # the same array, changed in place
    np.testing.assert_allclose(_measured(scene, task.handle, x, offset), _reference(scene, task.handle, x, offset), atol=1e-9)


def test_handle_poses_match_the_object_kinematics():
    scene = sabre.Scene.load(obj="shelf")
    frame, offset = geometry.handle_frame(scene, "handle_frame")
    openings = np.linspace(scene.o_lower[0], scene.o_upper[0], 5)[:, None]
    np.testing.assert_allclose(
        geometry.handle_poses(scene, "handle_frame", openings), scene.object_fk_many(openings, frame) @ offset, atol=1e-12
    )
    np.testing.assert_allclose(
        geometry.handle_pose(scene, "handle_frame", openings[2]), scene.object_fk(openings[2], frame) @ offset, atol=1e-12
    )


def test_bad_states_are_refused_with_sabre_errors():
    scene = sabre.Scene.load(obj="shelf")
    task = sabre.tasks.OpenObject()
    offset = task.grasp_offset(scene, "open")
    with pytest.raises(sabre.ShapeError):
        geometry.approach_error(scene, task.handle, np.zeros(3), offset)
    x = scene.default_state()
    x[1] = np.nan
    with pytest.raises(sabre.InvalidValueError):
        geometry.approach_error(scene, task.handle, x, offset)
    with pytest.raises(sabre.InvalidValueError):
        task.next_phase(scene, x, 0.0, "open")
    with pytest.raises(sabre.InvalidValueError, match="unknown phase"):
        task.guides(scene, scene.default_state(), "pull", 10, 0.015)
