"""An object written to another project's conventions: its own link and joint names, a `world` root
with a fixed joint, no `handle_frame`. Naming the handle link is enough: the inferred handle frame is
the one the shipped object declares, and the controller opens it."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

import sabre
from sabre import tasks
from sabre.handles import infer_handle_frame
from support.starts import pre_grasp_configuration

ASSETS = Path(__file__).resolve().parents[2] / "assets"
RENAMES = {
    "cabinet": "carcass_link",
    "door": "leaf",
    "drawer": "tray",
    "handle": "pull_bar",
    "articulation": "hinge",
    "handle_joint": "bar_mount",
}


def foreign_urdf(obj: str) -> str:
    """The shipped object as a CAD export would write it: renamed, world-rooted, no handle frame."""
    root = ET.fromstring((ASSETS / "objects" / f"{obj}.urdf").read_text())
    for element in list(root):
        if element.get("name") in ("handle_frame", "handle_frame_joint"):
            root.remove(element)
    for element in root.iter():
        for key in ("name", "link"):
            if element.tag in ("link", "joint", "parent", "child") and element.get(key) in RENAMES:
                element.set(key, RENAMES[element.get(key)])
    root.insert(0, ET.fromstring('<link name="world"/>'))
    root.insert(
        1,
        ET.fromstring(
            '<joint name="world_to_carcass" type="fixed"><parent link="world"/>'
            '<child link="carcass_link"/><origin xyz="0 0 0"/></joint>'
        ),
    )
    return ET.tostring(root, encoding="unicode")


def foreign_scene(obj: str) -> sabre.Scene:
    robot = (ASSETS / "robots" / "royalpanda.urdf").read_text()
    shipped = sabre.Scene.load("royalpanda", obj)
    pose = shipped.object_pose
    yaw = float(np.arctan2(pose[1, 0], pose[0, 0]))
    return sabre.Scene.from_urdf_strings(robot, foreign_urdf(obj), [pose[0, 3], pose[1, 3], pose[2, 3], 0.0, 0.0, yaw])


@pytest.mark.parametrize("obj", sabre.OBJECTS)
def test_the_inferred_handle_frame_is_the_one_the_shipped_object_declares(obj):
    shipped, foreign = sabre.Scene.load("royalpanda", obj), foreign_scene(obj)
    assert "handle_frame" not in foreign.object_frame_names
    task = tasks.OpenObject(handle="pull_bar")
    for o in np.linspace(shipped.o_lower[0], shipped.o_upper[0], 4):
        np.testing.assert_allclose(task.handle_pose(foreign, [o]), shipped.object_fk([o], "handle_frame"), atol=1e-9)
    # and in the handle link's own frame, on the shipped object itself
    lo = np.asarray(shipped.o_lower, dtype=float)
    declared = np.linalg.inv(shipped.object_fk(lo, "handle")) @ shipped.object_fk(lo, "handle_frame")
    np.testing.assert_allclose(infer_handle_frame(shipped, "handle"), declared, atol=1e-12)


def test_a_missing_handle_is_named_with_the_candidates_when_the_controller_is_built():
    foreign = foreign_scene("shelf")
    with pytest.raises(sabre.errors.UnknownFrameError, match="pull_bar"):
        sabre.Controller(foreign, tasks.OpenObject(), sabre.ControllerConfig(rollouts=8, horizon=0.15))
    with pytest.raises(sabre.errors.UnknownFrameError, match="pull_bar"):
        sabre.Controller(foreign, tasks.OpenObject(handle="knob"), sabre.ControllerConfig(rollouts=8, horizon=0.15))


def test_the_controller_opens_a_foreign_shelf_by_its_handle_link():
    shipped, foreign = sabre.Scene.load("royalpanda", "shelf"), foreign_scene("shelf")
    x0 = foreign.default_state()
    x0[: foreign.nq] = pre_grasp_configuration(shipped)  # the same robot in front of the same handle
    task = tasks.OpenObject(handle="pull_bar")
    controller = sabre.Controller(foreign, task, sabre.ControllerConfig(variant="N", seed=0, threads=1))
    episode = sabre.run_episode(foreign, controller, 15.0, seed=0, x0=x0, progress=False)
    assert episode.success
    assert episode.opening.max() >= 0.9 * task.target_opening(foreign)


DOUBLE = ASSETS / "objects" / "examples" / "double_cabinet.urdf"
# The left pull sits 0.045 m left of the cabinet's centre, the shelf's handle 0.1175 m right of its
# own: this placement puts the left pull where the shelf's handle stands in its default scene.
DOUBLE_POSE = [1.0, -0.1625, 0.0, 0.0, 0.0, 0.0]


def test_a_two_door_cabinet_needs_the_joint_to_open_and_lists_both():
    both = sabre.Scene.from_urdf(ASSETS / "robots" / "royalpanda.urdf", DOUBLE, DOUBLE_POSE)
    assert both.object_joint_names == ("left_hinge", "right_hinge")
    with pytest.raises(sabre.SabreError, match=r"joint=.*") as error:
        sabre.Controller(both, tasks.OpenObject(handle="left_pull"), sabre.ControllerConfig(rollouts=8, horizon=0.15))
    assert "left_hinge" in str(error.value) and "right_hinge" in str(error.value)
    with pytest.raises(sabre.errors.UrdfError, match="left_hinge, right_hinge"):
        sabre.Scene.from_urdf(ASSETS / "robots" / "royalpanda.urdf", DOUBLE, joint="hinge")
    with pytest.raises(sabre.errors.UrdfError, match="outside its limits"):
        sabre.Scene.from_urdf(ASSETS / "robots" / "royalpanda.urdf", DOUBLE, joint="left_hinge", hold={"right_hinge": -0.5})
    with pytest.raises(sabre.errors.InvalidValueError, match="finite"):
        sabre.Scene.from_urdf(ASSETS / "robots" / "royalpanda.urdf", DOUBLE, joint="left_hinge", hold={"right_hinge": np.nan})


def test_the_held_door_stays_where_it_was_held_while_the_other_opens():
    both = sabre.Scene.from_urdf(ASSETS / "robots" / "royalpanda.urdf", DOUBLE, DOUBLE_POSE)
    left = sabre.Scene.from_urdf(
        ASSETS / "robots" / "royalpanda.urdf", DOUBLE, DOUBLE_POSE, joint="left_hinge", hold={"right_hinge": 0.4}
    )
    for o in (0.0, 0.8, 1.5):
        for frame in ("left_pull", "right_pull"):
            np.testing.assert_allclose(left.object_fk([o], frame), both.object_fk([o, 0.4], frame), atol=1e-12)


def test_the_controller_opens_the_left_door_of_a_two_door_cabinet_and_leaves_the_right_shut():
    shipped = sabre.Scene.load("royalpanda", "shelf")
    scene = sabre.Scene.from_urdf(ASSETS / "robots" / "royalpanda.urdf", DOUBLE, DOUBLE_POSE, joint="left_hinge")
    task = tasks.OpenObject(handle="left_pull")
    # The left pull stands where the shelf's handle does: the shelf's scripted pre-grasp fits it.
    np.testing.assert_allclose(task.handle_pose(scene, [0.0])[:3, 3], shipped.object_fk([0.0], "handle_frame")[:3, 3], atol=1e-9)
    x0 = scene.default_state()
    x0[: scene.nq] = pre_grasp_configuration(shipped)
    controller = sabre.Controller(scene, task, sabre.ControllerConfig(variant="N", seed=0, threads=1))
    episode = sabre.run_episode(scene, controller, 15.0, seed=0, x0=x0, progress=False)
    assert episode.success
    assert episode.opening.max() >= 0.9 * task.target_opening(scene)
