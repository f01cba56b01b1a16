"""The handle frames the core infers, for every shipped object and example and for generated handles of
round primitives (a tilted cylinder, a capsule on cylinder standoffs, spheres capping a cylinder, a
drawer's box bar, a turned U of boxes on a right-hinged door): against the frames composed by hand
from the numbers written into the files, where there are such numbers, and against the frames the
NumPy implementation that the core replaced gave for the same objects (handle_frames.json, recorded
from it)."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

import sabre
from sabre.handles import handle_offset, infer_handle_frame

ASSETS = Path(__file__).resolve().parents[2] / "assets"
ROBOT = ASSETS / "robots" / "royalpanda.urdf"
EXAMPLES = ASSETS / "objects" / "examples"
RECORDED = json.loads((Path(__file__).with_name("handle_frames.json")).read_text())
S60, C60 = np.sin(np.radians(60.0)), np.cos(np.radians(60.0))
S20, C20 = np.sin(np.radians(20.0)), np.cos(np.radians(20.0))
LEFT_DOOR = """<joint name="hinge" type="revolute"><parent link="body"/><child link="door"/><origin xyz="0 0.2 0.8"/>
    <axis xyz="0 0 -1"/><limit lower="0" upper="1.5" effort="10" velocity="1"/></joint>"""
RIGHT_DOOR = """<joint name="hinge" type="revolute"><parent link="body"/><child link="door"/><origin xyz="0 -0.2 0.8"/>
    <axis xyz="0 0 1"/><limit lower="0" upper="1.5" effort="10" velocity="1"/></joint>"""
DRAWER = """<joint name="hinge" type="prismatic"><parent link="body"/><child link="door"/><origin xyz="0 0 0.6"/>
    <axis xyz="-1 0 0"/><limit lower="0" upper="0.35" effort="10" velocity="1"/></joint>"""


def collision(geometry: str, xyz: tuple[float, ...] = (0, 0, 0), rpy: tuple[float, ...] = (0, 0, 0)) -> str:
    origin = f'<origin xyz="{" ".join(repr(float(v)) for v in xyz)}" rpy="{" ".join(repr(float(v)) for v in rpy)}"/>'
    return f"<collision>{origin}<geometry>{geometry}</geometry></collision>"


def cabinet(joint: str, leaf_y: float, mount_y: float, grip: str) -> str:
    """A carcass, a part on ``joint`` whose leaf (0.018 thick, its front the part frame's x = 0 plane)
    is centred at y = ``leaf_y`` and a link ``grip`` 0.061 in front of the leaf at y = ``mount_y``."""
    leaf = collision('<box size="0.018 0.4 0.6"/>', (0.009, leaf_y, 0.0))
    return f"""<robot name="cabinet">
  <link name="body">{collision('<box size="0.45 0.44 1.0"/>', (0.25, 0.0, 0.5))}</link>
  <link name="door">{leaf}</link>
  <link name="grip">{grip}</link>
  {joint}
  <joint name="grip_mount" type="fixed"><parent link="door"/><child link="grip"/><origin xyz="-0.061 {mount_y} 0.05"/></joint>
</robot>"""


# name: (joint, leaf centre y, mount y, grip collisions, object pose, expected x in the grip frame).
# Every handle is centred on the grip frame's origin with z = +x into the leaf; x follows the rules of
# sabre.handles: vertical bars on a left (right) door point up (down), others keep y = z × x up.
GENERATED = {
    "cylinder tilted 60°": (
        LEFT_DOOR,
        -0.2,
        -0.32,
        collision('<cylinder radius="0.006" length="0.2"/>', rpy=(np.radians(60.0), 0.0, 0.0)),
        (1.0, 0.0, 0.0, 0.0, 0.0, 0.0),
        (0.0, S60, -C60),
    ),
    "capsule on cylinder standoffs": (
        LEFT_DOOR,
        -0.2,
        -0.32,
        collision('<capsule radius="0.007" length="0.16"/>')
        + "".join(
            collision('<cylinder radius="0.004" length="0.061"/>', (0.0305, 0.0, z), (0.0, np.pi / 2, 0.0)) for z in (-0.06, 0.06)
        ),
        (2.0, -1.0, 0.1, 0.0, 0.0, 0.7),
        (0.0, 0.0, 1.0),
    ),
    "spheres capping a cylinder": (
        LEFT_DOOR,
        -0.2,
        -0.32,
        collision('<cylinder radius="0.005" length="0.16"/>')
        + "".join(collision('<sphere radius="0.012"/>', (0.0, 0.0, z)) for z in (-0.08, 0.08)),
        (1.0, 0.0, 0.0, 0.0, 0.0, 0.0),
        (0.0, 0.0, 1.0),
    ),
    "box bar on a drawer": (
        DRAWER,
        0.0,
        0.05,
        collision('<box size="0.01 0.2 0.01"/>'),
        (1.2, 0.3, 0.05, 0.0, 0.0, 0.4),
        (0.0, 1.0, 0.0),
    ),
    "turned U on a right-hinged door": (
        RIGHT_DOOR,
        0.2,
        0.32,
        collision('<box size="0.01 0.01 0.16"/>', rpy=(np.radians(20.0), 0.0, 0.0))
        + "".join(
            collision('<box size="0.056 0.01 0.01"/>', (0.033, -S20 * z, C20 * z), (np.radians(20.0), 0.0, 0.0))
            for z in (-0.07, 0.07)
        ),
        (1.0, 0.5, 0.0, 0.0, 0.0, -0.3),
        (0.0, S20, -C20),
    ),
}


def load(urdf: str, pose: tuple[float, ...]) -> sabre.Scene:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sabre.AssumedInertialWarning)
        return sabre.Scene.from_urdf_strings(ROBOT.read_text(), urdf, list(pose))


def generated(name: str) -> sabre.Scene:
    joint, leaf_y, mount_y, grip, pose, _ = GENERATED[name]
    return load(cabinet(joint, leaf_y, mount_y, grip), pose)


def example(name: str) -> sabre.Scene:
    path = EXAMPLES / "mesh_cabinet" / "urdf" / "cabinet.urdf" if name == "mesh_cabinet" else EXAMPLES / f"{name}.urdf"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sabre.AssumedInertialWarning)
        return sabre.Scene.from_urdf(ROBOT, path)


EXAMPLE_HANDLES = [
    ("mesh_cabinet", "handle_0"),
    ("mesh_cabinet", "handle_1"),
    ("mesh_cabinet", "handle_2"),
    ("mesh_cabinet", "handle_3"),
    ("double_cabinet", "left_pull"),
    ("double_cabinet", "right_pull"),
    ("cad_shelf", "pull_bar"),
]


@pytest.mark.parametrize("obj", sabre.OBJECTS)
def test_a_shipped_handle_link_gives_the_declared_frame_and_the_recorded_one(obj):
    scene = sabre.Scene.load("royalpanda", obj)
    closed = scene.o_lower
    declared = np.linalg.inv(scene.object_fk(closed, "handle")) @ scene.object_fk(closed, "handle_frame")
    frame, offset = handle_offset(scene, "handle")
    assert frame == "handle"
    np.testing.assert_allclose(offset, declared, atol=1e-12)
    np.testing.assert_allclose(offset, RECORDED[f"{obj}/handle"], atol=1e-12)
    frame, offset = handle_offset(scene, "handle_frame")
    assert frame == "handle_frame"
    np.testing.assert_array_equal(offset, np.eye(4))


@pytest.mark.parametrize(("obj", "link"), EXAMPLE_HANDLES)
def test_an_example_objects_handle_frame_is_the_recorded_one(obj, link):
    scene = example(obj)
    np.testing.assert_allclose(infer_handle_frame(scene, link), RECORDED[f"{obj}/{link}"], atol=1e-12)
    frame, offset = handle_offset(scene, link)
    assert frame == link
    np.testing.assert_array_equal(offset, infer_handle_frame(scene, link))


@pytest.mark.parametrize("name", list(GENERATED))
def test_a_generated_handle_of_primitives_gives_the_frame_composed_by_hand_and_the_recorded_one(name):
    offset = infer_handle_frame(generated(name), "grip")
    x = np.array(GENERATED[name][5])
    z = np.array([1.0, 0.0, 0.0])
    expected = np.eye(4)
    expected[:3, 0], expected[:3, 1], expected[:3, 2] = x, np.cross(z, x), z
    np.testing.assert_allclose(offset, expected, atol=1e-9)
    np.testing.assert_allclose(offset, RECORDED[f"generated/{name}"], atol=1e-12)


def test_a_missing_handle_and_a_link_without_geometry_are_named_with_the_candidates():
    scene = generated("box bar on a drawer")
    with pytest.raises(sabre.errors.UnknownFrameError, match="links with collision geometry: body, door, grip"):
        handle_offset(scene, "pull")
    with pytest.raises(sabre.errors.UnknownFrameError, match="pull"):
        infer_handle_frame(scene, "pull")
    empty = load(cabinet(LEFT_DOOR, -0.2, -0.32, ""), (1.0, 0.0, 0.0, 0.0, 0.0, 0.0))
    with pytest.raises(sabre.InvalidValueError, match="has no collision geometry to infer a handle from"):
        infer_handle_frame(empty, "grip")
    np.testing.assert_array_equal(handle_offset(empty, "grip")[1], np.eye(4))
