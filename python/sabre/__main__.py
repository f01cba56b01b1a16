"""Command line: ``python -m sabre demo [--object shelf]``."""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from . import OBJECTS, Plant, LowLevelController, RolloutModel, Scene, default_threads, hook_and_pull


def scripted_demo(obj: str, threads: int | None) -> int:
    """Open-loop scripted hook-and-pull in the rollout model and in the plant, with throughput."""
    scene = Scene.load(obj=obj)
    motion = hook_and_pull(scene)
    model = RolloutModel(scene)
    x0 = scene.default_state()
    no = scene.nq * 2

    start = time.perf_counter()
    result = model.rollout(x0, motion.U[None], threads=1)
    elapsed = time.perf_counter() - start
    opening = result.states[0, -1, no]
    contact_steps = int(result.contact[0].sum())
    print(f"[{obj}] scripted hook-and-pull, {len(motion.U)} steps of {motion.dt * 1e3:.0f} ms "
          f"({len(motion.U) * motion.dt:.1f} s simulated) in {elapsed * 1e3:.1f} ms")
    print(f"  rollout model: final opening {opening:.3f} of {scene.o_upper[0]:.2f} "
          f"({'rad' if scene.object_is_revolute else 'm'}), hook in contact for {contact_steps} steps, "
          f"peak wrist force {np.linalg.norm(result.wrench[0, :, :3], axis=1).max():.1f} N")

    # Throughput of the kernel the controller uses: 40 rollouts of 66 steps around the scripted plan.
    rng = np.random.default_rng(0)
    n, k = 40, 66
    batch = motion.U[None, :k] + rng.normal(0.0, 0.1, size=(n, k, scene.nu))
    threads = threads or default_threads()
    model.rollout(x0, batch, threads=threads)
    runs = []
    for _ in range(10):
        t0 = time.perf_counter()
        model.rollout(x0, batch, threads=threads)
        runs.append(time.perf_counter() - t0)
    median = float(np.median(runs))
    print(f"  throughput: {n}x{k} rollouts in {median * 1e3:.2f} ms on {threads} threads "
          f"= {n * k / median:,.0f} steps/s")

    plant = Plant(scene)
    controller = LowLevelController(scene, dt=plant.dt)
    plant.reset(x0)
    per_step = int(round(motion.dt / plant.dt))
    t0 = time.perf_counter()
    for u in motion.U:
        plant.track(controller, u, steps=per_step)
    wall = time.perf_counter() - t0
    print(f"  plant (1 kHz, full dynamics, PI velocity control): final opening {plant.state[no]:.3f}, "
          f"real-time factor {len(motion.U) * motion.dt / wall:.1f}x")
    return 0 if opening > 0.5 * scene.o_upper[0] else 1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sabre", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="open an articulated object")
    demo.add_argument("--object", choices=OBJECTS, default="shelf")
    demo.add_argument("--threads", type=int, default=None)
    args = parser.parse_args(argv)
    if args.command == "demo":
        return scripted_demo(args.object, args.threads)
    return 2


if __name__ == "__main__":
    sys.exit(main())
