"""The whole system in closed loop: the controller opens a door and a drawer on the 1 kHz plant,
and the scenarios no other test runs (object manipulation from the paper's start, the obstacle
corridor) keep their promises. Each run is deterministic for its seed and thread count.
"""

from __future__ import annotations

import numpy as np
import pytest

import sabre
from sabre import tasks
from sabre.paper import scenarios
from support.starts import pre_grasp_state

#: The inner filter's passivity row is softened by a slack (penalty Γ against ‖ũ − u‖²), so a step
#: taken with the row active may let the tank fall short of its floor by about dt·b/(1 + Γ‖τ̂‖²);
#: over a run these shortfalls stay below 1 mJ.
TANK_SLACK = 1e-3


def open_from_pre_grasp(obj: str, variant: str, duration: float = 15.0) -> tuple[sabre.Episode, tasks.OpenObject]:
    scene = sabre.Scene.load("royalpanda", obj)
    task = tasks.OpenObject()
    controller = sabre.Controller(scene, task, sabre.ControllerConfig(variant=variant, seed=0, threads=1))
    episode = sabre.run_episode(scene, controller, duration, seed=0, x0=pre_grasp_state(scene), progress=False)
    return episode, task


@pytest.mark.parametrize("obj", ["shelf", "drawer"], ids=["revolute_shelf", "prismatic_drawer"])
def test_controller_opens_the_object_from_the_pre_grasp_pose(obj):
    episode, task = open_from_pre_grasp(obj, "N")
    scene = episode.scene
    target = task.target_opening(scene)
    assert episode.success
    assert episode.time_to_success is not None and episode.time_to_success <= 15.0
    # success means 90 % of the target opening; check it on the recorded trace itself
    assert episode.opening.max() >= 0.9 * target
    assert np.all(np.isfinite(episode.state))
    # the opening was reached by the hook pulling: there was contact before the object moved
    moved = np.flatnonzero(episode.opening > 0.05 * target)
    assert episode.contact[: moved[0] + 1].any()


def test_io_variant_opens_the_shelf_and_keeps_the_tank_above_its_floor():
    episode, task = open_from_pre_grasp("shelf", "IO")
    target = task.target_opening(episode.scene)
    assert episode.success and episode.opening.max() >= 0.9 * target
    assert episode.tank_energy.min() >= episode.tank_floor - TANK_SLACK
    # the tank paid for the opening: energy left it
    assert episode.tank_energy[-1] < episode.tank_energy[0]
    assert episode.filter_fallbacks == 0


def test_object_manipulation_opens_the_shelf_from_the_paper_start_and_reports_violations():
    result = scenarios.object_manipulation("IO", "shelf", seed=0, duration=25.0)
    assert result.success and result.episode.success
    assert set(result.violations) == {"joint_limits", "self_collision", "arm_reach", "base_box", "obstacles"}
    assert all(np.isfinite(v) and v >= 0.0 for v in result.violations.values())
    # the inner filter keeps the joints inside their limits all the way
    assert result.violations["joint_limits"] == 0.0
    q = result.episode.state[:, : result.episode.scene.nq]
    assert np.all(q >= result.episode.scene.q_lower - 1e-6) and np.all(q <= result.episode.scene.q_upper + 1e-6)


def test_obstacle_corridor_shows_the_obstacle_when_the_hand_nears_it_and_reports_the_violation():
    result = scenarios.obstacle_corridor("IO", seed=0, duration=4.0)
    ep = result.episode
    assert result.appeared_at is not None and 0.0 < result.appeared_at < ep.duration
    # it appears when the grasp frame comes within 1 cm of the sphere, which sits half-way
    # between the start and the target of the reach
    scene = ep.scene
    start = scene.fk(scene.default_state()[: scene.nq], "grasp")[:3, 3]
    center = 0.5 * (start + start + np.array([-0.15, 0.5, 0.0]))
    k = int(np.searchsorted(ep.time, result.appeared_at))
    gap = np.linalg.norm(scene.fk(ep.state[k, : scene.nq], "grasp")[:3, 3] - center) - 0.08
    assert gap <= 0.01 + 0.02  # the recorded state is up to one re-plan (50 ms) after the check
    before = ep.time < result.appeared_at - 0.1
    gaps_before = [np.linalg.norm(scene.fk(x[: scene.nq], "grasp")[:3, 3] - center) - 0.08 for x in ep.state[before]]
    assert min(gaps_before) > 0.01
    # the sampler switched to the phase whose cost holds the obstacle
    assert ep.phases[ep.phase[-1]] == "obstacle"
    assert np.isfinite(result.cartesian_violation) and result.cartesian_violation >= 0.0


def test_an_episode_in_contact_with_mesh_pieces_is_the_same_to_the_bit_again_and_on_two_threads():
    """The generated door whose bar is an STL mesh (a convex hull, collided through parry's manifolds,
    which seed a pair's next detection with its last normal): 20 s of approach, hook and pull, twice
    on one thread and once on two, end in the same state. A rollout world reset for the next row must
    carry nothing of the row before, whichever rows its worker ran."""
    from sabre.experiments.families import random_spec, scene_of

    rng = np.random.default_rng(0)
    spec = [random_spec(rng, i) for i in range(7)][6]
    assert spec.bar_shape == "mesh"
    ends = []
    for threads in (1, 1, 2):
        scene = scene_of(spec)
        safety = sabre.SafetyConfig(base_box=(-5.0, 5.0, -5.0, 5.0))
        config = sabre.ControllerConfig(variant="N", seed=0, safety=safety, threads=threads)
        controller = sabre.Controller(scene, tasks.OpenObject(handle=spec.handle_link), config)
        episode = sabre.run_episode(scene, controller, 20.0, seed=0, x0=scene.default_state(), progress=False)
        assert np.any(episode.contact)
        ends.append(episode.state[-1])
    np.testing.assert_array_equal(ends[0], ends[1])
    np.testing.assert_array_equal(ends[0], ends[2])
