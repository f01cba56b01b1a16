"""Safety geometry generated for robots that declare none: the spheres cover every link's collision surfaces,
no self-collision pair joins neighbouring links, and robot-check's <sabre> block reloads to the same scene."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import ConvexHull

import sabre
from sabre.cli.main import main
from sabre.robot_examples import example_robot_urdf, example_scene

#: The covering margin the generated spheres guarantee (they are grown by the 5 mm sampling spacing).
TOLERANCE = 1e-9


@pytest.fixture(scope="module", params=["panda_pedestal", "ur5_mobile"])
def robot(request) -> sabre.Scene:
    return example_scene(request.param, "shelf", obj_pose=(2.0, 0.0, 0.0, 0.0, 0.0, 0.0))


def surface_points(shape: sabre.scene.CollisionShape, rng: np.random.Generator, count: int = 400) -> np.ndarray:
    """Random points on a collision primitive's surface, in its link's frame."""
    if shape.kind == "mesh":
        hull = ConvexHull(shape.points)
        triangles = shape.points[hull.simplices]
        area = np.linalg.norm(np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0]), axis=1)
        pick = rng.choice(len(triangles), size=count, p=area / area.sum())
        u, v = rng.random((2, count))
        flip = u + v > 1.0
        u[flip], v[flip] = 1.0 - u[flip], 1.0 - v[flip]
        t = triangles[pick]
        local = t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])
    elif shape.kind == "box":
        half = np.asarray(shape.size)
        local = rng.uniform(-half, half, size=(count, 3))
        axis = rng.integers(0, 3, count)
        local[np.arange(count), axis] = np.sign(rng.standard_normal(count)) * half[axis]
    elif shape.kind == "sphere":
        d = rng.standard_normal((count, 3))
        local = shape.size[0] * d / np.linalg.norm(d, axis=1, keepdims=True)
    else:  # cylinder or capsule: the side and the caps
        radius, half = shape.size
        angle = rng.uniform(0.0, 2.0 * np.pi, count)
        local = np.c_[radius * np.cos(angle), radius * np.sin(angle), rng.uniform(-half, half, count)]
        caps = rng.random(count) < 0.3
        local[caps, 2] = np.sign(rng.standard_normal(caps.sum())) * half
        local[caps, :2] *= np.sqrt(rng.random(caps.sum()))[:, None]
    return local @ shape.pose[:3, :3].T + shape.pose[:3, 3]


def test_generated_spheres_cover_every_link_collision_surface(robot, rng):
    spheres: dict[str, list] = {}
    for _, link, centre, radius, _ in robot._core.spheres():
        spheres.setdefault(link, []).append((np.asarray(centre), radius))
    assert robot.role_origins["geometry"] == "generated"
    covered = 0
    for shape in robot.robot_collisions:
        points = surface_points(shape, rng)
        assert shape.link in spheres, f"link {shape.link} has collision geometry but no sphere"
        inside = np.zeros(len(points), dtype=bool)
        for centre, radius in spheres[shape.link]:
            inside |= np.linalg.norm(points - centre, axis=1) <= radius + TOLERANCE
        assert inside.all(), f"{shape.link}: {np.count_nonzero(~inside)} surface points outside every sphere"
        covered += 1
    assert covered >= 10


def moving_joints(scene: sabre.Scene, link: str) -> set[int]:
    """The joints that move ``link``: the non-zero columns of its Jacobian at a generic configuration."""
    q = 0.5 * (np.maximum(scene.q_lower, -3.0) + np.minimum(scene.q_upper, 3.0)) + 0.1
    return set(np.flatnonzero(np.abs(scene.jacobian(q, link)).sum(axis=0) > 1e-12))


def test_no_self_collision_pair_joins_adjacent_links(robot):
    link = {name: link for name, link, *_ in robot._core.spheres()}
    assert robot.self_collision_pairs
    for a, b in robot.self_collision_pairs:
        between = moving_joints(robot, link[a]) ^ moving_joints(robot, link[b])
        assert len(between) >= 3, f"{a} and {b} are {len(between)} joint(s) apart"


def test_the_home_and_start_postures_are_free_of_self_collision(robot):
    check = sabre.SafetyFilter(robot, sabre.SafetyConfig(base_box=None))
    names = np.array([n.startswith("self_collision") for n in check.row_names])
    for q in (robot.home_configuration(), robot.start_configuration()):
        x = robot.default_state()
        x[: robot.nq] = q
        assert (np.asarray(check.constraint_rows(x).h)[names] > 0.0).all()


def test_the_reach_limit_is_within_the_arm_and_holds_at_home(robot):
    base, frame, reach = robot.arm_reach
    assert frame == robot.tool_frame
    q = robot.home_configuration()
    home = np.linalg.norm(robot.fk(q, frame)[:2, 3] - robot.fk(q, base)[:2, 3])
    assert home < reach < 1.2


def test_robot_check_writes_a_block_that_reloads_to_the_same_scene(tmp_path, capsys):
    for name in ("panda_pedestal", "ur5_mobile"):
        source = example_robot_urdf(name, tmp_path)
        out = tmp_path / f"{name}.checked.urdf"
        assert main(["robot-check", str(source), "--out", str(out)]) == 0
        report = capsys.readouterr().out
        assert "tool frame: grasp" in report and "self-collision pairs" in report
        first = sabre.Scene.from_urdf(source, "drawer")
        again = sabre.Scene.from_urdf(out, "drawer")
        assert again.role_origins["geometry"] == "declared" and first.role_origins["geometry"] == "generated"
        for read in (
            lambda s: s.joint_names,
            lambda s: s.frame_names,
            lambda s: s.tool_frame,
            lambda s: s.base_joints,
            lambda s: s.base_link,
            lambda s: s.held_joints,
            lambda s: s.wrist_sensor_link,
            lambda s: s.tool,
            lambda s: s._core.spheres(),
            lambda s: s.self_collision_pairs,
            lambda s: s.rollout_contact_links,
            lambda s: s.arm_reach,
        ):
            assert read(again) == read(first)
        for posture in ("home_configuration", "start_configuration", "work_configuration"):
            np.testing.assert_array_equal(getattr(again, posture)(), getattr(first, posture)())
        np.testing.assert_array_equal(again.q_lower, first.q_lower)
        q = first.start_configuration()
        np.testing.assert_array_equal(again.fk(q, "grasp"), first.fk(q, "grasp"))
