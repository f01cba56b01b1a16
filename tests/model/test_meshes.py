"""Mesh collision geometry: URDF `<mesh>` files (STL and OBJ) found relative to the URDF, on
SABRE_MESH_PATH or through package://, reduced to their convex hull, cached on disk. A box written
as a mesh behaves like the box."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import sabre
from sabre.errors import UrdfError

trimesh = pytest.importorskip("trimesh")

ASSETS = Path(__file__).resolve().parents[2] / "assets"
BAR = '<geometry><box size="0.01 0.01 0.17"/></geometry>'
SHELF = (ASSETS / "objects" / "shelf.urdf").read_text()
ROBOT = (ASSETS / "robots" / "royalpanda.urdf").read_text()


def bar_mesh(directory: Path, suffix: str) -> Path:
    """The shelf's handle bar (0.01 × 0.01 × 0.17 m box) as a mesh file, with a few points inside."""
    box = trimesh.creation.box(extents=(0.01, 0.01, 0.17))
    path = directory / f"bar.{suffix}"
    box.export(path)
    return path


def shelf_with_mesh_bar(filename: str) -> str:
    assert SHELF.count(BAR) == 2  # the bar's visual and collision
    return SHELF.replace(BAR, f'<geometry><mesh filename="{filename}"/></geometry>')


@pytest.fixture
def cache(tmp_path, monkeypatch):
    directory = tmp_path / "cache"
    monkeypatch.setenv("SABRE_CACHE_DIR", str(directory))
    return directory


@pytest.mark.parametrize("suffix", ["stl", "obj"])
def test_a_mesh_bar_next_to_its_urdf_is_its_convex_hull_and_is_cached(tmp_path, cache, suffix):
    bar_mesh(tmp_path, suffix)
    urdf = tmp_path / "shelf.urdf"
    urdf.write_text(shelf_with_mesh_bar(f"bar.{suffix}"))
    scene = sabre.Scene.from_urdf(ASSETS / "robots" / "royalpanda.urdf", urdf)
    bars = [c for c in scene.object_collisions if c.link == "handle" and c.kind == "mesh"]
    assert len(bars) == 1
    np.testing.assert_allclose(bars[0].size, (0.005, 0.005, 0.085), atol=1e-7)
    # the hull of a box is its 8 corners
    assert len(bars[0].points) == 8
    np.testing.assert_allclose(np.sort(np.abs(bars[0].points), axis=0), np.tile([0.005, 0.005, 0.085], (8, 1)), atol=1e-7)
    assert len(list(cache.glob("*.hull"))) == 1
    sabre.Scene.from_urdf(ASSETS / "robots" / "royalpanda.urdf", urdf)  # a second load reads the cache
    assert len(list(cache.glob("*.hull"))) == 1


def test_package_urls_and_the_mesh_path_resolve(tmp_path, cache, monkeypatch):
    package = tmp_path / "pkgs" / "my_cabinet" / "meshes"
    package.mkdir(parents=True)
    bar_mesh(package, "stl")
    with pytest.raises(UrdfError, match="not found"):
        sabre.Scene.from_urdf_strings(ROBOT, shelf_with_mesh_bar("package://my_cabinet/meshes/bar.stl"))
    monkeypatch.setenv("SABRE_PACKAGE_PATH", str(tmp_path / "pkgs"))
    sabre.Scene.from_urdf_strings(ROBOT, shelf_with_mesh_bar("package://my_cabinet/meshes/bar.stl"))
    monkeypatch.setenv("SABRE_MESH_PATH", str(package))
    sabre.Scene.from_urdf_strings(ROBOT, shelf_with_mesh_bar("bar.stl"))
    sabre.Scene.from_urdf_strings(ROBOT, shelf_with_mesh_bar(str(package / "bar.stl")))


def test_unsupported_flat_and_missing_meshes_are_urdf_errors(tmp_path, cache):
    (tmp_path / "bar.ply").write_text("ply\n")
    flat = trimesh.Trimesh(vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], faces=[[0, 1, 2], [1, 3, 2]])
    flat.export(tmp_path / "flat.stl")
    for name, says in (("bar.ply", "not supported"), ("flat.stl", "flat"), ("nothing.stl", "not found")):
        with pytest.raises(UrdfError, match=says):
            sabre.Scene.from_urdf_strings(ROBOT, shelf_with_mesh_bar(str(tmp_path / name)))


def test_a_mesh_bar_gives_the_same_handle_frame_and_pull_as_the_box(tmp_path, cache):
    path = bar_mesh(tmp_path, "stl")
    box, mesh = sabre.Scene.load("royalpanda", "shelf"), sabre.Scene.from_urdf_strings(ROBOT, shelf_with_mesh_bar(str(path)))
    from sabre.handles import infer_handle_frame

    np.testing.assert_allclose(infer_handle_frame(mesh, "handle"), infer_handle_frame(box, "handle"), atol=1e-9)
    # the scripted hook and pull of the box shelf, rolled out on both: the door follows the same way
    motion = sabre.hook_and_pull(box)
    U = motion.U[None]
    openings = [sabre.RolloutModel(s).rollout(s.default_state(), U, threads=1).states[0, :, 2 * s.nq] for s in (box, mesh)]
    assert openings[0][-1] > 0.5  # the pull opened the door
    assert np.max(np.abs(openings[0] - openings[1])) < 0.02  # rad


@pytest.fixture
def no_package_path(monkeypatch):
    for variable in ("SABRE_PACKAGE_PATH", "ROS_PACKAGE_PATH", "AMENT_PREFIX_PATH"):
        monkeypatch.delenv(variable, raising=False)


@pytest.mark.parametrize("folder", ["my_cabinet", "cabinet_description"], ids=["named like the package", "with its package.xml"])
def test_package_urls_resolve_from_inside_the_package_as_ros_tools_do(tmp_path, cache, no_package_path, folder):
    package = tmp_path / "workspace" / "src" / folder
    (package / "urdf").mkdir(parents=True)
    (package / "meshes").mkdir()
    bar_mesh(package / "meshes", "stl")
    if folder != "my_cabinet":
        (package / "package.xml").write_text('<?xml version="1.0"?>\n<package format="3"><name> my_cabinet </name></package>\n')
    urdf = package / "urdf" / "shelf.urdf"
    urdf.write_text(shelf_with_mesh_bar("package://my_cabinet/meshes/bar.stl"))
    scene = sabre.Scene.from_urdf(ASSETS / "robots" / "royalpanda.urdf", urdf)
    assert [c.kind for c in scene.object_collisions if c.link == "handle"].count("mesh") == 1
    # the same text without a file to start from finds nothing, and says where it looked
    with pytest.raises(UrdfError, match="nowhere: no package path is set"):
        sabre.Scene.from_urdf_strings(ROBOT, urdf.read_text())


def test_a_package_that_is_nowhere_lists_where_it_was_looked_for(tmp_path, cache, no_package_path, monkeypatch):
    (tmp_path / "elsewhere" / "urdf").mkdir(parents=True)
    urdf = tmp_path / "elsewhere" / "urdf" / "shelf.urdf"
    urdf.write_text(shelf_with_mesh_bar("package://my_cabinet/meshes/bar.stl"))
    monkeypatch.setenv("ROS_PACKAGE_PATH", str(tmp_path / "ros"))
    with pytest.raises(UrdfError, match="not found") as error:
        sabre.Scene.from_urdf(ASSETS / "robots" / "royalpanda.urdf", urdf)
    message = str(error.value)
    assert str(tmp_path / "ros" / "my_cabinet" / "meshes" / "bar.stl") in message
    assert f"no folder at or above {urdf.parent.resolve()} is named 'my_cabinet' or has a package.xml naming it" in message


def test_an_obj_with_several_objects_is_that_many_convex_pieces(tmp_path, cache):
    from sabre.experiments import mesh_files

    halves = [(f"half_{k}", mesh_files.box((0.0, 0.0, z), (0.01, 0.01, 0.085))) for k, z in enumerate((-0.0425, 0.0425))]
    mesh_files.write_obj(tmp_path / "bar.obj", halves)
    scene = sabre.Scene.from_urdf_strings(ROBOT, shelf_with_mesh_bar(str(tmp_path / "bar.obj")))
    pieces = [c for c in scene.object_collisions if c.link == "handle" and c.kind == "mesh"]
    assert len(pieces) == 2
    np.testing.assert_allclose(sorted(p.pose[2, 3] for p in pieces), [-0.0425, 0.0425], atol=1e-7)
    for piece in pieces:
        np.testing.assert_allclose(piece.size, (0.005, 0.005, 0.0425), atol=1e-7)
    again = sabre.Scene.from_urdf_strings(ROBOT, shelf_with_mesh_bar(str(tmp_path / "bar.obj")))  # from the cache
    assert len([c for c in again.object_collisions if c.link == "handle" and c.kind == "mesh"]) == 2
    assert len(list(cache.glob("*.hull"))) == 1
