"""A robot from a public description opens an object in closed loop: the fixed-base Panda of example-robot-data,
with the hook on its hand, pulls the drawer open on the 1 kHz plant; and a hook that stalls far short of the bar
starts over however little the handle moved."""

from __future__ import annotations

import numpy as np

import sabre
from sabre import tasks
from sabre.robot_examples import example_scene


def test_the_fixed_base_panda_opens_the_drawer():
    scene = example_scene("panda_pedestal", "drawer")
    controller = sabre.Controller(scene, tasks.OpenObject(), sabre.ControllerConfig(variant="IO", seed=0))
    episode = sabre.run_episode(scene, controller, 20.0, seed=0, x0=scene.start_state(), replan_rate=50.0, progress=False)
    assert episode.success, f"opening {episode.opening[-1]:.3f} of the {episode.success_opening:.3f} m needed"
    phases = [episode.phases[i] for i in episode.phase]
    assert phases[0] == "approach" and "hook" in phases and phases[-1] == "open"
    # the held fingers never move and the arm stays within its limits
    q = scene.split_state(episode.state).q
    assert np.all(q >= scene.q_lower - 1e-3) and np.all(q <= scene.q_upper + 1e-3)


def test_a_stalled_hook_far_short_of_the_bar_starts_over_whatever_the_drag():
    scene = sabre.Scene.load(obj="shelf")
    task = tasks.OpenObject()
    x = scene.default_state()
    q, _, o, o_dot = scene.split_state(x)
    o[0] = 0.027 / task.handle_travel(scene, 0.0)  # the handle dragged 2.7 cm, below hook.drag_distance
    target = task.handle_pose(scene, o) @ task.grasp_offset(scene, "hook")
    target[:3, 3] -= 0.065 * target[:3, 2]  # the grasp frame 65 mm short of the hook target's depth
    from sabre.guides import servo_guide

    for _ in range(8):  # bring the grasp frame there on the kinematics
        q += 0.02 * servo_guide(scene, q, np.broadcast_to(target, (51, 4, 4)), 0.02, gain=4.0, max_linear=1.0).sum(axis=0)
    assert abs(task.depth_error(scene, x, "hook") + 0.065) < 5e-3
    assert task.handle_from_closed(scene, x) < task.hook.drag_distance
    assert task.backed_out(scene, x) and task.next_phase(scene, x, 1.0, "hook") == "approach"
    # within the tip's reach the drag-distance rule still waits: a tip on the bar may yet drag it open
    patient = tasks.OpenObject(hook=tasks.HookConfig(stall_depth=None))
    assert not patient.backed_out(scene, x)
    o_dot[0] = 1.0  # a handle that moves is being dragged, not stalled
    assert not task.backed_out(scene, x)
