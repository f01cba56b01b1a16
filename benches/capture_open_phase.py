"""Writes benches/data/shelf_open_phase.json: one planning iteration of the closed loop in the open phase.

    python benches/capture_open_phase.py [--seed 0] [--at 12.8]

Runs the shelf episode of `make demo` (paper start, seed 0, Table I defaults) re-planned at 20 Hz
(the demo itself re-plans at 50 Hz) and records,
at the first re-plan in the open phase at or after `--at` seconds, what the controller's next
iteration starts from: the measured state, the nominal sequence and its start time, the task's
noise scale and guides, and the open-phase cost's parameters. The criterion bench
(`cargo bench --bench planning`, case `open_phase`) replays exactly that iteration, so it times
what the robot's planner does while it pulls the door, not a hand-picked contact state.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

import sabre


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--at", type=float, default=12.8, help="earliest time (s) of the captured re-plan")
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "data" / "shelf_open_phase.json")
    args = parser.parse_args(argv)

    scene = sabre.Scene.load(obj="shelf")
    task = sabre.tasks.OpenObject()
    config = sabre.ControllerConfig(seed=args.seed)
    controller = sabre.Controller(scene, task, config)
    captured: dict = {}

    def capture(t: float, x: np.ndarray, plant: sabre.Plant, ctl: sabre.Controller) -> bool | None:
        if t < args.at or ctl.phase != "open":
            return None
        guides = task.guides(scene, x, "open", config.horizon_steps, config.dt)
        offset = task.grasp_offset(scene, "open")
        clearance = sabre.costs.BaseClearance(task.safety.base_link)  # the margin and spacing SafetyWeights uses
        captured.update(
            note=f"shelf, seed {args.seed}: the closed loop's re-plan at t = {t:.3f} s in the open phase "
            "(benches/capture_open_phase.py); the next iteration starts from x0 with this nominal",
            object="shelf",
            t=t,
            x0=x.tolist(),
            nominal=ctl.nominal.tolist(),
            nominal_t0=ctl.nominal_t0,
            noise_scale=float(task.noise_scale(scene, x, "open")),
            guides=[] if guides is None else np.asarray(guides)[: config.rollouts - 2].tolist(),
            grasp_offset=np.asarray(offset).tolist(),
            pose_weights=list(task.open.pose_weights),
            object_target=[float(task.object_setpoint(scene))],
            object_weight=task.open.object_weight,
            lead=task.lead(scene),
            lead_limit=task.target_opening(scene),
            safety=dataclasses.asdict(task.safety),
            base_clearance_margin=clearance.margin,
            base_clearance_spacing=clearance.spacing,
        )
        return True

    sabre.run_episode(scene, controller, 30.0, seed=args.seed, progress=False, on_replan=capture, stop_on_success=True)
    if not captured:
        print(f"no re-plan in the open phase at or after {args.at} s", file=sys.stderr)
        return 1
    args.out.write_text(json.dumps(captured) + "\n")
    print(f"wrote {args.out} (t = {captured['t']:.3f} s, {len(captured['guides'])} guides)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
