"""A planning iteration in contact at N rollouts on 1 and 2 threads, next to MuJoCo's bare batch of
the same size: the scaling with samples and threads, and where the iteration's time goes.

    python benches/planning_scaling.py [--objects shelf drawer] [--rollouts 40 160] [--repeats 20]

Each object starts hooked on its handle (the open phase planned from rest, as in
benches/compare_planning.py). For every N and thread count a controller (variant N, seed 0) runs
``Controller.update`` while `mujoco.rollout` runs the same N × K batch on the equivalent scene on
2 threads (per-step states, no cost), alternately in one process; medians are printed. Columns:
the whole iteration (wall time of ``update``), its parallel rollouts (with the cost), the rest of
the core's iteration (sampling and the update), the task's guides (the call that makes them, on
the calling thread before the rollouts), the rest of the task's and the controller's side (phase
switch, noise scale and bookkeeping: the iteration's wall time less the core's and the guides'),
the ratio of the iteration to MuJoCo's batch (< 1: sabre's whole iteration is faster than
MuJoCo's rollouts alone), and the speed-up of 2 threads over 1.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import mujoco
import mujoco.rollout
import numpy as np

import sabre

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root, for support/
sys.path.insert(0, str(Path(__file__).resolve().parent))
from compare_planning import hooked_state
from support.mujoco_scene import build_mujoco_model, mujoco_controls, mujoco_state

MUJOCO_THREADS = 2


def time_iterations(scene: sabre.Scene, x: np.ndarray, rollouts: int, threads: int, repeats: int, peer) -> dict[str, float]:
    """Medians (s) over ``repeats`` iterations from x, each next to one run of ``peer``."""
    config = sabre.ControllerConfig(seed=0, rollouts=rollouts, threads=threads)
    controller = sabre.Controller(scene, sabre.tasks.OpenObject(), config)
    controller.set_phase("open")
    rows: dict[str, list[float]] = {"iteration": [], "rollouts": [], "core_rest": [], "guides": [], "python": [], "mujoco": []}
    t = 0.0
    for round_ in range(repeats + 3):
        t += 0.01
        mujoco_first = round_ % 2 == 1
        if mujoco_first:
            rows["mujoco"].append(peer())
        start = time.perf_counter()
        stats = controller.update(x, t)
        wall = time.perf_counter() - start
        if not mujoco_first:
            rows["mujoco"].append(peer())
        core = stats.iteration_time - stats.guide_time
        rows["iteration"].append(wall)
        rows["rollouts"].append(stats.rollout_time)
        rows["core_rest"].append(core - stats.rollout_time)
        rows["guides"].append(stats.guide_time)
        rows["python"].append(wall - core - stats.guide_time)
    return {name: statistics.median(values[3:]) for name, values in rows.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--objects", nargs="+", default=["shelf", "drawer"], choices=sabre.OBJECTS)
    parser.add_argument("--rollouts", nargs="+", type=int, default=[40, 160])
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args(argv)
    print(
        f"sabre {sabre.__version__} vs MuJoCo {mujoco.__version__}: open phase from the hooked state, variant N, "
        f"median of {args.repeats} alternating rounds; MuJoCo on {MUJOCO_THREADS} threads"
    )
    print(
        f"{'object':<8} {'N':>4} {'threads':>7} {'iteration':>10} {'rollouts':>9} {'core rest':>10} {'guides':>7} {'Python':>7} "
        f"{'MuJoCo':>7} {'ratio':>6} {'2 vs 1':>7}   (ms)"
    )
    for obj in args.objects:
        scene = sabre.Scene.load(obj=obj)
        x = hooked_state(scene)
        model = build_mujoco_model(obj)
        data = mujoco.MjData(model)
        thread_data = [mujoco.MjData(model) for _ in range(MUJOCO_THREADS)]
        runner = mujoco.rollout.Rollout(nthread=MUJOCO_THREADS)
        k = sabre.ControllerConfig().horizon_steps
        rng = np.random.default_rng(0)
        for n in args.rollouts:
            state = mujoco_state(model, data, scene, x)
            states0 = np.tile(state, (n, 1))
            commands = np.clip(rng.normal(0.0, 0.3, size=(n, k, scene.nu)), -scene.dq_limit, scene.dq_limit)
            controls = mujoco_controls(model, commands)
            out_state = np.empty((n, k, state.size))

            def peer(batch=(runner, model, thread_data, states0, controls, out_state)) -> float:
                runner, model, thread_data, states0, controls, out_state = batch
                start = time.perf_counter()
                runner.rollout(model, thread_data, states0, controls, state=out_state)
                return time.perf_counter() - start

            one = None
            for threads in (1, 2):
                m = time_iterations(scene, x, n, threads, args.repeats, peer)
                speedup = "" if one is None else f"{one / m['iteration']:.2f}x"
                one = m["iteration"] if one is None else one
                print(
                    f"{obj:<8} {n:>4} {threads:>7} {1e3 * m['iteration']:>10.2f} {1e3 * m['rollouts']:>9.2f} "
                    f"{1e3 * m['core_rest']:>10.2f} {1e3 * m['guides']:>7.2f} {1e3 * m['python']:>7.2f} "
                    f"{1e3 * m['mujoco']:>7.2f} "
                    f"{m['iteration'] / m['mujoco']:>5.2f}x {speedup:>7}",
                    flush=True,
                )
    print("(ratio = sabre's whole iteration / MuJoCo's rollouts alone: the goal is 0.5 or less on 2 threads)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
