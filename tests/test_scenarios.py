"""Scenario checks (SPEC §10): the stuck door loads the held door and the tank keeps its floor."""

from __future__ import annotations

import numpy as np

from sabre import scenarios


def test_stuck_door_loads_the_held_door_and_io_keeps_the_tank_above_its_floor():
    n = scenarios.stuck_door("N", hold_seconds=2.0, release_seconds=0.2, driver="scripted")
    io = scenarios.stuck_door("IO", hold_seconds=2.0, release_seconds=0.2, driver="scripted")
    held = n.episode.time <= 2.0
    # the door does not move while held, yet the robot pulls on it
    assert np.ptp(n.episode.opening[held]) < 1e-3
    assert n.mean_wrench_stuck > 10.0
    assert io.tank_min >= io.tank_floor - 0.05
    assert io.episode.filter_fallbacks == 0
    # deterministic
    again = scenarios.stuck_door("IO", hold_seconds=2.0, release_seconds=0.2, driver="scripted")
    assert again.mean_wrench_stuck == io.mean_wrench_stuck and again.tank_min == io.tank_min


def test_power_sign_changes_counts_only_near_the_floor():
    ep = scenarios.stuck_door("IO", hold_seconds=0.5, release_seconds=0.1, driver="scripted").episode
    mask = np.ones(len(ep.time), dtype=bool)
    # the tank starts at 10 J, far above the 2 J floor: nothing to count within 0.5 J of it
    assert scenarios.power_sign_changes_per_s(ep, mask, near=0.5) == 0.0
    assert scenarios.power_sign_changes_per_s(ep, mask, near=100.0) >= 0.0
