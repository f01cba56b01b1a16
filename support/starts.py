"""Start states the closed-loop tests and tools share: the robot where the scripted hook-and-pull ends its
approach, in front of the handle."""

from __future__ import annotations

import numpy as np

import sabre


def pre_grasp_configuration(scene: sabre.Scene) -> np.ndarray:
    """(nq,) the robot's joints where `sabre.hook_and_pull` on ``scene`` ends its approach."""
    motion = sabre.hook_and_pull(scene)
    end_of_approach = int(np.flatnonzero(motion.phases == 0)[-1]) + 1
    return np.asarray(motion.planned_states[end_of_approach])


def pre_grasp_state(scene: sabre.Scene) -> np.ndarray:
    """The robot at :func:`pre_grasp_configuration`, at rest, with the object closed: a run reaches contact,
    the filter's passivity row and the tank within a few seconds."""
    x0 = scene.default_state()
    x0[: scene.nq] = pre_grasp_configuration(scene)
    assert x0[2 * scene.nq] == 0.0
    return x0
