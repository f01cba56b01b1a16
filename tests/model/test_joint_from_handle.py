"""The joint to open, found from the handle: `Scene.from_urdf(..., handle=...)` keeps the movable joint
that moves the handle's link and holds the others (`hold=` still sets where); a handle moved by
several joints, or by none, is an error listing the candidates; `OpenObject` on a scene with several
movable joints names the joint of its handle and the call that picks it."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

import sabre

ASSETS = Path(__file__).resolve().parents[2] / "assets"
ROBOT = ASSETS / "robots" / "royalpanda.urdf"
CABINET = ASSETS / "objects" / "examples" / "mesh_cabinet" / "urdf" / "cabinet.urdf"


def cabinet(**options) -> sabre.Scene:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sabre.AssumedInertialWarning)
        return sabre.Scene.from_urdf(ROBOT, CABINET, [1.5, 0.0, 0.0, 0.0, 0.0, 0.0], **options)


@pytest.mark.parametrize("part", range(4))
def test_the_handle_names_the_joint_and_the_other_parts_are_held_shut(part):
    every = cabinet()
    assert every.object_joint_names == ("joint_0", "joint_1", "joint_2", "joint_3")
    scene = cabinet(handle=f"handle_{part}")
    assert scene.object_joint_names == (f"joint_{part}",)
    opened = np.zeros(4)
    opened[part] = 0.3
    for frame in ("handle_0", "handle_1", "handle_2", "handle_3"):  # the others stay where they are closed
        np.testing.assert_allclose(scene.object_fk([0.3], frame), every.object_fk(opened, frame), atol=1e-12)


def test_hold_still_sets_where_the_others_are_held():
    scene = cabinet(handle="handle_2", hold={"joint_3": 0.2, "joint_0": 0.5})
    every = cabinet()
    np.testing.assert_allclose(scene.object_fk([0.1], "handle_3"), every.object_fk([0.5, 0.0, 0.1, 0.2], "handle_3"), atol=1e-12)
    np.testing.assert_allclose(scene.object_fk([0.1], "handle_0"), every.object_fk([0.5, 0.0, 0.1, 0.2], "handle_0"), atol=1e-12)
    with pytest.raises(sabre.UrdfError, match="cannot hold 'joint_2'"):
        cabinet(handle="handle_2", hold={"joint_2": 0.1})


def test_a_handle_moved_by_several_joints_or_none_lists_the_candidates():
    urdf = """<robot name="nested">
      <link name="body"><collision><geometry><box size="0.4 0.4 0.4"/></geometry></collision></link>
      <link name="drawer"><collision><geometry><box size="0.02 0.3 0.2"/></geometry></collision></link>
      <link name="flap"><collision><origin xyz="0 0 0.05"/><geometry><box size="0.01 0.3 0.1"/></geometry></collision></link>
      <link name="pull"><collision><geometry><box size="0.01 0.15 0.01"/></geometry></collision></link>
      <link name="knob"><collision><geometry><box size="0.01 0.15 0.01"/></geometry></collision></link>
      <joint name="slide" type="prismatic"><parent link="body"/><child link="drawer"/><axis xyz="-1 0 0"/>
        <limit lower="0" upper="0.3" effort="1" velocity="1"/></joint>
      <joint name="flap_hinge" type="revolute"><parent link="drawer"/><child link="flap"/><axis xyz="0 1 0"/>
        <limit lower="0" upper="1" effort="1" velocity="1"/></joint>
      <joint name="pull_mount" type="fixed"><parent link="flap"/><child link="pull"/><origin xyz="-0.05 0 0.05"/></joint>
      <joint name="knob_mount" type="fixed"><parent link="body"/><child link="knob"/><origin xyz="-0.25 0 0"/></joint>
    </robot>"""
    robot = ROBOT.read_text()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sabre.AssumedInertialWarning)
        with pytest.raises(
            sabre.UrdfError, match="moved by several joints: slide, flap_hinge; name the one to open with `joint`"
        ):
            sabre.Scene.from_urdf_strings(robot, urdf, handle="pull")
        flap = sabre.Scene.from_urdf_strings(robot, urdf, handle="pull", joint="flap_hinge")
        assert flap.object_joint_names == ("flap_hinge",)
        with pytest.raises(sabre.UrdfError, match="is on a part no joint moves; the movable joints are: slide, flap_hinge"):
            sabre.Scene.from_urdf_strings(robot, urdf, handle="knob")
        with pytest.raises(sabre.UnknownFrameError, match="no_such_link"):
            sabre.Scene.from_urdf_strings(robot, urdf, handle="no_such_link")


def test_a_joint_that_does_not_move_the_handle_is_refused():
    with pytest.raises(sabre.UrdfError, match="joint 'joint_0' does not move handle 'handle_2'; it is moved by: joint_2"):
        cabinet(handle="handle_2", joint="joint_0")
    assert cabinet(handle="handle_2", joint="joint_2").object_joint_names == ("joint_2",)


def test_open_object_on_the_whole_cabinet_names_the_joint_of_its_handle():
    config = sabre.ControllerConfig(rollouts=8, horizon=0.15)
    with pytest.raises(sabre.InvalidValueError) as error:
        sabre.Controller(cabinet(), sabre.tasks.OpenObject(handle="handle_3"), config)
    message = str(error.value)
    assert "'handle_3' is moved by 'joint_3'" in message and "Scene.from_urdf(..., handle='handle_3')" in message
    # the handle of a part the scene holds shut cannot be opened, and the message says how to load it instead
    with pytest.raises(sabre.InvalidValueError, match=r"does not move with the scene's joint 'joint_2'.*handle='handle_3'"):
        sabre.Controller(cabinet(handle="handle_2"), sabre.tasks.OpenObject(handle="handle_3"), config)
    sabre.Controller(cabinet(handle="handle_3"), sabre.tasks.OpenObject(handle="handle_3"), config)
