"""Run-time obstacles meet spheres that cover the robot's links, not spheres sized to keep two links apart."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

import sabre

ROBOT_URDF = Path(__file__).resolve().parents[2] / "assets" / "robots" / "royalpanda.urdf"


def _farthest_collision_point(link: str, about: np.ndarray) -> float:
    """Farthest distance from ``about`` (link frame) of the link's collision spheres and cylinders
    (no rotation in their origins), from the URDF text."""
    far = 0.0
    for element in ET.parse(ROBOT_URDF).getroot().find(f"link[@name='{link}']").findall("collision"):
        origin = element.find("origin")
        assert all(float(v) == 0.0 for v in origin.get("rpy", "0 0 0").split())
        centre = np.array([float(v) for v in origin.get("xyz").split()]) - about
        shape = element.find("geometry")[0]
        r = float(shape.get("radius"))
        if shape.tag == "sphere":
            far = max(far, np.linalg.norm(centre) + r)
        elif shape.tag == "cylinder":
            half = float(shape.get("length")) / 2
            for z in (-half, half):  # the rims of both caps
                far = max(far, np.hypot(np.hypot(centre[0], centre[1]) + r, centre[2] + z))
        else:
            raise AssertionError(f"unexpected collision shape {shape.tag}")
    return far


def test_obstacles_meet_link7_at_a_sphere_that_covers_its_geometry():
    """link7's self-collision sphere (0.2 m) keeps it 0.35 m from link1 and stays out of the obstacle
    rows; link7_geometry (0.08 m about the middle of the link) covers the link's collision geometry,
    read from the URDF here. An obstacle 0.15 m from that centre has the barrier ½(d² − (r_o + 0.08)²)
    in the filter, computed by hand; the 0.2 m sphere would have put it inside."""
    scene = sabre.Scene.load(obj="shelf")
    obstacle = {name: (link, np.array(c), r) for name, link, c, r in scene.obstacle_spheres}
    pairs = {name: r for name, _, _, r in scene.self_collision_spheres}
    assert "link7" not in obstacle and pairs["link7"] == 0.2
    link, centre, radius = obstacle["link7_geometry"]
    assert link == "panda_link7" and radius == 0.08
    assert "link7_geometry" not in pairs and not any("link7_geometry" in pair for pair in scene.self_collision_pairs)
    assert _farthest_collision_point("panda_link7", centre) == pytest.approx(radius, abs=1e-9)

    x = scene.default_state()
    world = scene.fk(x[: scene.nq], link) @ np.append(centre, 1.0)
    r_o, d = 0.05, 0.15
    f = sabre.SafetyFilter(scene, sabre.SafetyConfig(base_box=None))
    oid = f.add_obstacle(world[:3] + np.array([0.0, 0.0, d]), r_o)
    rows = [i for i, name in enumerate(f.row_names) if name == f"obstacle:{oid}:panda_link7"]
    assert len(rows) == 1
    expected = 0.5 * (d * d - (r_o + radius) ** 2)
    assert expected > 0.0 > 0.5 * (d * d - (r_o + 0.2) ** 2)
    r = f.filter(x, np.zeros(scene.nq))
    np.testing.assert_allclose(r.barrier[rows[0]], expected, rtol=1e-9, atol=1e-12)
