"""One planning iteration of sabre's controller next to `mujoco.rollout` of the same batch, plus the
closed-loop real-time factor.

    python benches/compare_planning.py [--object shelf] [--repeats 30] [--episode-seconds 30] [--replan-rate 20]
                                       [--contact-model reduced|rapier]

A sabre planning iteration samples N = 40 sequences of K = 67 steps, rolls them out in parallel with
the task's cost evaluated at every step, and updates the policy (`Controller.update`). The peer is
what a MuJoCo-based sampler would pay for its rollouts alone: `mujoco.rollout` of the same N × K
batch on the equivalent scene (support/mujoco_scene.py), 2 threads, per-step states, cost not
included. Both are timed alternately in one process, from three starts: the default state (free
space), the state with the hook on the handle (contact; the open phase planned from rest), and the
closed loop's own re-plan while it pulls the shelf door (the open phase recorded in
benches/data/shelf_open_phase.json, every timed iteration starting from the recorded plan, shelf
only). Medians are printed with the ratio of the two, and with the time sabre's workers spent in
the contact step (`Controller.stats.engine_time`: the reduced contact path, or Rapier's pipeline).
Finally the closed loop opens the object from the paper's start (plant at 1 kHz, re-planning at
`--replan-rate`, 20 Hz by default; `make demo` re-plans at 50 Hz); its real-time factor and the median planning iteration
of each task phase are printed (the approach plans in free space, hook and open in contact).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import mujoco
import mujoco.rollout
import numpy as np

import sabre

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root, for support/
from support.mujoco_scene import build_mujoco_model, mujoco_controls, mujoco_state

THREADS = 2


def hooked_state(scene: sabre.Scene) -> np.ndarray:
    motion = sabre.hook_and_pull(scene)
    start = int(np.argmax(motion.phases == 3)) + 20
    return sabre.RolloutModel(scene).rollout(scene.default_state(), motion.U[None, :start]).states[0, -1]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--object", default="shelf", choices=sabre.OBJECTS)
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--episode-seconds", type=float, default=30.0)
    parser.add_argument("--replan-rate", type=float, default=20.0, help="closed-loop re-planning rate (Hz); make demo uses 50")
    parser.add_argument("--contact-model", default="reduced", choices=sabre.CONTACT_MODELS)
    args = parser.parse_args(argv)

    scene = sabre.Scene.load(obj=args.object)
    config = sabre.ControllerConfig(seed=0, threads=THREADS, contact_model=args.contact_model)
    n, k = config.rollouts, config.horizon_steps
    model = build_mujoco_model(args.object)
    data = mujoco.MjData(model)
    # One MjData per worker thread: rollout threads must not share one.
    thread_data = [mujoco.MjData(model) for _ in range(THREADS)]
    runner = mujoco.rollout.Rollout(nthread=THREADS)
    rng = np.random.default_rng(0)

    print(
        f"sabre {sabre.__version__} ({args.contact_model} contact path) vs MuJoCo {mujoco.__version__}: planning "
        f"iteration, N={n} x K={k}, {THREADS} threads, median of {args.repeats} alternating rounds"
    )
    print(
        f"{'start':<10} {'sabre iteration (ms)':>22} {'mujoco.rollout (ms)':>21} {'ratio':>7} "
        f"{'contact step (ms)':>18} {'share':>6}"
    )
    recorded = json.loads((Path(__file__).resolve().parent / "data" / "shelf_open_phase.json").read_text())
    starts = [("free", scene.default_state()), ("contact", hooked_state(scene))]
    if args.object == recorded["object"]:
        starts.append(("open", np.asarray(recorded["x0"])))
    for label, x in starts:
        controller = sabre.Controller(scene, sabre.tasks.OpenObject(), config)
        if label != "free":
            controller.set_phase("open")
        state = mujoco_state(model, data, scene, x)
        states0 = np.tile(state, (n, 1))
        commands = np.clip(rng.normal(0.0, 0.3, size=(n, k, scene.nu)), -scene.dq_limit, scene.dq_limit)
        controls = mujoco_controls(model, commands)
        out_state = np.empty((n, k, state.size))
        t_sim = 0.0
        sabre_times, mujoco_times, engine_ms, engine_share = [], [], [], []
        for round_ in range(args.repeats + 3):

            def run_sabre() -> float:
                nonlocal t_sim
                if label == "open":  # noqa: B023 (called within this iteration)
                    # The recorded re-plan, from the recorded plan every time: the same work each round.
                    t_sim = recorded["t"]
                    controller.reset(t0=recorded["nominal_t0"])  # noqa: B023
                    controller.set_phase("open", t_sim)  # noqa: B023
                    controller.set_nominal(np.asarray(recorded["nominal"]), recorded["nominal_t0"])  # noqa: B023
                else:
                    t_sim += 0.01
                t0 = time.perf_counter()
                controller.update(x, t_sim)  # noqa: B023 (called within this iteration)
                return time.perf_counter() - t0

            def run_mujoco() -> float:
                t0 = time.perf_counter()
                runner.rollout(model, thread_data, states0, controls, state=out_state)  # noqa: B023 (called within this iteration)
                return time.perf_counter() - t0

            pair = (run_sabre, run_mujoco) if round_ % 2 == 0 else (run_mujoco, run_sabre)
            results = {f.__name__: f() for f in pair}
            if round_ >= 3:
                sabre_times.append(results["run_sabre"])
                mujoco_times.append(results["run_mujoco"])
                stats = controller.stats
                engine_ms.append(1e3 * stats.engine_time / THREADS)
                engine_share.append(stats.engine_time / (THREADS * stats.rollout_time))
        s, m = statistics.median(sabre_times), statistics.median(mujoco_times)
        e, share = statistics.median(engine_ms), statistics.median(engine_share)
        print(f"{label:<10} {1e3 * s:>22.2f} {1e3 * m:>21.2f} {m / s:>6.2f}x {e:>15.2f} {100 * share:>5.0f}%")
    print("(ratio = MuJoCo rollouts alone / sabre's whole iteration; > 1 means sabre's iteration is faster;")
    print(" contact step = time in the rollouts' contact step per worker per iteration, share = its part of")
    print(" the rollout workers' time)")

    controller = sabre.Controller(scene, sabre.tasks.OpenObject(), config)
    episode = sabre.run_episode(scene, controller, args.episode_seconds, seed=0, replan_rate=args.replan_rate, progress=False)
    times = 1e3 * np.asarray(episode.planning_times)
    # Re-plan i happens at i / rate; the phase it planned for is the one recorded just after it.
    plan_times = np.arange(times.size) * episode.duration / times.size
    phases = np.asarray(episode.phase)[np.searchsorted(episode.time, plan_times).clip(0, episode.time.size - 1)]
    per_phase = ", ".join(
        f"{name} {np.median(times[phases == i]):.1f} ms ({np.count_nonzero(phases == i)})"
        for i, name in enumerate(episode.phases)
        if np.any(phases == i)
    )
    print(
        f"closed loop: {episode.duration:.1f} s simulated in {episode.wall_time:.1f} s "
        f"(real-time factor {episode.real_time_factor:.2f}, plant at 1 kHz, re-planning at {args.replan_rate:g} Hz, "
        f"{'opened' if episode.success else 'NOT opened'})"
    )
    print(f"median planning iteration per phase (re-plans): {per_phase}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
