"""Opening objects the controller knows only by a detected handle, in closed loop on the plant with the true
object hidden: the object opens, and the estimate of its joint is right against the true one."""

from __future__ import annotations

import math

import numpy as np
import pytest

import sabre
from sabre.tasks import OpenObject


def true_joint(scene: sabre.Scene) -> tuple[str, np.ndarray, np.ndarray]:
    """(type, axis or direction, a point on a hinge) of the scene's object, from its handle frame at two
    openings (a rotation's axis and fixed point, or a translation's direction)."""
    a, b = scene.object_fk([0.0], "handle_frame"), scene.object_fk([0.3], "handle_frame")
    r = b[:3, :3] @ a[:3, :3].T
    if not scene.object_is_revolute:
        d = b[:3, 3] - a[:3, 3]
        return "prismatic", d / np.linalg.norm(d), a[:3, 3]
    w = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    axis = w / np.linalg.norm(w)
    # the fixed points p of the rotation: (I − R) p = b − R a, least squares (rank 2)
    point = np.linalg.lstsq(np.eye(3) - r, b[:3, 3] - r @ a[:3, 3], rcond=None)[0]
    return "revolute", axis, point


@pytest.mark.parametrize("obj", ["drawer", "shelf"])
def test_an_object_opens_from_its_handle_pose_and_its_joint_is_found(obj):
    true = sabre.Scene.load("royalpanda", obj)
    estimated = sabre.EstimatedObject(
        "royalpanda", sabre.DetectedHandle(true.object_fk([0.0], "handle_frame")), simulated_noise=(0.002, 0.5)
    )
    controller = sabre.Controller(estimated.scene, OpenObject(), sabre.ControllerConfig(variant="N"))
    episode = sabre.run_episode(true, controller, 30.0, estimated=estimated, record_every=1, progress=False)
    assert episode.success, controller.phase_history
    kind, axis, point = true_joint(true)
    e = estimated.estimate
    assert e.kind == kind and estimated.scene.hypothesis is not None and estimated.rebuilds
    assert controller.scene is estimated.scene  # the controller planned with the rebuilt object
    assert math.degrees(math.acos(min(1.0, abs(e.axis @ axis)))) < 5.0
    if kind == "revolute":
        off = e.point - point
        assert np.linalg.norm(off - (off @ axis) * axis) < 0.05
    # the opening the controller saw is the true one, near enough
    nq = true.nq
    assert e.opening == pytest.approx(episode.state[-1, 2 * nq], abs=0.05 if kind == "revolute" else 0.02)
