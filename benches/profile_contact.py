"""A steady in-contact planning loop to profile with `perf` (the breakdown in docs/results.md).

    perf record -e cpu-clock -F 999 -g -o /tmp/contact.perf -- .venv/bin/python benches/profile_contact.py --iterations 300
    .venv/bin/python benches/perf_breakdown.py /tmp/contact.perf

Repeats `Controller.update` from the hooked shelf state in the open phase (N = 40 unless
--rollouts says otherwise, K = 67, 2 threads), the iteration that benches/compare_planning.py
times against `mujoco.rollout`; --contact-model rapier profiles the reference path.
"""

from __future__ import annotations

import argparse
import sys
import time

import sabre
from compare_planning import hooked_state  # a sibling script: Python puts the script's folder on sys.path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--iterations", type=int, default=300)
    parser.add_argument("--object", default="shelf", choices=sabre.OBJECTS)
    parser.add_argument("--contact-model", default="reduced", choices=sabre.CONTACT_MODELS)
    parser.add_argument("--rollouts", type=int, default=40, help="samples per iteration (N)")
    args = parser.parse_args(argv)
    scene = sabre.Scene.load(obj=args.object)
    config = sabre.ControllerConfig(seed=0, threads=2, rollouts=args.rollouts, contact_model=args.contact_model)
    controller = sabre.Controller(scene, sabre.tasks.OpenObject(), config)
    controller.set_phase("open")
    x = hooked_state(scene)
    started = time.perf_counter()
    engine = rollout = 0.0
    for i in range(args.iterations):
        controller.update(x, 0.01 * (i + 1))
        engine += controller.stats.engine_time
        rollout += controller.stats.rollout_time
    wall = time.perf_counter() - started
    print(
        f"{args.iterations} in-contact iterations: {1e3 * wall / args.iterations:.2f} ms each; "
        f"contact step {100 * engine / (2 * rollout):.0f} % of the workers' rollout time"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
