"""The subcommands that run the robot in simulation: ``demo`` and ``episode`` (closed-loop opening in
the plant) and ``scripted`` (open-loop hook-and-pull with the rollout throughput)."""

from __future__ import annotations

import argparse
import time
from typing import TYPE_CHECKING

import numpy as np

from .. import (
    OBJECTS,
    VARIANTS,
    Controller,
    ControllerConfig,
    LowLevelController,
    MujocoPlant,
    Plant,
    RolloutModel,
    Scene,
    default_threads,
    hook_and_pull,
    plot_episode,
    run_episode,
    tasks,
)
from ..closed_loop import paper_start_state
from ..errors import InvalidValueError
from ._args import HelpFormatter, non_negative_int, positive_float, thread_count

if TYPE_CHECKING:
    from .. import Episode
    from ..viz.viewer import Viewer

__all__ = ["register", "demo_command", "episode_command", "scripted_command", "open_in_plant", "scripted_demo", "PLANTS"]

#: The plants ``demo`` and ``episode`` run on (``--plant``): sabre's Rapier plant and MuJoCo's.
PLANTS: tuple[str, ...] = ("sabre", "mujoco")


def register(sub: argparse._SubParsersAction) -> None:
    """Adds ``demo``, ``episode`` and ``scripted``; each sets ``run`` (args -> exit code)."""
    demo = sub.add_parser(
        "demo",
        formatter_class=HelpFormatter,
        help="open an articulated object from the paper's starting condition and plot it",
        description="Closed-loop opening from the paper's start (base at (-3, -3), arm folded), "
        "with a figure. Exits 0 whether or not the object opened.",
    )
    _episode_options(demo, duration=60.0, replan_rate=50.0, plot_help="(default: sabre_demo_<object>.png)")
    demo.add_argument("--view", action="store_true", help="show the run in the browser viewer (needs the viewer extra)")
    demo.set_defaults(run=demo_command)
    episode = sub.add_parser(
        "episode",
        formatter_class=HelpFormatter,
        help="closed-loop opening with the sampling-based controller",
        description="Closed-loop opening in the 1 kHz plant. Exits 1 if the object did not open.",
    )
    _episode_options(episode, duration=30.0, replan_rate=100.0, plot_help="(default: no figure)")
    episode.add_argument(
        "--start",
        choices=("default", "paper"),
        default="paper",
        help="paper: base at (-3, -3) with the arm folded; default: the scene's default state",
    )
    episode.set_defaults(run=episode_command)
    scripted = sub.add_parser(
        "scripted",
        formatter_class=HelpFormatter,
        help="open-loop scripted hook-and-pull in the rollout model and the plant",
        description="Replays a scripted hook-and-pull open loop in the rollout model and in "
        "the plant and reports the rollout throughput. Exits 1 if the rollout "
        "model opened the object less than half way.",
    )
    scripted.add_argument("--object", choices=OBJECTS, default="shelf", help="articulated object to open")
    scripted.add_argument(
        "--threads",
        type=thread_count,
        default=None,
        metavar="N",
        help="worker threads of the throughput test (default: every available core)",
    )
    scripted.set_defaults(run=scripted_command)


def _episode_options(parser: argparse.ArgumentParser, duration: float, replan_rate: float, plot_help: str) -> None:
    parser.add_argument("--object", choices=OBJECTS, default="shelf", help="articulated object to open")
    parser.add_argument(
        "--variant",
        choices=VARIANTS,
        default="N",
        help="N: no filter; I: 1 kHz FILTER-QP with the energy tank; O: sequential FILTER-QP on each plan; IO: both",
    )
    parser.add_argument("--seed", type=non_negative_int, default=0, help="random seed of the sampler")
    parser.add_argument(
        "--plant",
        choices=PLANTS,
        default="sabre",
        help="the 1 kHz plant: sabre's Rapier plant, or MuJoCo's (sabre.MujocoPlant, needs the mujoco extra)",
    )
    parser.add_argument(
        "--duration",
        type=positive_float,
        default=duration,
        metavar="S",
        help="longest episode, in seconds of simulated time (it ends 0.5 s after success)",
    )
    parser.add_argument(
        "--replan-rate",
        type=positive_float,
        default=replan_rate,
        metavar="HZ",
        help="re-planning rate of the outer loop, in Hz of simulated time",
    )
    parser.add_argument(
        "--threads",
        type=thread_count,
        default=None,
        metavar="N",
        help="worker threads of the parallel rollouts (default: every available core)",
    )
    parser.add_argument(
        "--plot",
        default=None,
        metavar="PNG",
        help="write a figure of opening, wrist force, tank energy and base path to this PNG " + plot_help,
    )


def demo_command(args: argparse.Namespace) -> int:
    """``demo``: the episode from the paper's start with a figure; 0 whether or not it opened."""
    open_in_plant(
        args.object,
        duration=args.duration,
        start="paper",
        seed=args.seed,
        replan_rate=args.replan_rate,
        plot=args.plot or f"sabre_demo_{args.object}.png",
        variant=args.variant,
        threads=args.threads,
        view=args.view,
        plant=args.plant,
    )
    return 0


def episode_command(args: argparse.Namespace) -> int:
    """``episode``: 0 if the object opened, else 1."""
    opened = open_in_plant(
        args.object,
        duration=args.duration,
        start=args.start,
        seed=args.seed,
        replan_rate=args.replan_rate,
        plot=args.plot,
        variant=args.variant,
        threads=args.threads,
        plant=args.plant,
    )
    return 0 if opened else 1


def scripted_command(args: argparse.Namespace) -> int:
    """``scripted``: 0 if the rollout model opened the object at least half way, else 1."""
    return scripted_demo(args.object, args.threads)


def open_in_plant(
    obj: str,
    *,
    duration: float,
    start: str,
    seed: int,
    replan_rate: float,
    plot: str | None,
    variant: str = "N",
    threads: int | None = None,
    view: bool = False,
    plant: str = "sabre",
) -> bool:
    """Closed-loop opening with the sampling-based controller in the plant (``plant``: "sabre" for sabre's
    Rapier plant, "mujoco" for :class:`sabre.MujocoPlant`), reported on stdout; True if the object opened."""
    if plant not in PLANTS:
        raise InvalidValueError(f"plant must be one of {PLANTS}, got {plant!r}")
    scene = Scene.load(obj=obj)
    simulator = MujocoPlant(scene) if plant == "mujoco" else Plant(scene)
    task = tasks.OpenObject()
    controller = Controller(scene, task, ControllerConfig(seed=seed, variant=variant, threads=threads))
    x0 = paper_start_state(scene) if start == "paper" else scene.default_state()
    print(
        f"[{obj}] variant {variant}, seed {seed}: up to {duration:.0f} s of simulated time from the "
        f"{'paper' if start == 'paper' else 'default'} start, re-planning at {replan_rate:.0f} Hz, in the {plant} plant"
    )
    viewer = _live_viewer(scene, x0) if view else None
    episode = run_episode(scene, controller, duration, seed=seed, x0=x0, replan_rate=replan_rate, viewer=viewer, plant=simulator)
    _report(obj, episode, controller, task)
    if plot:
        plot_episode(episode, plot)
        print(f"  wrote {plot}")
    if viewer is not None:
        _replay_until_interrupted(viewer, episode)
    return bool(episode.success)


def _report(obj: str, episode: Episode, controller: Controller, task: tasks.OpenObject) -> None:
    scene = episode.scene
    when = "—" if episode.time_to_success is None else f"{episode.time_to_success:.1f} s"
    print(
        f"[{obj}] success: {episode.success}, final opening {episode.opening[-1]:.3f} "
        f"(target {task.target_opening(scene):.3f}, success at {task.open.success_fraction:.0%}), time to open: {when}"
    )
    print(f"  phases: {[(round(t, 2), p) for t, p in controller.phase_history]}")
    tank_end = "—" if episode.tank_energy is None else f"{episode.tank_energy[-1]:.2f} J"
    power = episode.dissipated_energy() / max(episode.duration, 1e-9)
    print(
        f"  mean wrench in contact {episode.mean_wrench():.1f} N, dissipated energy {episode.dissipated_energy():.2f} J "
        f"(mean dissipated power {power:.2f} W), tank at the end {tank_end}"
    )
    print(
        f"  planning iteration median {1e3 * np.median(episode.planning_times):.1f} ms, "
        f"real-time factor {episode.real_time_factor:.2f}"
    )


def _live_viewer(scene: Scene, x0: np.ndarray) -> Viewer:
    from ..viz.viewer import Viewer

    viewer = Viewer(scene)
    base = scene.fk(scene.split_state(x0).q, scene.base_link)[:3, 3]
    viewer.look_at(0.5 * (base + scene.object_pose[:3, 3]), distance=6.0)
    print(f"  viewer: http://127.0.0.1:{viewer.port}")
    return viewer


def _replay_until_interrupted(viewer: Viewer, episode: Episode) -> None:
    print("  run finished: replaying it in the viewer (Ctrl-C to stop)")
    try:
        viewer.load_episode(episode).play()
    except KeyboardInterrupt:
        pass
    finally:
        viewer.close()


def scripted_demo(obj: str, threads: int | None) -> int:
    """Open-loop scripted hook-and-pull in the rollout model and in the plant, with throughput; 0 if
    the rollout model opened the object at least half way, else 1."""
    scene = Scene.load(obj=obj)
    motion = hook_and_pull(scene)
    model = RolloutModel(scene)
    x0 = scene.default_state()

    start = time.perf_counter()
    result = model.rollout(x0, motion.U[None], threads=1)
    elapsed = time.perf_counter() - start
    opening = scene.split_state(result.states[0, -1]).o[0]
    contact_steps = int(result.contact[0].sum())
    print(
        f"[{obj}] scripted hook-and-pull, {len(motion.U)} steps of {motion.dt * 1e3:.0f} ms "
        f"({len(motion.U) * motion.dt:.1f} s simulated) in {elapsed * 1e3:.1f} ms"
    )
    print(
        f"  rollout model: final opening {opening:.3f} of {scene.o_upper[0]:.2f} "
        f"({'rad' if scene.object_is_revolute else 'm'}), hook in contact for {contact_steps} steps, "
        f"peak wrist force {np.linalg.norm(result.wrench[0, :, :3], axis=1).max():.1f} N"
    )
    _throughput(model, x0, motion.U, threads or default_threads())

    plant = Plant(scene)
    controller = LowLevelController(scene, dt=plant.dt)
    plant.reset(x0)
    per_step = int(round(motion.dt / plant.dt))
    t0 = time.perf_counter()
    for u in motion.U:
        controller.track(plant, u, steps=per_step)
    wall = time.perf_counter() - t0
    print(
        f"  plant (1 kHz, full dynamics, PI velocity control): final opening {scene.split_state(plant.state).o[0]:.3f}, "
        f"real-time factor {len(motion.U) * motion.dt / wall:.1f}x"
    )
    return 0 if opening > 0.5 * scene.o_upper[0] else 1


def _throughput(model: RolloutModel, x0: np.ndarray, U: np.ndarray, threads: int) -> None:
    """Times the kernel the controller uses: 40 rollouts of 66 steps around the scripted plan
    (median of 10 after one warm-up)."""
    rng = np.random.default_rng(0)
    n, k = 40, 66
    batch = U[None, :k] + rng.normal(0.0, 0.1, size=(n, k, U.shape[1]))
    model.rollout(x0, batch, threads=threads)
    runs = []
    for _ in range(10):
        t0 = time.perf_counter()
        model.rollout(x0, batch, threads=threads)
        runs.append(time.perf_counter() - t0)
    median = float(np.median(runs))
    print(
        f"  throughput: {n}x{k} rollouts in {median * 1e3:.2f} ms on {threads} thread{'s' if threads != 1 else ''} "
        f"= {n * k / median:,.0f} steps/s"
    )
