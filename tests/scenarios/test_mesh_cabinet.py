"""A cabinet as robot-learning benchmarks ship it (assets/objects/examples/mesh_cabinet: a ROS package,
every part convex mesh pieces named by package:// URLs, no inertial anywhere, two doors and two
drawers) loads from its file with no path set, and the controller opens one of its drawers and one of
its doors, named by their handle links only. The shipped generator writes exactly those files.

Each run starts where a shipped object's run is known to start well: the cabinet is placed so that
the handle to open stands where the shipped object's handle frame does, and the robot starts at the
scripted hook-and-pull's pre-grasp configuration for that object."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

import sabre
from sabre.experiments import families as objects
from support.starts import pre_grasp_configuration

ASSETS = Path(__file__).resolve().parents[2] / "assets"
ROBOT = ASSETS / "robots" / "royalpanda.urdf"
PACKAGE = ASSETS / "objects" / "examples" / "mesh_cabinet"


def test_the_shipped_files_are_what_the_generator_writes(tmp_path):
    written = objects.write_mesh_cabinet(objects.MESH_CABINET_EXAMPLE, tmp_path, "mesh_cabinet").parents[1]
    names = sorted(p.relative_to(written) for p in written.rglob("*") if p.is_file())
    assert names == sorted(p.relative_to(PACKAGE) for p in PACKAGE.rglob("*") if p.is_file())
    for name in names:
        assert (written / name).read_bytes() == (PACKAGE / name).read_bytes(), name


def test_every_part_is_meshes_and_every_moving_inertial_is_assumed(monkeypatch):
    for variable in ("SABRE_PACKAGE_PATH", "ROS_PACKAGE_PATH", "AMENT_PREFIX_PATH"):
        monkeypatch.delenv(variable, raising=False)
    with pytest.warns(sabre.AssumedInertialWarning) as caught:
        scene = sabre.Scene.from_urdf(ROBOT, PACKAGE / "urdf" / "cabinet.urdf")
    assert {s.kind for s in scene.object_collisions} == {"mesh"}
    moving = {"link_0", "link_1", "link_2", "link_3", "handle_0", "handle_1", "handle_2", "handle_3"}
    assert {a.link for a in scene.assumed_inertials} == moving
    assert {str(w.message).split("'")[1] for w in caught} == moving
    drawer = next(a for a in scene.assumed_inertials if a.link == "link_2")
    assert 2.0 < drawer.mass < 8.0  # a front and four boards of 600 kg/m³ material


def aligned_scene(shipped: sabre.Scene, handle: str) -> sabre.Scene:
    """The cabinet keeping the joint of ``handle``, placed so that ``handle`` stands where the shipped
    object's handle frame does (both face −x: a translation is enough)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sabre.AssumedInertialWarning)
        at_origin = sabre.Scene.from_urdf(ROBOT, PACKAGE / "urdf" / "cabinet.urdf", [0.0] * 6, handle=handle)
        task = sabre.tasks.OpenObject(handle=handle)
        offset = shipped.object_fk(shipped.o_lower, "handle_frame")[:3, 3] - task.handle_pose(at_origin, [0.0])[:3, 3]
        scene = sabre.Scene.from_urdf(ROBOT, PACKAGE / "urdf" / "cabinet.urdf", [*offset, 0.0, 0.0, 0.0], handle=handle)
    np.testing.assert_allclose(task.handle_pose(scene, [0.0]), shipped.object_fk(shipped.o_lower, "handle_frame"), atol=1e-6)
    return scene


@pytest.mark.parametrize(("shipped_name", "handle"), [("drawer", "handle_3"), ("shelf", "handle_0")], ids=["drawer", "door"])
def test_the_controller_opens_a_mesh_only_part_by_its_handle_link(shipped_name, handle):
    shipped = sabre.Scene.load("royalpanda", shipped_name)
    scene = aligned_scene(shipped, handle)
    x0 = scene.default_state()
    x0[: scene.nq] = pre_grasp_configuration(shipped)
    task = sabre.tasks.OpenObject(handle=handle)
    controller = sabre.Controller(scene, task, sabre.ControllerConfig(variant="N", seed=0, threads=1))
    episode = sabre.run_episode(scene, controller, 15.0, seed=0, x0=x0, progress=False)
    assert episode.success
    assert episode.opening.max() >= 0.9 * task.target_opening(scene)
