"""Command line of sabre: robust sampling-based control for mobile manipulators opening doors,
drawers and dishwashers.

  python -m sabre demo        closed-loop opening from the paper's start, with a figure (--view: in the browser)
  python -m sabre episode     the same, exit code 1 if the object did not open
  python -m sabre scripted    open-loop hook-and-pull check of the rollout model and the plant
  python -m sabre view        replay a saved episode (.npz) in the browser viewer
  python -m sabre experiment  the paper's experiments over seeds: CSV, figure, summary
  python -m sabre ros-demo    the ROS 2 controller node and a simulated robot as two processes
  python -m sabre control     the ROS 2 controller node alone (sim-robot: the simulated robot)

Run `python -m sabre <command> --help` for the options of each."""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from .. import (
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
    plot_episode,
    run_episode,
    tasks,
)
from ..sim import MAX_THREADS
from .commands import register as register_commands


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
        controller.track(plant, u, steps=per_step)
    wall = time.perf_counter() - t0
    print(f"  plant (1 kHz, full dynamics, PI velocity control): final opening {plant.state[no]:.3f}, "
          f"real-time factor {len(motion.U) * motion.dt / wall:.1f}x")
    return 0 if opening > 0.5 * scene.o_upper[0] else 1


def episode_command(obj: str, duration: float, start: str, seed: int, replan_rate: float, plot: str | None,
                    variant: str = "N", threads: int | None = None, view: bool = False) -> int:
    """Closed-loop opening with the sampling-based controller in the plant; 0 if it opened, else 1."""
    scene = Scene.load(obj=obj)
    task = tasks.OpenObject()
    controller = Controller(scene, task, ControllerConfig(seed=seed, variant=variant, threads=threads))
    x0 = paper_start_state(scene) if start == "paper" else scene.default_state()
    print(f"[{obj}] variant {variant}, seed {seed}: up to {duration:.0f} s of simulated time from the "
          f"{'paper' if start == 'paper' else 'default'} start, re-planning at {replan_rate:.0f} Hz")
    viewer = None
    if view:
        from ..viz.viewer import Viewer

        viewer = Viewer(scene)
        viewer.look_at(0.5 * (x0[:3] + scene.object_pose[:3, 3]), distance=6.0)
        print(f"  viewer: http://127.0.0.1:{viewer.port}")
    episode = run_episode(scene, controller, duration, seed=seed, x0=x0, replan_rate=replan_rate, viewer=viewer)
    when = "—" if episode.time_to_success is None else f"{episode.time_to_success:.1f} s"
    print(f"[{obj}] success: {episode.success}, final opening {episode.opening[-1]:.3f} "
          f"(target {task.target_opening(scene):.3f}, success at {task.open.success_fraction:.0%}), time to open: {when}")
    print(f"  phases: {[(round(t, 2), p) for t, p in controller.phase_history]}")
    tank_end = "—" if episode.tank_energy is None else f"{episode.tank_energy[-1]:.2f} J"
    power = episode.dissipated_energy() / max(episode.duration, 1e-9)
    print(f"  mean wrench in contact {episode.mean_wrench():.1f} N, dissipated energy {episode.dissipated_energy():.2f} J "
          f"(mean dissipated power {power:.2f} W), tank at the end {tank_end}")
    print(f"  planning iteration median {1e3 * np.median(episode.planning_times):.1f} ms, "
          f"real-time factor {episode.real_time_factor:.2f}")
    if plot:
        plot_episode(episode, plot)
        print(f"  wrote {plot}")
    if viewer is not None:
        print("  run finished: replaying it in the viewer (Ctrl-C to stop)")
        try:
            viewer.load_episode(episode).play()
        except KeyboardInterrupt:
            pass
        finally:
            viewer.close()
    return 0 if episode.success else 1


class _HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows every option's default, except where the help text already says what None means."""

    def _get_help_string(self, action: argparse.Action) -> str:
        if action.default is None:
            return action.help or ""
        return super()._get_help_string(action) or ""


class _TopHelpFormatter(_HelpFormatter, argparse.RawDescriptionHelpFormatter):
    """Keeps the line breaks of the command overview."""


def _positive_float(text: str) -> float:
    value = float(text)
    if not (value > 0.0 and np.isfinite(value)):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text}")
    return value


def _seed(text: str) -> int:
    value = int(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be a non-negative integer, got {text}")
    return value


def _threads(text: str) -> int:
    value = int(text)
    if not 1 <= value <= MAX_THREADS:
        raise argparse.ArgumentTypeError(f"must be between 1 and {MAX_THREADS}, got {text}")
    return value


def _episode_options(parser: argparse.ArgumentParser, duration: float, replan_rate: float, plot_help: str) -> None:
    parser.add_argument("--object", choices=OBJECTS, default="shelf", help="articulated object to open")
    parser.add_argument("--variant", choices=VARIANTS, default="N",
                        help="N: no filter; I: 1 kHz FILTER-QP with the energy tank; O: sequential FILTER-QP on "
                             "each plan; IO: both")
    parser.add_argument("--seed", type=_seed, default=0, help="random seed of the sampler")
    parser.add_argument("--duration", type=_positive_float, default=duration, metavar="S",
                        help="longest episode, in seconds of simulated time (it ends 0.5 s after success)")
    parser.add_argument("--replan-rate", type=_positive_float, default=replan_rate, metavar="HZ",
                        help="re-planning rate of the outer loop, in Hz of simulated time")
    parser.add_argument("--threads", type=_threads, default=None, metavar="N",
                        help="worker threads of the parallel rollouts (default: every available core)")
    parser.add_argument("--plot", default=None, metavar="PNG",
                        help="write a figure of opening, wrist force, tank energy and base path to this PNG " + plot_help)


def main(argv: list[str] | None = None) -> int:
    """Parses ``argv`` (default: the command line) and runs the subcommand; returns the exit code."""
    parser = argparse.ArgumentParser(prog="python -m sabre", description=__doc__, formatter_class=_TopHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", formatter_class=_HelpFormatter,
                          help="open an articulated object from the paper's starting condition and plot it",
                          description="Closed-loop opening from the paper's start (base at (-3, -3), arm folded), "
                                      "with a figure. Exits 0 whether or not the object opened.")
    _episode_options(demo, duration=60.0, replan_rate=50.0, plot_help="(default: sabre_demo_<object>.png)")
    demo.add_argument("--view", action="store_true", help="show the run in the browser viewer (needs the viewer extra)")
    ep = sub.add_parser("episode", formatter_class=_HelpFormatter,
                        help="closed-loop opening with the sampling-based controller",
                        description="Closed-loop opening in the 1 kHz plant. Exits 1 if the object did not open.")
    _episode_options(ep, duration=30.0, replan_rate=100.0, plot_help="(default: no figure)")
    ep.add_argument("--start", choices=("default", "paper"), default="paper",
                    help="paper: base at (-3, -3) with the arm folded; default: the scene's default state")
    scripted = sub.add_parser("scripted", formatter_class=_HelpFormatter,
                              help="open-loop scripted hook-and-pull in the rollout model and the plant",
                              description="Replays a scripted hook-and-pull open loop in the rollout model and in "
                                          "the plant and reports the rollout throughput. Exits 1 if the rollout "
                                          "model opened the object less than half way.")
    scripted.add_argument("--object", choices=OBJECTS, default="shelf", help="articulated object to open")
    scripted.add_argument("--threads", type=_threads, default=None, metavar="N",
                          help="worker threads of the throughput test (default: every available core)")
    register_commands(sub)
    from .ros import add_commands as add_ros_commands

    add_ros_commands(sub)
    args = parser.parse_args(argv)
    if hasattr(args, "run"):
        return args.run(args)
    if hasattr(args, "handler"):
        return args.handler(args)
    if args.command == "demo":
        plot = args.plot or f"sabre_demo_{args.object}.png"
        episode_command(args.object, args.duration, "paper", args.seed, args.replan_rate, plot, args.variant, args.threads,
                        args.view)
        return 0
    if args.command == "scripted":
        return scripted_demo(args.object, args.threads)
    if args.command == "episode":
        return episode_command(args.object, args.duration, args.start, args.seed, args.replan_rate, args.plot, args.variant,
                               args.threads)
    return 2


if __name__ == "__main__":
    sys.exit(main())
