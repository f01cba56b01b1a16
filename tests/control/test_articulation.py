"""Objects known only by a detected handle: the handle's validation, the parametric object built around it
against rotations and slides computed here, the estimator's Python face on analytic paths, and the
controller taking a rebuilt scene with its plan in force."""

from __future__ import annotations

import math

import numpy as np
import pytest

import sabre
from sabre.articulation import ArticulationEstimate
from sabre.errors import InvalidValueError, ShapeError
from sabre.poses import pose_to_xyz_rpy, xyz_rpy_to_pose
from sabre.robot_examples import example_scene
from sabre.tasks import OpenObject

#: A handle as on the shelf: bar vertical (x up), z into the panel (+x world), 0.94 m ahead.
HANDLE = np.array([[0.0, 0.0, 1.0, 0.94], [0.0, -1.0, 0.0, -0.12], [1.0, 0.0, 0.0, 0.75], [0.0, 0.0, 0.0, 1.0]])


def rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues' rotation about the unit ``axis``."""
    a = axis / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


def estimate(kind: str, axis: np.ndarray, point: np.ndarray, radius: float = float("nan")) -> ArticulationEstimate:
    return ArticulationEstimate(
        kind=kind, geometry=kind, p_revolute=1.0 if kind == "revolute" else 0.0, axis=np.asarray(axis, float),
        point=np.asarray(point, float), radius=radius, axis_std=0.01, point_std=0.01, radius_std=0.01, opening=0.0,
        rate=0.0, path_length=0.2, samples=100, hooked=True,
    )  # fmt: skip


def test_a_pose_round_trips_through_roll_pitch_yaw_also_at_ninety_degrees_pitch():
    rng = np.random.default_rng(0)
    for v in [*rng.uniform(-3, 3, (20, 6)), [0, 0, 0, 0.3, math.pi / 2, 0.2], [1, 2, 3, -0.4, -math.pi / 2, 1.0]]:
        m = xyz_rpy_to_pose(v)
        np.testing.assert_allclose(xyz_rpy_to_pose(pose_to_xyz_rpy(m)), m, atol=1e-12)
    np.testing.assert_allclose(xyz_rpy_to_pose(pose_to_xyz_rpy(HANDLE)), HANDLE, atol=1e-12)


def test_a_detected_handle_is_checked_and_takes_either_pose_form():
    h = sabre.DetectedHandle(pose_to_xyz_rpy(HANDLE))
    np.testing.assert_allclose(h.pose, HANDLE, atol=1e-12)
    np.testing.assert_allclose(h.outward, [-1.0, 0.0, 0.0], atol=1e-12)
    with pytest.raises(ShapeError):
        sabre.DetectedHandle(np.eye(3))
    with pytest.raises(InvalidValueError, match="rotation"):
        sabre.DetectedHandle(np.diag([1.0, 1.0, -1.0, 1.0]))
    with pytest.raises(InvalidValueError, match="prior"):
        sabre.DetectedHandle(HANDLE, prior="cupboard")
    with pytest.raises(InvalidValueError, match="thickness"):
        sabre.DetectedHandle(HANDLE, length=0.01, thickness=0.02)
    with pytest.raises(TypeError, match="DetectedHandle"):
        sabre.Scene.from_handle("royalpanda", HANDLE)  # type: ignore[arg-type]


def test_the_first_pull_slides_the_detected_handle_along_its_outward_normal():
    scene = sabre.Scene.from_handle("royalpanda", sabre.DetectedHandle(HANDLE))
    assert scene.object_joint_names == ("articulation",) and not scene.object_is_revolute
    assert scene.hypothesis is None and scene.detected_handle is not None
    np.testing.assert_allclose(scene.object_fk([0.0], "handle_frame"), HANDLE, atol=1e-9)
    moved = scene.object_fk([0.05], "handle_frame")
    np.testing.assert_allclose(moved[:3, :3], HANDLE[:3, :3], atol=1e-9)
    np.testing.assert_allclose(moved[:3, 3] - HANDLE[:3, 3], [-0.05, 0.0, 0.0], atol=1e-9)
    # the first pull's travel is short: the type is not known yet
    assert scene.o_upper[0] == pytest.approx(sabre.DetectedHandle(HANDLE).first_pull)


@pytest.mark.parametrize(
    ("axis", "point"),
    [
        (np.array([0.0, 0.0, -1.0]), np.array([0.95, 0.2, 0.75])),  # hinge to the left, vertical
        (np.array([0.03, 0.02, 1.0]), np.array([0.93, -0.5, 0.9])),  # to the right, a little tilted
    ],
)
def test_a_door_hypothesis_turns_the_handle_about_the_estimated_hinge(axis, point):
    e = estimate("revolute", axis / np.linalg.norm(axis), point)
    scene = sabre.Scene.from_handle("royalpanda", sabre.DetectedHandle(HANDLE), e)
    assert scene.object_is_revolute and scene.hypothesis is e
    np.testing.assert_allclose(scene.object_fk([0.0], "handle_frame"), HANDLE, atol=1e-9)
    for angle in (0.2, 0.9):
        r = rotation(axis, angle)
        expected = np.eye(4)
        expected[:3, :3] = r @ HANDLE[:3, :3]
        expected[:3, 3] = point + r @ (HANDLE[:3, 3] - point)
        np.testing.assert_allclose(scene.object_fk([angle], "handle_frame"), expected, atol=1e-9)


def test_a_decided_drawer_slides_along_the_estimated_direction_to_its_travel():
    direction = np.array([-0.98, 0.2, 0.0]) / np.linalg.norm([-0.98, 0.2, 0.0])
    h = sabre.DetectedHandle(HANDLE, drawer_travel=0.4)
    scene = sabre.Scene.from_handle("royalpanda", h, estimate("prismatic", direction, HANDLE[:3, 3]))
    np.testing.assert_allclose(scene.object_fk([0.1], "handle_frame")[:3, 3] - HANDLE[:3, 3], 0.1 * direction, atol=1e-9)
    assert scene.o_upper[0] == pytest.approx(0.4)


def test_the_estimator_tells_an_arc_from_a_line_through_its_python_face():
    rng = np.random.default_rng(3)
    hinge, r = np.array([0.94, 0.3, 0.75]), 0.42
    start = HANDLE[:3, 3]
    angles = np.linspace(0.0, math.radians(25), 1500)
    arc = np.array([hinge + rotation(np.array([0, 0, -1.0]), a) @ (start - hinge) for a in angles])
    est = sabre.ArticulationEstimator(HANDLE)
    e = est.update(np.arange(len(angles)) * 1e-3, arc + rng.normal(0, 0.002, arc.shape))
    assert e.kind == "revolute" and e.geometry == "revolute"
    assert math.degrees(math.acos(abs(e.axis @ [0, 0, 1.0]))) < 3.0
    assert np.linalg.norm((e.point - hinge)[:2]) < 0.03 and abs(e.radius - r) < 0.03
    assert e.axis @ [0, 0, -1.0] > 0  # the opening is right-handed about the reported axis
    assert e.opening == pytest.approx(math.radians(25), abs=math.radians(2))
    line = start + np.outer(np.linspace(0, 0.2, 2000), [-1.0, 0.0, 0.0])
    est = sabre.ArticulationEstimator(HANDLE, prior="door")
    e = est.update(np.arange(2000) * 1e-3, line + rng.normal(0, 0.002, line.shape))
    assert e.kind == "prismatic" and np.degrees(np.arccos(e.axis @ [-1.0, 0.0, 0.0])) < 2.0
    assert e.opening == pytest.approx(0.2, abs=0.01)
    assert est.points.shape[1] == 5


def test_the_estimator_refuses_bad_input_whole():
    est = sabre.ArticulationEstimator(HANDLE)
    with pytest.raises(InvalidValueError):
        sabre.ArticulationEstimator(HANDLE, prior=1.5)
    with pytest.raises(InvalidValueError):
        sabre.ArticulationEstimator(HANDLE, prior="wardrobe")
    with pytest.raises(InvalidValueError):
        sabre.ArticulationConfig(radius=(0.5, 0.2))
    with pytest.raises(ShapeError):
        est.update([0.0, 0.001], np.zeros((3, 3)))
    with pytest.raises(InvalidValueError):
        est.update([0.0, 0.001], [[0.9, 0.0, 0.7], [np.nan, 0.0, 0.7]])
    assert est.estimate.samples == 0  # a bad batch is refused whole
    est.reference = [0.9, -0.1, 0.75]
    np.testing.assert_allclose(est.reference, [0.9, -0.1, 0.75])
    # a hand held still away from the reference reads as open along the first pull, never below closed
    assert est.opening_at([0.85, -0.1, 0.75]) == pytest.approx(0.05)
    assert est.opening_at([0.95, -0.1, 0.75]) == 0.0


def test_the_controller_takes_a_rebuilt_scene_with_its_plan_in_force():
    first = sabre.Scene.from_handle("royalpanda", sabre.DetectedHandle(HANDLE))
    controller = sabre.Controller(first, OpenObject(), sabre.ControllerConfig(rollouts=8, horizon=0.3, threads=1))
    x = first.start_state()
    controller.update(x, 0.0)
    nominal, t0, phase = controller.nominal.copy(), controller.nominal_t0, controller.phase
    door = sabre.Scene.from_handle(
        "royalpanda", sabre.DetectedHandle(HANDLE), estimate("revolute", [0, 0, -1.0], [0.94, 0.3, 0.75])
    )
    controller.set_scene(door)
    assert controller.scene is door and controller.model.scene is door and controller.scene_changes == 1
    np.testing.assert_array_equal(controller.nominal, nominal)
    assert controller.nominal_t0 == t0 and controller.phase == phase
    controller.update(x, 0.05)  # plans on in the new model
    other = example_scene("ur5_mobile", "drawer")
    with pytest.raises(InvalidValueError, match="robot"):
        controller.set_scene(other)


def test_an_estimated_object_takes_no_samples_and_refuses_a_wrench_of_another_length():
    estimated = sabre.EstimatedObject("royalpanda", sabre.DetectedHandle(HANDLE))
    assert estimated.observe([], np.zeros((0, estimated.scene.nq))).samples == 0
    assert estimated.history == []
    q = estimated.scene.start_state()[: estimated.scene.nq]
    with pytest.raises(ShapeError, match="wrench"):
        estimated.observe([0.0, 0.001], np.tile(q, (2, 1)), np.zeros((3, 6)))
    # the first pull's scene reads the robot's joints and a closed object
    x = estimated.state(q, np.zeros_like(q))
    assert x.shape == (estimated.scene.nx,) and x[-2:].tolist() == [0.0, 0.0]
