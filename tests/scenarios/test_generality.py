"""The generality sweep's objects (sabre.experiments.families): each loads as another tool writes it, and the
handle frame inferred from its bar is where the generator put the bar, oriented as the generator built it."""

from __future__ import annotations

import numpy as np
import pytest

import sabre
from sabre.experiments import families as objects

_RNG = np.random.default_rng(0)  # the sweep's default generator seed
SPECS = [objects.random_spec(_RNG, i) for i in range(40)]


def test_the_generated_objects_cover_every_kind_and_range():
    assert {s.kind for s in SPECS} == {"door", "drawer"}
    assert {s.vertical_bar for s in SPECS} == {True, False} and {s.hinge_left for s in SPECS} == {True, False}
    assert {s.bar_shape for s in SPECS} == {"box", "cylinder", "mesh"}
    widths, heights = [s.width for s in SPECS], [s.handle_height for s in SPECS]
    assert 0.25 <= min(widths) and max(widths) <= 0.6 and 0.6 <= min(heights) and max(heights) <= 1.1
    assert all(2.0 <= s.distance <= 4.0 and abs(s.facing) <= np.pi / 3 for s in SPECS)
    # the short-standoff class: bars of 10–20 mm on standoffs of 20–40 mm, doors and drawers, both bar directions
    short = [s for s in SPECS if s.handle_class == "short standoff"]
    assert {s.kind for s in short} == {"door", "drawer"} and {s.vertical_bar for s in short} == {True, False}
    assert all(0.01 <= s.bar_size <= 0.02 and 0.02 <= s.standoff <= 0.04 for s in short)
    assert all((s.bar_size, s.standoff) == (0.01, 0.056) for s in SPECS if s not in short) and 10 <= len(short) <= 30


@pytest.mark.parametrize("spec", SPECS, ids=lambda s: f"{s.index}-{s.kind}-{'v' if s.vertical_bar else 'h'}-{s.bar_shape}")
def test_the_inferred_handle_frame_is_the_generated_bar(spec):
    scene = objects.scene_of(spec)
    assert scene.no == 1 and "world" in scene.object_frame_names
    pose = sabre.tasks.OpenObject(handle=spec.handle_link).handle_pose(scene, scene.o_lower)
    # independent reference: the generator's own numbers, composed by hand
    x, y, _, _, _, yaw = spec.pose()
    c, s = np.cos(yaw), np.sin(yaw)
    side = 1.0 if spec.hinge_left else -1.0
    # a door's bar sits 4 cm from its free edge, the hinge on the other edge; a drawer's in the middle
    grip_y = -side * (spec.width / 2 - 0.04) if spec.kind == "door" else 0.0
    local = np.array([-(spec.standoff + spec.bar_size / 2), grip_y])
    expected_centre = [x + c * local[0] - s * local[1], y + s * local[0] + c * local[1], spec.handle_height]
    np.testing.assert_allclose(pose[:3, 3], expected_centre, atol=1e-4)  # the URDF prints 4 decimals
    into = np.array([c, s, 0.0])  # the object's +x: from the front into the body
    np.testing.assert_allclose(pose[:3, 2], into, atol=1e-6)
    along = np.array([0.0, 0.0, 1.0]) if spec.vertical_bar else np.array([-s, c, 0.0])
    assert abs(pose[:3, 0] @ along) == pytest.approx(1.0, abs=1e-6)
    controller = sabre.Controller(
        scene, sabre.tasks.OpenObject(handle=spec.handle_link), sabre.ControllerConfig(rollouts=8, horizon=0.15, threads=1)
    )
    controller.update(scene.default_state(), 0.0)
    assert np.all(np.isfinite(controller.nominal))
