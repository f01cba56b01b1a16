"""What a robot's parts are for: the attached tool and its frame, held joints, the base (planar joints
anywhere in q, or none), postures; declared, detected, or refused with a message naming the role."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

import sabre
from sabre import costs
from sabre.robot_examples import example_robot_data, example_robot_urdf, example_scene

ASSETS = Path(__file__).resolve().parents[2] / "assets"
PANDA = "robots/panda_description/urdf/panda.urdf"
HOOK_ON_HAND = sabre.Tool("panda_hand", xyz=(0.0, 0.0, 0.0584))


@pytest.fixture(scope="module")
def panda_urdf(tmp_path_factory) -> Path:
    """example-robot-data's Panda as it ships (no <sabre> block), with absolute mesh paths."""
    share = example_robot_data()
    text = (share / PANDA).read_text().replace("package://example-robot-data/", f"{share}/")
    path = tmp_path_factory.mktemp("panda") / "panda.urdf"
    path.write_text(text)
    return path


def test_a_tool_defines_the_control_frame_and_the_unused_fingers_are_held(panda_urdf):
    scene = sabre.Scene.from_urdf(panda_urdf, "drawer", tool=HOOK_ON_HAND)
    assert scene.tool_frame == "grasp" and scene.role_origins["tool_frame"] == "tool"
    assert scene.joint_names == tuple(f"panda_joint{i}" for i in range(1, 8))
    # the fingers do not move the grasp frame: held, at their home value (0 within their limits)
    assert scene.held_joints == {"panda_finger_joint1": 0.0, "panda_finger_joint2": 0.0}
    assert scene.role_origins["hold:panda_finger_joint1"] == "off the tool frame's chain"
    hand = scene.fk(scene.home_configuration(), "panda_hand")
    grasp = scene.fk(scene.home_configuration(), "grasp")
    np.testing.assert_allclose(np.linalg.solve(hand, grasp)[:3, 3], [0.0, 0.015, 0.0584 + 0.0366], atol=1e-12)
    # the hook's boxes ride on the hand: same link poses as the RoyalPanda's hook relative to its hand
    royal = sabre.Scene.load()
    q = royal.home_configuration()
    relative = np.linalg.solve(royal.fk(q, "panda_hand"), royal.fk(q, "hook_finger"))
    mine = np.linalg.solve(hand, scene.fk(scene.home_configuration(), "hook_finger"))
    np.testing.assert_allclose(mine, relative, atol=1e-12)


def test_held_robot_joints_take_the_given_value(panda_urdf):
    held = {"panda_finger_joint1": 0.04, "panda_finger_joint2": 0.04}
    scene = sabre.Scene.from_urdf(panda_urdf, "drawer", tool=HOOK_ON_HAND, robot_hold=held)
    assert scene.held_joints == held and scene.role_origins["hold:panda_finger_joint2"] == "declared"
    q = scene.home_configuration()
    finger = np.linalg.solve(scene.fk(q, "panda_hand"), scene.fk(q, "panda_leftfinger"))
    np.testing.assert_allclose(finger[:3, 3], [0.0, 0.04, 0.0584], atol=1e-12)
    with pytest.raises(sabre.UrdfError, match="outside its limits"):
        sabre.Scene.from_urdf(panda_urdf, "drawer", tool=HOOK_ON_HAND, robot_hold={"panda_finger_joint1": 0.1})
    with pytest.raises(sabre.UrdfError, match=r"'gripper'.*movable joints are: panda_joint1"):
        sabre.Scene.from_urdf(panda_urdf, "drawer", robot_hold={"gripper": 0.0})


def test_without_a_tool_the_single_frame_leaf_is_the_tool_frame(panda_urdf):
    scene = sabre.Scene.from_urdf(panda_urdf, "drawer")
    assert scene.tool_frame == "panda_hand_tcp" and scene.role_origins["tool_frame"] == "detected"
    assert scene.base_joints is None and scene.base_link == "panda_link0"


def test_a_robot_without_a_tool_frame_is_refused_by_the_task_naming_the_role():
    two_leaves = """<robot name="r"><link name="base"/><link name="arm"/><link name="tip_a"/><link name="tip_b"/>
      <joint name="j" type="revolute"><parent link="base"/><child link="arm"/><axis xyz="0 0 1"/>
        <limit lower="-1" upper="1" effort="10" velocity="1"/></joint>
      <joint name="a" type="fixed"><parent link="arm"/><child link="tip_a"/></joint>
      <joint name="b" type="fixed"><parent link="arm"/><child link="tip_b"/></joint></robot>"""
    scene = sabre.Scene.from_urdf_strings(two_leaves, (ASSETS / "objects" / "shelf.urdf").read_text())
    assert scene.tool_frame is None and scene.role_origins["tool_frame"] == "none"
    with pytest.raises(sabre.UnknownFrameError, match=r"OpenObject needs a tool frame.*tool_frame="):
        sabre.tasks.OpenObject().check(scene)
    named = sabre.Scene.from_urdf_strings(two_leaves, (ASSETS / "objects" / "shelf.urdf").read_text(), tool_frame="tip_b")
    assert named.tool_frame == "tip_b" and named.role_origins["tool_frame"] == "declared"
    with pytest.raises(sabre.UrdfError, match="tool frame 'nowhere' is not a link"):
        sabre.Scene.from_urdf_strings(two_leaves, (ASSETS / "objects" / "shelf.urdf").read_text(), tool_frame="nowhere")


def test_tool_errors_name_the_link_or_the_clash(panda_urdf):
    with pytest.raises(sabre.UrdfError, match="parent link 'wrist' is not a link of the robot"):
        sabre.Scene.from_urdf(panda_urdf, "drawer", tool=sabre.Tool("wrist"))
    with pytest.raises(sabre.UrdfError, match="tool's link 'hook_finger' is also a link of the robot"):
        sabre.Scene.from_urdf(ASSETS / "robots" / "royalpanda.urdf", "drawer", tool=sabre.Tool("panda_hand"))
    with pytest.raises(sabre.InvalidValueError, match="neither a shipped tool"):
        sabre.Tool("panda_hand", "spoon").source()


def arm_first(text: str) -> str:
    """The RoyalPanda's URDF with its base joints written after the arm's: q starts with the arm."""
    joints = re.findall(r'  <joint name="base_(?:x|y|yaw)".*?</joint>\n', text, re.DOTALL)
    assert len(joints) == 3
    for j in joints:
        text = text.replace(j, "")
    return text.replace("</robot>", "".join(joints) + "</robot>").replace(
        '<base type="planar" joints="base_x base_y base_yaw" link="base_link"/>', ""
    )


def test_base_joints_anywhere_in_q_are_detected_and_drive_the_base_rows_and_costs():
    text = arm_first((ASSETS / "robots" / "royalpanda.urdf").read_text())
    scene = sabre.Scene.from_urdf_strings(text, (ASSETS / "objects" / "shelf.urdf").read_text())
    assert scene.joint_names[-3:] == ("base_x", "base_y", "base_yaw")
    assert scene.base_indices == (7, 8, 9) and scene.role_origins["base"] == "detected"
    assert scene.base_link == "base_link"
    x = scene.default_state()
    x[7:9] = (2.5, -0.5)  # base beyond x_max = 2
    rows = sabre.SafetyFilter(scene).constraint_rows(x)
    h = dict(zip(sabre.SafetyFilter(scene).row_names, np.asarray(rows.h)))
    assert h["base_box:x"] < 0.0 < h["base_box:y"]
    assert costs.BaseBox().compile(scene).core.num_terms == 1
    start = sabre.Scene.load().start_state()
    moved = scene.default_state()
    moved[:7], moved[7:10] = start[3:10], start[:3]
    np.testing.assert_allclose(scene.fk(moved[:10], "grasp"), sabre.Scene.load().fk(start[:10], "grasp"), atol=1e-12)


def test_a_fixed_base_has_no_base_rows_and_refuses_the_base_box_cost():
    scene = example_scene("panda_pedestal", "drawer")
    assert scene.base_joints is None and scene.base_link == "pedestal" and scene.role_origins["base"] == "declared"
    names = sabre.SafetyFilter(scene).row_names
    assert not any(n.startswith("base_box") for n in names)
    with pytest.raises(sabre.InvalidValueError, match="BaseBox needs a robot with a holonomic base"):
        costs.BaseBox().compile(scene)
    # the safety terms leave the base clearance out: a fixed base cannot get out of a door's way
    assert not any(isinstance(t, costs.BaseClearance) for t in sabre.tasks.SafetyWeights().terms(scene).terms)


def test_declared_base_joints_must_make_a_planar_base(panda_urdf):
    with pytest.raises(sabre.UrdfError, match="must be the first three movable joints"):
        sabre.Scene.from_urdf(panda_urdf, "drawer", base=("panda_joint2", "panda_joint3", "panda_joint4"))
    with pytest.raises(sabre.UrdfError, match="'panda_joint1' is not a base joint"):
        sabre.Scene.from_urdf(panda_urdf, "drawer", base=("panda_joint1", "panda_joint2", "panda_joint3"))
    with pytest.raises(sabre.InvalidValueError, match="'fixed' or three joint names"):
        sabre.Scene.from_urdf(panda_urdf, "drawer", base=("panda_joint1",))


def test_a_holonomic_base_from_example_robot_data_parts_is_detected():
    scene = example_scene("ur5_mobile", "shelf")
    assert scene.base_joints == ("mobile_x", "mobile_y", "mobile_yaw") and scene.role_origins["base"] == "detected"
    assert scene.base_link == "mobile_base" and scene.tool_frame == "grasp"
    np.testing.assert_allclose(scene.start_configuration()[:3], [-3.0, -3.0, 0.0])
    assert any(isinstance(t, costs.BaseClearance) for t in sabre.tasks.SafetyWeights().terms(scene).terms)


def test_postures_default_from_the_limits_and_follow_declarations(panda_urdf):
    scene = sabre.Scene.from_urdf(panda_urdf, "drawer", tool=HOOK_ON_HAND, home={"panda_joint4": -1.0})
    home = scene.home_configuration()
    # 0 where it lies within the limits, the declared value, and the middle of limits that exclude 0
    assert home[0] == 0.0 and home[3] == -1.0
    scene = sabre.Scene.from_urdf(panda_urdf, "drawer", tool=HOOK_ON_HAND)
    assert scene.home_configuration()[3] == pytest.approx(0.5 * (-3.0718 - 0.0698))
    np.testing.assert_array_equal(scene.start_state()[: scene.nq], scene.home_configuration())
    with pytest.raises(sabre.UrdfError, match="home value 1 of joint 'panda_joint4' is outside its limits"):
        sabre.Scene.from_urdf(panda_urdf, "drawer", home={"panda_joint4": 1.0})


def test_collada_meshes_load_as_hulls_and_as_triangles(tmp_path):
    share = example_robot_data()
    dae = share / "robots/panda_description/meshes/visual/link4.dae"
    stl = share / "robots/panda_description/meshes/collision/link4.stl"
    vertices, faces = sabre._core.mesh_triangles(dae, [1.0, 1.0, 1.0])
    vertices = np.asarray(vertices)
    assert len(faces) > 100 and np.asarray(faces).max() < len(vertices)
    robot = (ASSETS / "robots" / "royalpanda.urdf").read_text()
    obj = (ASSETS / "objects" / "shelf.urdf").read_text()
    hulls = {}
    for path in (dae, stl):
        bar = obj.replace('<box size="0.01 0.01 0.17"/>', f'<mesh filename="{path}"/>')  # the visual and the collision
        assert bar != obj
        scene = sabre.Scene.from_urdf_strings(robot, bar)
        hulls[path.suffix] = next(s for s in scene.object_collisions if s.kind == "mesh")
    # the visual and the collision mesh of the same link have about the same extent (the collision
    # one is a little larger, as the description's are)
    np.testing.assert_allclose(hulls[".dae"].size, hulls[".stl"].size, atol=0.012)
    np.testing.assert_allclose(np.ptp(vertices, axis=0) / 2.0, hulls[".dae"].size, atol=1e-6)


def test_a_gain_floor_that_would_make_a_light_joint_diverge_is_refused():
    scene = example_scene("panda_pedestal", "drawer")
    low = sabre.LowLevelController(scene, dt=0.001)
    stable = low.max_stable_floor
    assert 0.05 < stable < 1.0
    auto = sabre.LowLevelController(scene, dt=0.001, gain_inertia_floor="auto")
    assert auto.gain_inertia_floor == pytest.approx(0.5 * stable)
    plant = sabre.Plant(scene)
    plant.reset(scene.start_state())
    auto.track(plant, np.zeros(scene.nq), 5)
    heavy = sabre.LowLevelController(scene, dt=0.001, gain_inertia_floor=2.0 * stable)
    with pytest.raises(sabre.InvalidValueError, match=r"joint 'panda_joint7'.*diverges.*at most"):
        heavy.track(plant, np.zeros(scene.nq), 1)


def test_the_viewer_draws_every_link_of_any_robot_from_its_visuals():
    pytest.importorskip("viser")
    from sabre.viz.viewer import Viewer

    scene = example_scene("ur5_mobile", "dishwasher")
    meshes = [v for v in scene.robot_visuals if v.kind == "mesh"]
    assert {v.link for v in meshes} >= {"shoulder_link", "forearm_link", "wrist_3_link"}
    assert all(v.mesh is not None and v.mesh.endswith(".dae") for v in meshes)
    viewer = Viewer(scene, port=0)
    try:
        assert {"mobile_base", "upper_arm_link", "hook_finger"} <= set(viewer.robot_links)
        viewer.show_state(scene.start_state())
    finally:
        viewer.close()


def test_example_urdfs_point_into_the_package_and_copy_no_mesh(tmp_path):
    path = example_robot_urdf("panda_pedestal", tmp_path)
    text = path.read_text()
    share = str(example_robot_data())
    assert "package://" not in text and text.count(share) >= 10
    assert not any(p.suffix in (".stl", ".dae") for p in tmp_path.iterdir())
