"""Command line: ``python -m sabre demo [--object shelf] [--variant IO]`` (closed-loop opening from
the paper's starting condition), ``python -m sabre episode ...`` (the same with more options) and
``python -m sabre scripted [--object shelf]`` (the open-loop hook-and-pull check of the simulators)."""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from . import (
    OBJECTS,
    VARIANTS,
    Controller,
    ControllerConfig,
    LowLevelController,
    Plant,
    RolloutModel,
    Scene,
    default_threads,
    hook_and_pull,
    paper_start_state,
    run_episode,
    tasks,
)


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


def plot_episode(episode, path: str) -> None:
    """Opening, wrench norm and base path of an episode, as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    axes[0].plot(episode.time, episode.opening)
    axes[0].set(xlabel="time (s)", ylabel="opening", title="object")
    axes[1].plot(episode.time, np.linalg.norm(episode.wrench[:, :3], axis=1))
    axes[1].set(xlabel="time (s)", ylabel="|f| (N)", title="wrist force")
    axes[2].plot(episode.state[:, 0], episode.state[:, 1])
    axes[2].set(xlabel="x (m)", ylabel="y (m)", title="base path", aspect="equal")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def episode_command(obj: str, duration: float, start: str, seed: int, replan_rate: float, plot: str | None,
                    variant: str = "N", threads: int | None = None) -> int:
    """Closed-loop opening with the sampling-based controller in the plant."""
    scene = Scene.load(obj=obj)
    task = tasks.OpenObject()
    controller = Controller(scene, task, ControllerConfig(seed=seed, variant=variant, threads=threads))
    x0 = paper_start_state(scene) if start == "paper" else scene.default_state()
    print(f"[{obj}] variant {variant}, seed {seed}: up to {duration:.0f} s of simulated time from the "
          f"{'paper' if start == 'paper' else 'default'} start, re-planning at {replan_rate:.0f} Hz")
    episode = run_episode(scene, controller, duration, seed=seed, x0=x0, replan_rate=replan_rate)
    when = "—" if episode.time_to_success is None else f"{episode.time_to_success:.1f} s"
    print(f"[{obj}] success: {episode.success}, final opening {episode.opening[-1]:.3f} "
          f"(target {task.target_opening(scene):.3f}, success at {task.success_fraction:.0%}), time to open: {when}")
    print(f"  phases: {[(round(t, 2), p) for t, p in controller.phase_history]}")
    power = episode.dissipated_energy() / max(episode.duration, 1e-9)
    print(f"  mean wrench in contact {episode.mean_wrench():.1f} N, dissipated energy {episode.dissipated_energy():.2f} J "
          f"(mean dissipated power {power:.2f} W), tank at the end {episode.tank_energy[-1]:.2f} J")
    print(f"  planning iteration median {1e3 * np.median(episode.planning_times):.1f} ms, "
          f"real-time factor {episode.real_time_factor:.2f}")
    if plot:
        plot_episode(episode, plot)
        print(f"  wrote {plot}")
    return 0 if episode.success else 1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sabre", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="open an articulated object from the paper's starting condition")
    demo.add_argument("--object", choices=OBJECTS, default="shelf")
    demo.add_argument("--variant", choices=VARIANTS, default="N")
    demo.add_argument("--seed", type=int, default=0)
    demo.add_argument("--threads", type=int, default=None)
    demo.add_argument("--plot", default=None, help="PNG path (default: sabre_demo_<object>.png)")
    scripted = sub.add_parser("scripted", help="open-loop scripted hook-and-pull in the rollout model and the plant")
    scripted.add_argument("--object", choices=OBJECTS, default="shelf")
    scripted.add_argument("--threads", type=int, default=None)
    ep = sub.add_parser("episode", help="closed-loop opening with the sampling-based controller")
    ep.add_argument("--object", choices=OBJECTS, default="shelf")
    ep.add_argument("--duration", type=float, default=30.0)
    ep.add_argument("--start", choices=("default", "paper"), default="paper")
    ep.add_argument("--seed", type=int, default=0)
    ep.add_argument("--replan-rate", type=float, default=100.0)
    ep.add_argument("--plot", default=None, help="write a PNG of opening, wrench and base path")
    ep.add_argument("--variant", choices=VARIANTS, default="N")
    from .ros.cli import add_commands as add_ros_commands

    add_ros_commands(sub)
    args = parser.parse_args(argv)
    if hasattr(args, "handler"):
        return args.handler(args)
    if args.command == "demo":
        plot = args.plot or f"sabre_demo_{args.object}.png"
        episode_command(args.object, 60.0, "paper", args.seed, 50.0, plot, args.variant, args.threads)
        return 0  # the demo reports; `episode` exits non-zero on failure
    if args.command == "scripted":
        return scripted_demo(args.object, args.threads)
    if args.command == "episode":
        return episode_command(args.object, args.duration, args.start, args.seed, args.replan_rate, args.plot, args.variant)
    return 2


if __name__ == "__main__":
    sys.exit(main())
