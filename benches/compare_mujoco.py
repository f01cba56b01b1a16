"""Throughput of sabre's rollout model against MuJoCo on the equivalent scene.

    python benches/compare_mujoco.py [--object shelf] [--repeats 30]

Both simulators roll out the same batch: N = 40 input sequences of K = 66 steps (dt = 0.015 s) on
2 threads, recording the state at every step. MuJoCo runs `mujoco.rollout.Rollout(nthread=2)`
(one pool and one MjData per thread, reused across calls, output buffer preallocated); sabre runs
`RolloutModel.rollout(x0, U, threads=2)`. Initial states and controls are prepared once, outside
the timed region. After a warm-up the two are timed alternately in the same process (the order
flips every round) and the medians are reported, for two batches:

  (a) free motion: the default state, small seeded random joint velocities (N(0, 0.3) clipped to
      the velocity limits); the hand stays clear of the object.
  (b) in contact: the state that sabre reaches by running the scripted hook-and-pull motion up to
      the start of its pull phase (hook on the handle), then the next 66 commands of the script plus
      small seeded noise per rollout (rollout 0 is the nominal, noise-free sequence). MuJoCo starts
      from the same qpos / qvel.

So that a reader can judge how equivalent the two scenes are, the script also prints, for the
nominal contact sequence, the fraction of steps with robot-object contact and the final opening
in each simulator (MuJoCo's contacts are counted by stepping the nominal sequence with mj_step,
since rollout does not report them), plus the same for the whole pull phase of the script, and
the joint-space divergence of the free-motion batch. The scene differences are listed in
support/mujoco_scene.py. The numbers are also written to benches/results/compare_mujoco.json.

Besides the specified MuJoCo model (velocity servos, "MuJoCo"; the ratio sabre/MuJoCo is the
headline), a reference variant "MuJoCo+I" with integral servo actuators (the PI structure of
sabre's servo; see support/mujoco_scene.py) is timed and compared too, because without integral action
MuJoCo's arm yields to the door's resistance during long pulls. Skip it with --no-integral-variant.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import mujoco
import mujoco.rollout
import numpy as np

import sabre

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root, for support/
from support.mujoco_scene import (
    STATE_SPEC,
    TIMESTEP,
    build_mujoco_model,
    mujoco_controls,
    mujoco_state,
    mujoco_step_through,
    qpos_slice,
)

N = 40
K = 66
THREADS = 2
DT = TIMESTEP  # the MuJoCo scene's step, also sabre's dt here
FREE_SIGMA = 0.3  # rad/s or m/s
CONTACT_NOISE_SIGMA = 0.05  # rad/s or m/s
WARMUP = 3
RESULTS = Path(__file__).resolve().parent / "results" / "compare_mujoco.json"


# --------------------------------------------------------------------------------------------
# MuJoCo side: timed rollouts
# --------------------------------------------------------------------------------------------


class MujocoRunner:
    """One batch on a persistent `mujoco.rollout.Rollout` pool: inputs, MjData and output buffer made once."""

    def __init__(self, pool: mujoco.rollout.Rollout, model: mujoco.MjModel, init_state: np.ndarray, control: np.ndarray) -> None:
        self.pool = pool
        self.model = model
        self.data = [mujoco.MjData(model) for _ in range(THREADS)]
        self.init_state = np.ascontiguousarray(init_state)
        self.control = np.ascontiguousarray(control)
        self.out = np.empty((len(control), control.shape[1], mujoco.mj_stateSize(model, STATE_SPEC)))

    def __call__(self) -> np.ndarray:
        state, _ = self.pool.rollout(self.model, self.data, self.init_state, self.control, state=self.out)
        return state


# --------------------------------------------------------------------------------------------
# Batches
# --------------------------------------------------------------------------------------------


def free_batch(scene: sabre.Scene, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    x0 = scene.default_state()
    lim = scene.dq_limit
    U = np.clip(rng.normal(0.0, FREE_SIGMA, size=(N, K, scene.nu)), -lim, lim)
    return x0, np.ascontiguousarray(U)


def contact_batch(scene: sabre.Scene, model: sabre.RolloutModel, rng: np.random.Generator):
    """(x0, U, motion, start): x0 = sabre's state at the first pull step of the scripted motion."""
    motion = sabre.hook_and_pull(scene, dt=DT)
    pull = np.flatnonzero(motion.phases == 3)
    if pull.size == 0:
        raise RuntimeError("the scripted motion has no pull phase")
    start = int(pull[0])
    if start + K > len(motion.U):
        raise RuntimeError(f"scripted motion too short: pull starts at {start}, {len(motion.U)} steps")
    pre = model.rollout(scene.default_state(), motion.U[None, :start], threads=1)
    if pre.failed[0]:
        raise RuntimeError("sabre diverged on the approach of the scripted motion")
    x0 = np.array(pre.states[0, -1])
    nominal = motion.U[start : start + K]
    lim = scene.dq_limit
    noise = rng.normal(0.0, CONTACT_NOISE_SIGMA, size=(N, K, scene.nu))
    noise[0] = 0.0  # rollout 0 is the nominal sequence
    U = np.clip(nominal[None] + noise, -lim, lim)
    return x0, np.ascontiguousarray(U), motion, start


# --------------------------------------------------------------------------------------------
# Timing
# --------------------------------------------------------------------------------------------


def time_alternating(runners: dict, repeats: int, warmup: int) -> dict[str, list[float]]:
    """Runs every runner once per round, the order reversed every other round; warm-up rounds untimed."""
    names = list(runners)
    times: dict[str, list[float]] = {n: [] for n in names}
    for r in range(warmup + repeats):
        for n in names if r % 2 == 0 else names[::-1]:
            t0 = time.perf_counter()
            runners[n]()
            elapsed = time.perf_counter() - t0
            if r >= warmup:
                times[n].append(elapsed)
    return times


def summarize(ts: list[float]) -> dict[str, float]:
    med = statistics.median(ts)
    return {"median_ms": 1e3 * med, "min_ms": 1e3 * min(ts), "max_ms": 1e3 * max(ts), "steps_per_s": N * K / med}


# --------------------------------------------------------------------------------------------
# Main
# --------------------------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--object", default="shelf", choices=["shelf", "microwave", "dishwasher", "drawer"])
    p.add_argument("--repeats", type=int, default=30)
    p.add_argument("--warmup", type=int, default=WARMUP)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, default=RESULTS)
    p.add_argument(
        "--no-integral-variant",
        action="store_true",
        help="skip the reference MuJoCo model with integral servo actuators (MuJoCo+I)",
    )
    args = p.parse_args(argv)
    if args.repeats < 1 or args.warmup < 0:
        p.error("--repeats must be >= 1 and --warmup >= 0")

    scene = sabre.Scene.load(robot="royalpanda", obj=args.object)
    nq = scene.nq
    o_index = 2 * nq  # opening in sabre's state
    sabre_model = sabre.RolloutModel(scene, dt=DT)
    mj_models = {"MuJoCo": build_mujoco_model(args.object, scene)}
    if not args.no_integral_variant:
        mj_models["MuJoCo+I"] = build_mujoco_model(args.object, scene, servo_integral=True)
    for m in mj_models.values():
        if abs(m.opt.timestep - DT) > 1e-12:
            raise RuntimeError("MuJoCo timestep differs from sabre's dt")
    scratch = {name: mujoco.MjData(m) for name, m in mj_models.items()}
    rng = np.random.default_rng(args.seed)

    pool = mujoco.rollout.Rollout(nthread=THREADS)  # one thread pool, reused by every MuJoCo call
    x0f, Uf = free_batch(scene, rng)
    x0c, Uc, motion, start = contact_batch(scene, sabre_model, rng)
    batches = {"free motion": (x0f, Uf), "in contact": (x0c, Uc)}

    results: dict = {
        "object": args.object,
        "N": N,
        "K": K,
        "threads": THREADS,
        "dt": DT,
        "repeats": args.repeats,
        "warmup": args.warmup,
        "seed": args.seed,
        "sabre_version": getattr(sabre, "__version__", None),
        "mujoco_version": mujoco.__version__,
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count()},
        "notes": {
            "MuJoCo": "velocity actuators kv = 40 M_ii(home), P-only servo (the benchmark's reference)",
            "MuJoCo+I": "MuJoCo plus intvelocity actuators kp = 400 M_ii(home) (PI servo like sabre's); reference only",
        },
        "batches": {},
    }
    qpos_at = {name: qpos_slice(m) for name, m in mj_models.items()}
    final: dict[str, dict] = {}
    for bname, (x0, U) in batches.items():
        mj_runners = {}
        for name, m in mj_models.items():
            init = mujoco_state(m, scratch[name], scene, x0)
            mj_runners[name] = MujocoRunner(pool, m, np.tile(init, (N, 1)), mujoco_controls(m, U))
        runners = dict(mj_runners)
        runners["sabre"] = lambda x0=x0, U=U: sabre_model.rollout(x0, U, threads=THREADS)
        times = time_alternating(runners, args.repeats, args.warmup)
        timing = {name: summarize(ts) for name, ts in times.items()}
        for name in mj_models:
            ratio = timing["sabre"]["steps_per_s"] / timing[name]["steps_per_s"]
            timing[f"ratio_sabre_over_{name}_steps_per_s"] = ratio
        results["batches"][bname] = {"timing": timing}
        # Outputs of one more (untimed) call of each, for the equivalence figures.
        final[bname] = {name: np.array(r())[:, :, qpos_at[name]] for name, r in mj_runners.items()}
        final[bname]["sabre"] = sabre_model.rollout(x0, U, threads=THREADS)
    pool.close()

    # ---- equivalence: free motion (joint-space divergence from sabre) -----------------------
    sb = final["free motion"]["sabre"]
    eq_free: dict = {"sabre_contact_fraction": float(np.mean(sb.contact)), "sabre_failed": int(np.sum(sb.failed))}
    for name in mj_models:
        dq = np.abs(sb.states[:, 1:, :nq] - final["free motion"][name][:, :, :nq])
        eq_free[name] = {"mean_abs_dq_final": float(dq[:, -1].mean()), "max_abs_dq_final": float(dq[:, -1].max())}
    results["batches"]["free motion"]["equivalence"] = eq_free

    # ---- equivalence: in contact -------------------------------------------------------------
    sb = final["in contact"]["sabre"]
    pull_U = motion.U[start:][motion.phases[start:] == 3]  # the whole pull phase of the script
    sb_pull = sabre_model.rollout(x0c, pull_U[None], threads=1)
    rows = {
        "nominal_contact_fraction": {"sabre": float(np.mean(sb.contact[0]))},
        "nominal_final_opening": {"sabre": float(sb.states[0, -1, o_index])},
        "batch_contact_fraction": {"sabre": float(np.mean(sb.contact))},
        "batch_mean_final_opening": {"sabre": float(np.mean(sb.states[:, -1, o_index]))},
        "pull_phase_contact_fraction": {"sabre": float(np.mean(sb_pull.contact[0]))},
        "pull_phase_final_opening": {"sabre": float(sb_pull.states[0, -1, o_index])},
    }
    for name, m in mj_models.items():
        init = mujoco_state(m, scratch[name], scene, x0c)
        opening, contact = mujoco_step_through(m, scratch[name], init, Uc[0], nq)
        pull_opening, pull_contact = mujoco_step_through(m, scratch[name], init, pull_U, nq)
        states = final["in contact"][name]
        if abs(states[0, -1, nq] - opening[-1]) > 1e-9:
            print(f"warning: {name} rollout and mj_step disagree on the nominal opening", file=sys.stderr)
        rows["nominal_contact_fraction"][name] = float(np.mean(contact))
        rows["nominal_final_opening"][name] = float(opening[-1])
        rows["batch_contact_fraction"][name] = None  # rollout() does not report contacts
        rows["batch_mean_final_opening"][name] = float(np.mean(states[:, -1, nq]))
        rows["pull_phase_contact_fraction"][name] = float(np.mean(pull_contact))
        rows["pull_phase_final_opening"][name] = float(pull_opening[-1])
    eq_contact = {
        "start_step": start,
        "opening_at_start": float(x0c[o_index]),
        "pull_phase_steps": int(len(pull_U)),
        "planned_opening_after_K": float(motion.planned_opening[start + K]),
        "planned_opening_after_pull_phase": float(motion.planned_opening[start + len(pull_U)]),
        "sabre_failed": int(np.sum(sb.failed)),
        **rows,
    }
    results["batches"]["in contact"]["equivalence"] = eq_contact

    # ---- report --------------------------------------------------------------------------------
    unit = "rad" if scene.object_is_revolute else "m"
    sims = list(mj_models) + ["sabre"]
    print(
        f"sabre {results['sabre_version']} vs MuJoCo {mujoco.__version__}: object '{args.object}', "
        f"N={N} rollouts x K={K} steps (dt={DT} s), {THREADS} threads, per-step states; "
        f"median of {args.repeats} alternating rounds after {args.warmup} warm-up"
    )
    header = f"{'batch':<12} {'simulator':<9} {'ms/batch':>9} {'min':>7} {'max':>7} {'steps/s':>10}"
    print(header)
    print("-" * len(header))
    for bname in batches:
        timing = results["batches"][bname]["timing"]
        for name in sims:
            t = timing[name]
            print(f"{bname:<12} {name:<9} {t['median_ms']:9.2f} {t['min_ms']:7.2f} {t['max_ms']:7.2f} {t['steps_per_s']:10.0f}")
        ratios = [f"sabre/{name} steps/s = {timing[f'ratio_sabre_over_{name}_steps_per_s']:.2f}" for name in mj_models]
        print(f"{'':12} {'; '.join(ratios)}")
    if "MuJoCo+I" in mj_models:
        print("(MuJoCo: velocity servos as specified; MuJoCo+I: plus integral servo actuators, reference only)")
    print()

    col = "".join(f"{name:>10}" for name in sims)
    print(f"equivalence, free motion: |q_sabre - q_MuJoCo| after {K} steps (rad or m), mean / max over the batch")
    for name in mj_models:
        e = eq_free[name]
        print(f"  {name:<9} {e['mean_abs_dq_final']:.2e} / {e['max_abs_dq_final']:.2e}")
    print(f"  sabre contact fraction {eq_free['sabre_contact_fraction']:.2f} (the hand stays clear of the object)")
    print(
        f"equivalence, in contact: from script step {start} (start of the pull phase, hook on the handle, "
        f"opening {eq_contact['opening_at_start']:.3f} {unit})"
    )
    print(f"  {'':38}{col}")
    labels = [
        (f"nominal {K} steps: contact fraction", "nominal_contact_fraction", ""),
        (f"nominal {K} steps: final opening", "nominal_final_opening", unit),
        ("batch: contact fraction", "batch_contact_fraction", ""),
        ("batch: mean final opening", "batch_mean_final_opening", unit),
        (f"pull phase {len(pull_U)} steps: contact fraction", "pull_phase_contact_fraction", ""),
        (f"pull phase {len(pull_U)} steps: final opening", "pull_phase_final_opening", unit),
    ]
    for label, key, u in labels:
        cells = "".join(f"{'n/a':>10}" if eq_contact[key][n] is None else f"{eq_contact[key][n]:10.3f}" for n in sims)
        print(f"  {label:<38}{cells} {u}")
    print(
        f"  (script's planned opening: {eq_contact['planned_opening_after_K']:.3f} {unit} after {K} steps, "
        f"{eq_contact['planned_opening_after_pull_phase']:.3f} {unit} after the pull phase; "
        f"sabre failed rollouts: {eq_contact['sabre_failed']})"
    )

    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=2) + "\n")
    print(f"\nwrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
