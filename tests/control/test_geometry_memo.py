"""The open-object geometry keeps the last state's poses per scene: asked about other states in
turn, or about an array changed in place, it answers as if it had kept nothing."""

from __future__ import annotations

import numpy as np

import sabre
from sabre.tasks.open_object import geometry


def _fresh_approach_distance(scene, handle, x, offset):
    q, _, o, _ = scene.split_state(x)
    target = scene.object_fk(o, geometry.handle_frame(scene, handle)[0]) @ geometry.handle_frame(scene, handle)[1] @ offset
    return float(np.linalg.norm(scene.fk(q, geometry.tool_frame(scene))[:3, 3] - target[:3, 3]))


def test_answers_follow_the_state_asked_about():
    scene = sabre.Scene.load(obj="shelf")
    task = sabre.tasks.OpenObject()
    offset = task.grasp_offset(scene, "open")
    a = scene.default_state()
    b = a.copy()
    b[0] += 0.1  # the base moved
    b[2 * scene.nq] = 0.4  # the door opened
    assert _fresh_approach_distance(scene, task.handle, a, offset) != _fresh_approach_distance(scene, task.handle, b, offset)
    for x in (a, b, a, b):
        got = geometry.approach_error(scene, task.handle, x, offset).distance
        assert got == _fresh_approach_distance(scene, task.handle, x, offset)
    x = a.copy()
    geometry.approach_error(scene, task.handle, x, offset)
    x[0] += 0.2  # the same array, changed in place
    assert geometry.approach_error(scene, task.handle, x, offset).distance == _fresh_approach_distance(
        scene, task.handle, x, offset
    )
