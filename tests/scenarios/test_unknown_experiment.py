"""The unknown-object experiment's parts: the detected pose's error as configured, and the report's counts
from records made up here."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sabre.errors import InvalidValueError
from sabre.experiments.unknown import MODES, noisy_pose, unknown_configs, unknown_table


def test_the_detected_pose_is_off_by_the_configured_offset_and_angle():
    rng = np.random.default_rng(0)
    pose = np.eye(4)
    pose[:3, 3] = [1.0, 0.2, 0.7]
    for _ in range(20):
        noisy = noisy_pose(pose, rng, 0.005, math.radians(3.0))
        assert np.linalg.norm(noisy[:3, 3] - pose[:3, 3]) == pytest.approx(0.005)
        turn = noisy[:3, :3] @ pose[:3, :3].T
        assert math.degrees(math.acos((np.trace(turn) - 1.0) / 2.0)) == pytest.approx(3.0)
        np.testing.assert_allclose(noisy[:3, :3].T @ noisy[:3, :3], np.eye(3), atol=1e-12)


def test_the_configurations_cover_every_object_variant_and_mode():
    configs = unknown_configs(objects=2, builtins=("shelf",), variants=("N", "IO"))
    assert len(configs) == (1 + 2 * 2) * 2 * len(MODES)
    with pytest.raises(InvalidValueError):
        unknown_configs(modes=("guess",))


def _record(case: str, variant: str, mode: str, success: bool, kind: str, **metrics: float) -> dict:
    nan = float("nan")
    base = {"type_right": nan, "axis_error": nan, "hinge_error": nan, "rebuilds": nan, "time_to_success": 10.0}
    return {
        "config": {"case": case, "object": 0, "variant": variant, "mode": mode},
        "kind": kind,
        "metrics": base | metrics | {"success": float(success)},
    }


def test_the_report_counts_each_mode_and_scores_the_estimates():
    records = [
        _record("builtin", "N", "known", True, "revolute"),
        _record("builtin", "N", "known", True, "prismatic"),
        _record("builtin", "N", "unknown", True, "revolute", type_right=1.0, axis_error=1.0, hinge_error=0.02),
        _record("builtin", "N", "unknown", False, "prismatic", type_right=0.0, axis_error=4.0),
        _record("builtin", "N", "wrong prior", True, "revolute", type_right=1.0, axis_error=2.0, hinge_error=0.04),
    ]
    row = next(line for line in unknown_table(records).splitlines() if line.startswith("| builtin | N "))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[2:5] == ["2/2", "1/2 (50%)", "1/1"]
    assert cells[6] == "2/3"  # the type, right in two of the three estimated runs
    assert cells[7] == "1.5° (2.0°)"  # the doors' axis errors, median (max)
    assert cells[8] == "3.0 cm (4.0 cm)"
    assert cells[9] == "4.0° (4.0°)"  # the drawer's direction
