"""A planning iteration in contact at N rollouts on 1 and 2 threads, next to MuJoCo's bare batch of
the same size: the scaling with samples and threads, and where the iteration's time goes.

    python benches/planning_scaling.py [--objects shelf drawer] [--rollouts 40 160] [--repeats 20] [--idle MS]

Each object starts hooked on its handle (the open phase planned from rest, as in
benches/compare_planning.py). For every N, two controllers (variant N, seed 0; one on 1 thread, one
on 2) run ``Controller.update`` while `mujoco.rollout` runs the same N × K batch on the equivalent
scene on 2 threads (per-step states, no cost): each round runs both controllers and MuJoCo's batch
on 1 thread once, each right after a MuJoCo batch on 2 threads, in an order that rotates from round
to round, in one process; medians are printed. Columns:
the whole iteration (wall time of ``update``), its parallel rollouts (with the cost), the rest of
the core's iteration (sampling and the update), the task's guides (the call that makes them, on
the calling thread before the rollouts), the rest of the task's and the controller's side (phase
switch, noise scale and bookkeeping: the iteration's wall time less the core's and the guides'),
the ratio of the iteration to MuJoCo's batch (< 1: sabre's whole iteration is faster than
MuJoCo's rollouts alone), and the speed-up of 2 threads over 1 (the median over rounds of the
two iterations' ratio within a round). A last line per N gives MuJoCo's own speed-up from 1 thread
to 2 on the same batch, measured the same way: what the host's two cores allow a peer. --idle
sleeps before every measured run, as a loop that re-plans at a fixed rate does between iterations.
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


def time_iterations(
    scene: sabre.Scene,
    x: np.ndarray,
    rollouts: int,
    thread_counts: tuple[int, ...],
    repeats: int,
    peer,
    idle: float = 0.0,
) -> tuple[dict[int, dict[str, float]], float]:
    """Medians (s) over ``repeats`` rounds from x, per thread count, and MuJoCo's own speed-up.

    A round runs one iteration of every thread count's controller and one batch of MuJoCo on 1
    thread (in an order that rotates from round to round), each right after one batch of MuJoCo on
    2 threads (``peer(2)``, the ratio's reference): every run starts on two cores that were just
    busy, so that none pays for an idle core (a virtual CPU left idle can take milliseconds to be
    scheduled again) and a slower or faster stretch of a shared host falls on all alike. A
    speed-up is the median over rounds of the 1-thread run over the one on more threads. With
    ``idle`` (s), every measured run starts after that long a sleep instead, as in a loop that
    re-plans at a fixed rate."""
    controllers = {}
    for threads in thread_counts:
        config = sabre.ControllerConfig(seed=0, rollouts=rollouts, threads=threads)
        controllers[threads] = sabre.Controller(scene, sabre.tasks.OpenObject(), config)
        controllers[threads].set_phase("open")
    names = ("iteration", "rollouts", "core_rest", "guides", "python", "mujoco", "speedup")
    rows: dict[int, dict[str, list[float]]] = {threads: {name: [] for name in names} for threads in thread_counts}
    mujoco_speedups: list[float] = []
    jobs: list[int | None] = [*thread_counts, None]  # None: MuJoCo on 1 thread
    t = 0.0
    for round_ in range(repeats + 3):
        t += 0.01
        shift = round_ % len(jobs)
        walls: dict[int, float] = {}
        for job in jobs[shift:] + jobs[:shift]:
            reference = peer(MUJOCO_THREADS)
            if idle > 0.0:
                time.sleep(idle)
            if job is None:
                mujoco_speedups.append(peer(1) / reference)
                continue
            start = time.perf_counter()
            stats = controllers[job].update(x, t)
            wall = time.perf_counter() - start
            walls[job] = wall
            core = stats.iteration_time - stats.guide_time
            row = rows[job]
            row["mujoco"].append(reference)
            row["iteration"].append(wall)
            row["rollouts"].append(stats.rollout_time)
            row["core_rest"].append(core - stats.rollout_time)
            row["guides"].append(stats.guide_time)
            row["python"].append(wall - core - stats.guide_time)
        for threads in thread_counts:
            rows[threads]["speedup"].append(walls[thread_counts[0]] / walls[threads])
    medians = {threads: {name: statistics.median(values[3:]) for name, values in row.items()} for threads, row in rows.items()}
    return medians, statistics.median(mujoco_speedups[3:])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--objects", nargs="+", default=["shelf", "drawer"], choices=sabre.OBJECTS)
    parser.add_argument("--rollouts", nargs="+", type=int, default=[40, 160])
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument(
        "--idle",
        type=float,
        default=0.0,
        help="ms to sleep before each measured run (default 0: right after MuJoCo's batch on 2 threads)",
    )
    args = parser.parse_args(argv)
    print(
        f"sabre {sabre.__version__} vs MuJoCo {mujoco.__version__}: open phase from the hooked state, variant N, "
        f"median of {args.repeats} alternating rounds; MuJoCo on {MUJOCO_THREADS} threads"
        + (f"; {args.idle:g} ms idle before each measured run" if args.idle > 0 else "")
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
        runners = {threads: mujoco.rollout.Rollout(nthread=threads) for threads in (1, MUJOCO_THREADS)}
        k = sabre.ControllerConfig().horizon_steps
        rng = np.random.default_rng(0)
        for n in args.rollouts:
            state = mujoco_state(model, data, scene, x)
            states0 = np.tile(state, (n, 1))
            commands = np.clip(rng.normal(0.0, 0.3, size=(n, k, scene.nu)), -scene.dq_limit, scene.dq_limit)
            controls = mujoco_controls(model, commands)
            out_state = np.empty((n, k, state.size))

            def peer(threads: int, batch=(runners, model, thread_data, states0, controls, out_state)) -> float:
                runners, model, thread_data, states0, controls, out_state = batch
                start = time.perf_counter()
                runners[threads].rollout(model, thread_data[:threads], states0, controls, state=out_state)
                return time.perf_counter() - start

            medians, mujoco_speedup = time_iterations(scene, x, n, (1, 2), args.repeats, peer, args.idle / 1e3)
            for threads, m in medians.items():
                speedup = "" if threads == 1 else f"{m['speedup']:.2f}x"
                print(
                    f"{obj:<8} {n:>4} {threads:>7} {1e3 * m['iteration']:>10.2f} {1e3 * m['rollouts']:>9.2f} "
                    f"{1e3 * m['core_rest']:>10.2f} {1e3 * m['guides']:>7.2f} {1e3 * m['python']:>7.2f} "
                    f"{1e3 * m['mujoco']:>7.2f} "
                    f"{m['iteration'] / m['mujoco']:>5.2f}x {speedup:>7}",
                    flush=True,
                )
            print(f"{'':<8} {n:>4} MuJoCo's own batch, 2 threads over 1: {mujoco_speedup:.2f}x", flush=True)
    print("(ratio = sabre's whole iteration / MuJoCo's rollouts alone: the goal is 0.5 or less on 2 threads)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
