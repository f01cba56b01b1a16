"""The handle frame inferred from mesh handles as real models bring them: tilted, asymmetric, split into
several convex pieces, U-shaped, mounted on a door leaf that is itself mesh pieces; and the reasons
given when there is no bar to infer. Every expected frame is composed by hand from the numbers the
test wrote into the files, not from sabre's geometry."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

import sabre
from sabre.experiments import mesh_files
from sabre.handles import infer_handle_frame

ROBOT = Path(__file__).resolve().parents[2] / "assets" / "robots" / "royalpanda.urdf"
HINGE = np.array([0.0, 0.2, 0.8])  # the door's hinge in the object frame; the leaf spans y ∈ [−0.2, 0.2]
MOUNT = np.array([-0.061, -0.32, 0.05])  # the handle link's origin in the door frame (the leaf's front is x = 0)
LEAF = '<collision><origin xyz="0.009 -0.2 0"/><geometry><box size="0.018 0.4 0.6"/></geometry></collision>'


def rot_x(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def turned(piece: mesh_files.Piece, rotation: np.ndarray) -> mesh_files.Piece:
    return piece[0] @ rotation.T, piece[1]


def collisions(files: list[str]) -> str:
    return "".join(f'<collision><geometry><mesh filename="{f}"/></geometry></collision>' for f in files)


def cabinet(handle: str, leaf: str = LEAF) -> str:
    """A carcass, a door hinged at HINGE and a handle link at MOUNT carrying ``handle`` collisions."""
    return f"""<robot name="cabinet">
  <link name="body"><collision><origin xyz="0.25 0 0.5"/><geometry><box size="0.45 0.44 1.0"/></geometry></collision></link>
  <link name="door">{leaf}</link>
  <link name="grip">{handle}</link>
  <joint name="hinge" type="revolute"><parent link="body"/><child link="door"/><origin xyz="{HINGE[0]} {HINGE[1]} {HINGE[2]}"/>
    <axis xyz="0 0 -1"/><limit lower="0" upper="1.5" effort="10" velocity="1"/></joint>
  <joint name="grip_mount" type="fixed"><parent link="door"/><child link="grip"/><origin xyz="{MOUNT[0]} {MOUNT[1]} {MOUNT[2]}"/></joint>
</robot>"""


def load(directory: Path, urdf: str, pose: tuple[float, ...] = (1.0, 0.0, 0.0, 0.0, 0.0, 0.0)) -> sabre.Scene:
    path = directory / "cabinet.urdf"
    path.write_text(urdf)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sabre.errors.AssumedInertialWarning)
        return sabre.Scene.from_urdf(ROBOT, path, list(pose))


def world_frame(scene: sabre.Scene) -> np.ndarray:
    return scene.object_fk(scene.o_lower, "grip") @ infer_handle_frame(scene, "grip")


def expected_world(pose: tuple[float, ...], centre: np.ndarray, along: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(centre, unit bar axis, into-the-door) in the world for an object at ``pose`` (yaw only), a bar
    centred at ``centre`` (grip frame) running along ``along`` (grip frame); closed door: the grip
    frame is the object frame shifted by HINGE + MOUNT."""
    yaw = rot_z(pose[5])
    origin = np.array(pose[:3])
    return origin + yaw @ (HINGE + MOUNT + centre), yaw @ along, yaw @ np.array([1.0, 0.0, 0.0])


def check(frame: np.ndarray, centre: np.ndarray, along: np.ndarray, into: np.ndarray, atol: float = 1e-6) -> None:
    np.testing.assert_allclose(frame[:3, 3], centre, atol=atol)
    np.testing.assert_allclose(frame[:3, 2], into, atol=atol)
    assert abs(frame[:3, 0] @ along) == pytest.approx(1.0, abs=atol)
    np.testing.assert_allclose(frame[:3, :3].T @ frame[:3, :3], np.eye(3), atol=1e-12)
    np.testing.assert_allclose(np.cross(frame[:3, 2], frame[:3, 0]), frame[:3, 1], atol=1e-12)


def u_handle(length: float, bar: mesh_files.Piece | None = None) -> list[tuple[str, mesh_files.Piece]]:
    """A vertical bar (along z, 0.01 thick, its centre at the origin) on two 0.057 m standoffs toward +x."""
    pieces = [("bar", bar or mesh_files.box((0.0, 0.0, 0.0), (0.01, 0.01, length)))]
    return pieces + [
        (f"leg_{k}", mesh_files.box((0.0325, 0.0, s * (length / 2 - 0.01)), (0.057, 0.01, 0.01))) for k, s in enumerate((-1, 1))
    ]


def test_a_tilted_handle_on_a_turned_cabinet(tmp_path):
    tilt = rot_x(np.radians(30.0))  # the bar leans 30° from vertical in the leaf's plane
    pieces = [(name, turned(piece, tilt)) for name, piece in u_handle(0.18)]
    mesh_files.write_obj(tmp_path / "grip.obj", pieces)
    pose = (2.0, -1.0, 0.1, 0.0, 0.0, 0.7)
    frame = world_frame(load(tmp_path, cabinet(collisions(["grip.obj"])), pose))
    centre, along, into = expected_world(pose, np.zeros(3), tilt @ np.array([0.0, 0.0, 1.0]))
    check(frame, centre, along, into)
    assert frame[2, 0] > 0.0  # within 45° of vertical: x points up


def test_an_asymmetric_handle_of_unevenly_meshed_pieces(tmp_path):
    # one half of the bar finely meshed (48 sides), the other coarsely (8), standoffs at −0.07 and +0.02:
    # the vertices crowd at one end, the shape is not symmetric about the bar's centre
    fine = mesh_files.prism((0.0, -0.05, 0.0), 1, 0.006, 0.1, sides=48)
    coarse = mesh_files.prism((0.0, 0.05, 0.0), 1, 0.006, 0.1, sides=8)
    legs = [(f"leg_{k}", mesh_files.box((0.0335, y, 0.0), (0.055, 0.01, 0.01))) for k, y in enumerate((-0.07, 0.02))]
    mesh_files.write_obj(tmp_path / "grip.obj", [("fine", fine), ("coarse", coarse), *legs])
    frame = world_frame(load(tmp_path, cabinet(collisions(["grip.obj"]))))
    centre, along, into = expected_world((1.0, 0, 0, 0, 0, 0), np.zeros(3), np.array([0.0, 1.0, 0.0]))
    check(frame, centre, along, into)
    assert frame[2, 1] > 0.99  # a horizontal bar: y = z × x points up


def test_a_bar_split_into_pieces_each_its_own_file(tmp_path):
    files = []
    for k, z in enumerate((-0.06, 0.0, 0.06)):
        mesh_files.write_stl(tmp_path / f"bar_{k}.stl", mesh_files.box((0.0, 0.0, z), (0.01, 0.01, 0.06)))
        files.append(f"bar_{k}.stl")
    for k, z in enumerate((-0.07, 0.07)):
        mesh_files.write_stl(tmp_path / f"leg_{k}.stl", mesh_files.box((0.0335, 0.0, z), (0.055, 0.01, 0.01)))
        files.append(f"leg_{k}.stl")
    scene = load(tmp_path, cabinet(collisions(files)))
    assert sum(s.link == "grip" for s in scene.object_collisions) == 5
    centre, along, into = expected_world((1.0, 0, 0, 0, 0, 0), np.zeros(3), np.array([0.0, 0.0, 1.0]))
    check(world_frame(scene), centre, along, into)


@pytest.mark.parametrize("as_one_piece", [True, False], ids=["one concave piece", "three convex pieces"])
def test_a_u_handle_is_grasped_at_its_bar_not_its_middle(tmp_path, as_one_piece):
    pieces = u_handle(0.16)
    if as_one_piece:  # a single concave U, as a CAD export writes it: it loads as its hull, a slab
        vertices = np.concatenate([p[0] for _, p in pieces])
        faces = np.concatenate([p[1] + 8 * k for k, (_, p) in enumerate(pieces)])
        mesh_files.write_stl(tmp_path / "grip.stl", (vertices, faces))
        handle = collisions(["grip.stl"])
    else:
        mesh_files.write_obj(tmp_path / "grip.obj", pieces)
        handle = collisions(["grip.obj"])
    scene = load(tmp_path, cabinet(handle))
    assert sum(s.link == "grip" for s in scene.object_collisions) == (1 if as_one_piece else 3)
    centre, along, into = expected_world((1.0, 0, 0, 0, 0, 0), np.zeros(3), np.array([0.0, 0.0, 1.0]))
    check(world_frame(scene), centre, along, into)  # the hull's middle would be 2.8 cm deeper


def test_a_panel_of_mesh_pieces_gives_the_frame_of_the_box_panel(tmp_path):
    mesh_files.write_obj(tmp_path / "grip.obj", u_handle(0.17))
    halves = [(f"half_{k}", mesh_files.box((0.009, -0.2, s * 0.15), (0.018, 0.4, 0.3))) for k, s in enumerate((-1, 1))]
    mesh_files.write_obj(tmp_path / "leaf.obj", halves)
    box_leaf = load(tmp_path, cabinet(collisions(["grip.obj"])))
    mesh_leaf = load(tmp_path, cabinet(collisions(["grip.obj"]), leaf=collisions(["leaf.obj"])))
    assert sum(s.link == "door" and s.kind == "mesh" for s in mesh_leaf.object_collisions) == 2
    np.testing.assert_allclose(infer_handle_frame(mesh_leaf, "grip"), infer_handle_frame(box_leaf, "grip"), atol=1e-9)
    centre, along, into = expected_world((1.0, 0, 0, 0, 0, 0), np.zeros(3), np.array([0.0, 0.0, 1.0]))
    check(world_frame(mesh_leaf), centre, along, into)


def test_a_round_knob_is_refused_saying_what_would_work(tmp_path):
    mesh_files.write_obj(tmp_path / "knob.obj", [("knob", mesh_files.prism((0.0, 0.0, 0.0), 0, 0.015, 0.03, sides=24))])
    scene = load(tmp_path, cabinet(collisions(["knob.obj"])))
    with pytest.raises(sabre.InvalidValueError, match="knob, not a bar") as error:
        infer_handle_frame(scene, "grip")
    assert "30 × 30 mm" in str(error.value) and "What works" in str(error.value)
    with pytest.raises(sabre.InvalidValueError, match="knob"):
        sabre.Controller(scene, sabre.tasks.OpenObject(handle="grip"), sabre.ControllerConfig(rollouts=8, horizon=0.15))


def test_a_handle_with_nothing_moving_behind_it_is_refused(tmp_path):
    mesh_files.write_obj(tmp_path / "grip.obj", u_handle(0.17))
    scene = load(tmp_path, cabinet(collisions(["grip.obj"]), leaf=""))
    with pytest.raises(sabre.InvalidValueError, match="no moving collision geometry besides the handle"):
        infer_handle_frame(scene, "grip")


def test_the_finger_comes_in_from_the_hinge_side_of_a_door_hinged_left_or_right(tmp_path):
    mesh_files.write_obj(tmp_path / "grip.obj", u_handle(0.17))
    left = load(tmp_path, cabinet(collisions(["grip.obj"])))  # hinged on its +y edge, the handle near −y
    right_hinged = (
        cabinet(collisions(["grip.obj"]))
        .replace(f'xyz="{HINGE[0]} {HINGE[1]} {HINGE[2]}"', f'xyz="{HINGE[0]} {-HINGE[1]} {HINGE[2]}"')
        .replace('<axis xyz="0 0 -1"/>', '<axis xyz="0 0 1"/>')
        .replace('<origin xyz="0.009 -0.2 0"/>', '<origin xyz="0.009 0.2 0"/>')
        .replace(f'xyz="{MOUNT[0]} {MOUNT[1]} {MOUNT[2]}"', f'xyz="{MOUNT[0]} {-MOUNT[1]} {MOUNT[2]}"')
    )
    right = load(tmp_path, right_hinged)
    for scene, hinge_y in ((left, HINGE[1]), (right, -HINGE[1])):
        frame = world_frame(scene)
        to_hinge = np.array([1.0, hinge_y, 0.0]) - frame[:3, 3]  # the object stands at (1, 0, 0)
        to_hinge[[0, 2]] = 0.0
        assert frame[:3, 1] @ to_hinge < 0.0  # the finger, on the −y side, is on the hinge's side
        assert abs(frame[2, 0]) == pytest.approx(1.0)
    assert world_frame(left)[2, 0] > 0.0 > world_frame(right)[2, 0]  # x up on the left door, down on the right
