"""Digests of closed-loop traces: the cascade's behaviour pinned to the bit, to compare two versions of the code.

Runs `run_episode` on the four built-in objects with variants N and IO (the Rust plant), one with a planning
delay, the deployment loop (`RealtimeCascade`) ticking a plant in simulated time, and, when MuJoCo is
installed, `run_episode` on the MuJoCo plant; prints one SHA-256 per run over every recorded array. Two
versions of the code that print the same lines gave the same traces to the bit.

    python tools/cascade_trace.py [--duration 3]
"""

from __future__ import annotations

import argparse
import hashlib
import sys
from pathlib import Path

import numpy as np

import sabre
from sabre import tasks

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root, for support/
from support.starts import pre_grasp_state

FIELDS = (
    "time",
    "state",
    "reference",
    "command",
    "wrench",
    "tau_ext",
    "tau_ext_measured",
    "contact",
    "cost",
    "phase",
    "tank_energy",
)


def digest(arrays: list[np.ndarray]) -> str:
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str(a.dtype).encode() + str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()[:16]


def controller(scene: sabre.Scene, variant: str) -> sabre.Controller:
    return sabre.Controller(scene, tasks.OpenObject(), sabre.ControllerConfig(variant=variant, seed=0, threads=1))


def episode_digest(episode: sabre.Episode) -> str:
    return digest([np.asarray(getattr(episode, f)) for f in FIELDS])


def realtime_digest(duration: float) -> str:
    """The deployment loop in simulated time: plans every 50 ms with a 10 ms delay, ticks a 1 kHz plant."""
    scene = sabre.Scene.load("royalpanda", "shelf")
    plant = sabre.Plant(scene)
    low = sabre.LowLevelController(scene, dt=plant.dt)
    cascade = sabre.RealtimeCascade(controller(scene, "IO"), low_level=low, inner_dt=plant.dt)
    plant.reset(pre_grasp_state(scene))
    cascade.reset(seed=0)
    rows = []
    for step in range(int(round(duration / plant.dt))):
        if step % 50 == 0:
            cascade.plan(plant.state, plant.time, delay=0.01)
        r = cascade.tick(plant.state, plant.measured_tau_ext, plant.time)
        plant.step(r.torque)
        rows.append(np.concatenate([plant.state, r.command, r.torque, [r.tank_energy]]))
    return digest([np.array(rows)])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=3.0, help="simulated seconds per run (default 3)")
    args = parser.parse_args()
    d = args.duration
    for obj in ("shelf", "microwave", "dishwasher", "drawer"):
        scene = sabre.Scene.load("royalpanda", obj)
        for variant in ("N", "IO"):
            x0 = pre_grasp_state(scene)
            ep = sabre.run_episode(scene, controller(scene, variant), d, seed=0, progress=False, x0=x0)
            print(f"run_episode {obj:10s} {variant:2s} {episode_digest(ep)}")
    scene = sabre.Scene.load("royalpanda", "shelf")
    x0 = pre_grasp_state(scene)
    ep = sabre.run_episode(scene, controller(scene, "IO"), d, seed=0, progress=False, plan_delay=0.02, x0=x0)
    print(f"run_episode shelf      IO plan_delay=0.02 {episode_digest(ep)}")
    print(f"RealtimeCascade shelf  IO {realtime_digest(d)}")
    try:
        plant = sabre.MujocoPlant(scene)
    except sabre.MissingExtraError:
        print("MujocoPlant: not installed")
        return
    ep = sabre.run_episode(scene, controller(scene, "IO"), min(d, 1.0), seed=0, progress=False, plant=plant, x0=x0)
    print(f"run_episode shelf      IO MujocoPlant {episode_digest(ep)}")


if __name__ == "__main__":
    main()
