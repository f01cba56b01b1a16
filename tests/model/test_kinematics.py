"""Kinematics through the Python API, against independent references: finite differences of fk, the
hand-computed Panda zero pose, and the object geometry documented in assets/objects/README.md."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

import sabre

MOUNT = np.array([0.295, 0.005, 0.445])  # panda_link0 on base_link
ROBOT_URDF = Path(__file__).resolve().parents[2] / "assets" / "robots" / "royalpanda.urdf"
ROBOT_MASSES = {
    link.get("name"): float(link.find("inertial/mass").get("value"))
    for link in ET.parse(ROBOT_URDF).getroot().findall("link")
    if link.find("inertial") is not None
}


def rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rpy_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """URDF convention: R = Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr, cp, sp = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    return rot_z(yaw) @ ry @ rx


def axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues' formula."""
    k = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * kx + (1 - np.cos(angle)) * kx @ kx


def fd_jacobian(scene: sabre.Scene, q: np.ndarray, frame: str, h: float = 1e-6) -> np.ndarray:
    """Central differences: linear rows dp/dq, angular rows vee(dR/dq Rᵀ)."""
    r0 = scene.fk(q, frame)[:3, :3]
    J = np.zeros((6, scene.nq))
    for i in range(scene.nq):
        dq = np.zeros(scene.nq)
        dq[i] = h
        tp, tm = scene.fk(q + dq, frame), scene.fk(q - dq, frame)
        J[:3, i] = (tp[:3, 3] - tm[:3, 3]) / (2 * h)
        w = (tp[:3, :3] - tm[:3, :3]) / (2 * h) @ r0.T
        J[3:, i] = 0.5 * np.array([w[2, 1] - w[1, 2], w[0, 2] - w[2, 0], w[1, 0] - w[0, 1]])
    return J


def test_jacobian_matches_finite_differences(scene, random_q):
    for _ in range(3):
        q = random_q(scene)
        for frame in ("grasp", "hook_finger", "panda_link5"):
            J = scene.jacobian(q, frame)
            assert J.shape == (6, scene.nq) and J.dtype == np.float64
            np.testing.assert_allclose(J, fd_jacobian(scene, q, frame), atol=1e-6, err_msg=f"{frame} at q={q}")


def test_fk_zero_configuration_is_the_panda_zero_pose(scene):
    T = scene.fk(np.zeros(scene.nq), "panda_link8")
    assert T.shape == (4, 4)
    # Panda at q = 0: flange 0.088 m forward and 0.926 m above the arm base, pointing down.
    np.testing.assert_allclose(T[:3, 3], MOUNT + [0.088, 0.0, 0.926], atol=1e-9)
    np.testing.assert_allclose(T[:3, :3], np.diag([1.0, -1.0, -1.0]), atol=1e-9)
    np.testing.assert_allclose(T[3], [0, 0, 0, 1], atol=0)
    # the elbow (link 4) sits 0.0825 m forward at the height d1 + d3 = 0.649 m
    np.testing.assert_allclose(scene.fk(np.zeros(scene.nq), "panda_link4")[:3, 3], MOUNT + [0.0825, 0.0, 0.649], atol=1e-9)


def test_fk_of_a_known_configuration_with_base_motion(scene):
    q = np.zeros(scene.nq)
    q[:3] = [1.0, -0.5, np.pi / 2]  # base at (1, -0.5), turned to face +y
    q[scene.joint_names.index("panda_joint2")] = 0.4  # shoulder tilts the upper arm forward
    T = scene.fk(q, "panda_link3")
    shoulder = MOUNT + [0.0, 0.0, 0.333]
    upper_arm = 0.316 * np.array([np.sin(0.4), 0.0, np.cos(0.4)])
    expected = np.array([1.0, -0.5, 0.0]) + rot_z(np.pi / 2) @ (shoulder + upper_arm)
    np.testing.assert_allclose(T[:3, 3], expected, atol=1e-9)
    # link 3's orientation: base yaw, then the joint-2 tilt about the (base) y axis
    ry = axis_angle([0, 1, 0], 0.4)
    np.testing.assert_allclose(T[:3, :3], rot_z(np.pi / 2) @ ry, atol=1e-9)


def test_fk_accepts_integer_arrays_like_floats(scene):
    q = np.array([1, -1, 0, 0, 0, 0, -2, 0, 2, 1])
    np.testing.assert_array_equal(scene.fk(q, "grasp"), scene.fk(q.astype(float), "grasp"))
    np.testing.assert_array_equal(scene.jacobian(list(q), "grasp"), scene.jacobian(q.astype(float), "grasp"))


def test_mass_matrix_is_symmetric_positive_definite(scene, random_q):
    for _ in range(3):
        q = random_q(scene)
        M, g = scene.mass_matrix(q)
        assert M.shape == (scene.nq, scene.nq) and g.shape == (scene.nq,)
        np.testing.assert_allclose(M, M.T, atol=1e-10)
        assert np.linalg.eigvalsh(M).min() > 0
        # base_x carries every link but the world; base_y every link but base_x_link (URDF masses)
        assert M[0, 0] == pytest.approx(sum(ROBOT_MASSES.values()), rel=1e-12)
        assert M[1, 1] == pytest.approx(sum(ROBOT_MASSES.values()) - ROBOT_MASSES["base_x_link"], rel=1e-12)
        assert M[0, 1] == pytest.approx(0.0, abs=1e-9)
        # horizontal base motion needs no gravity torque
        np.testing.assert_allclose(g[:3], 0.0, atol=1e-9)


# Object geometry from assets/objects/README.md (object frame): hinge point and axis, or drawer axis;
# handle_frame position when closed and at the upper limit.
OBJECTS = {
    "shelf": dict(
        origin=[0, 0.1475, 0.75],
        axis=[0, 0, -1],
        revolute=True,
        upper=1.57,
        vertical=True,
        closed=[-0.061, -0.1175, 0.75],
        open=[-0.265, 0.208, 0.75],
        z_open=[0, -1, 0],
    ),
    "microwave": dict(
        origin=[0, 0.15, 0.95],
        axis=[0, 0, -1],
        revolute=True,
        upper=1.57,
        vertical=True,
        closed=[-0.061, -0.12, 0.95],
        open=[-0.270, 0.211, 0.95],
        z_open=[0, -1, 0],
    ),
    "dishwasher": dict(
        origin=[0, 0, 0.07],
        axis=[0, -1, 0],
        revolute=True,
        upper=1.57,
        vertical=False,
        closed=[-0.061, 0, 0.58],
        open=[-0.510, 0, 0.009],
        z_open=[0, 0, 1],
    ),
    "drawer": dict(
        origin=[0, 0, 0.70],
        axis=[-1, 0, 0],
        revolute=False,
        upper=0.55,
        vertical=False,
        closed=[-0.061, 0, 0.70],
        open=[-0.611, 0, 0.70],
        z_open=[1, 0, 0],
    ),
}
POSE = np.array([1.3, -0.25, 0.05, 0.0, 0.0, 0.4])  # a placement other than the default


@pytest.mark.parametrize("name", list(OBJECTS))
def test_handle_follows_the_documented_path(name):
    spec = OBJECTS[name]
    scene = sabre.Scene.load("royalpanda", name, obj_pose=POSE)
    assert scene.no == 1
    assert scene.object_is_revolute == spec["revolute"]
    np.testing.assert_allclose(scene.o_upper, [spec["upper"]])
    R0, p0 = rpy_matrix(*POSE[3:]), POSE[:3]
    np.testing.assert_allclose(scene.object_pose[:3, :3], R0, atol=1e-12)
    world = lambda v: p0 + R0 @ np.asarray(v, dtype=float)
    hinge = world(spec["origin"])
    axis = R0 @ np.asarray(spec["axis"], dtype=float)

    closed = scene.object_fk([0.0], "handle_frame")
    np.testing.assert_allclose(closed[:3, 3], world(spec["closed"]), atol=1e-9)
    # README: z into the closed door (+x), x along the bar (+z for vertical bars, +y for horizontal
    # ones) and y = z × x; as columns of the rotation in the object frame:
    x_bar = [0.0, 0, 1] if spec["vertical"] else [0.0, 1, 0]
    frame_axes = np.column_stack([x_bar, np.cross([1.0, 0, 0], x_bar), [1.0, 0, 0]])
    np.testing.assert_allclose(closed[:3, :3], R0 @ frame_axes, atol=1e-9)
    opened = scene.object_fk([spec["upper"]], "handle_frame")
    np.testing.assert_allclose(opened[:3, 3], world(spec["open"]), atol=2e-3)  # README gives 3 decimals
    np.testing.assert_allclose(opened[:3, 2], R0 @ spec["z_open"], atol=2e-3)

    for o in np.linspace(0.0, spec["upper"], 7):
        T = scene.object_fk(np.array([o]), "handle_frame")
        if spec["revolute"]:
            # a rotation by o about the hinge axis (positive values open, right-hand rule about axis)
            Ra = axis_angle(axis, o)
            np.testing.assert_allclose(T[:3, 3], hinge + Ra @ (closed[:3, 3] - hinge), atol=1e-9)
            np.testing.assert_allclose(T[:3, :3], Ra @ closed[:3, :3], atol=1e-9)
            # hence the distance to the hinge axis is constant
            r = lambda p: np.linalg.norm(np.cross(p - hinge, axis))
            assert r(T[:3, 3]) == pytest.approx(r(closed[:3, 3]), abs=1e-9)
        else:
            # the drawer translates by exactly o along its axis, orientation unchanged
            np.testing.assert_allclose(T[:3, 3] - closed[:3, 3], o * axis, atol=1e-12)
            np.testing.assert_allclose(T[:3, :3], closed[:3, :3], atol=1e-12)
    # The batched call (used by guides) gives the poses just checked, in any leading shape.
    openings = np.linspace(0.0, spec["upper"], 6).reshape(2, 3, 1)
    batch = scene.object_fk_many(openings, "handle_frame")
    assert batch.shape == (2, 3, 4, 4)
    for o, T in zip(openings.reshape(-1), batch.reshape(-1, 4, 4)):
        np.testing.assert_array_equal(T, scene.object_fk([o], "handle_frame"))


def test_default_object_placement_is_documented():
    for name, x in (("shelf", 1.0), ("microwave", 1.0), ("dishwasher", 1.2), ("drawer", 1.2)):
        pose = sabre.Scene.load("royalpanda", name).object_pose
        np.testing.assert_allclose(pose, [[1, 0, 0, x], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], atol=1e-12)
