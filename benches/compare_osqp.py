"""sabre's FILTER-QP next to OSQP (the solver the paper used) on the identical QP.

    .venv/bin/python benches/compare_osqp.py [--repeats 300]

The QP, the cases (free, binding, binding cold, inner loop, random) and OSQP's set-up (one sparsity
pattern, updated in place, warm-started, eps 1e-7, polished) are support/filter_qp.py's. sabre is
called through its public Python API (`SafetyFilter.filter`: input checks, rows, screening,
Clarabel), once with screening (the default) and once solving the full QP every call.
Calls alternate between the solvers; medians are printed with the ratio and the largest difference
of the filtered commands (they must agree to 1e-4).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import osqp

import sabre

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root, for support/
from support.filter_qp import OsqpFilter, c_stdout_silenced, cases, make_filter


def median_us(values: list[float]) -> float:
    return 1e6 * statistics.median(values)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=300, help="calls per single-state case")
    args = parser.parse_args()
    scene = sabre.Scene.load("royalpanda", "shelf")
    rng = np.random.default_rng(3)
    all_cases = cases(scene, rng)
    screened, full = make_filter(scene, True), make_filter(scene, False)
    qps = {
        name: [screened.qp_matrices(x, u, tau_ext=t, tank_energy=s) for x, u, t, s in inputs]
        for name, inputs in all_cases.items()
    }
    solver = OsqpFilter([qp for qs in qps.values() for qp in qs])

    print(
        f"FILTER-QP: {len(screened.row_names)} ZBF rows + {2 * scene.nq} input bounds; "
        f"Clarabel (sabre) vs OSQP {osqp.__version__}"
    )
    header = (
        f"{'case':<12} {'calls':>5} {'sabre':>9} {'(core)':>8} {'sabre full':>10} {'OSQP':>9} {'(OSQP)':>8} "
        f"{'OSQP/sabre':>10} {'OSQP/full':>9} {'max |du|':>9} {'rows':>5}"
    )
    lines, failures = [], []
    with c_stdout_silenced():
        for name, inputs in all_cases.items():
            repeats = args.repeats if len(inputs) == 1 else 1
            t_s, t_core, t_f, t_o, t_oi, du, rows = [], [], [], [], [], 0.0, []
            for _ in range(repeats):
                for (x, u, tau, s), qp in zip(inputs, qps[name]):
                    if name == "binding cold":
                        screened.forget_active_set()
                    t = time.perf_counter()
                    r = screened.filter(x, u, tau_ext=tau, tank_energy=s)
                    t_s.append(time.perf_counter() - t)
                    t_core.append(r.solve_time)
                    rows.append(r.qp_rows)
                    t = time.perf_counter()
                    full.filter(x, u, tau_ext=tau, tank_energy=s)
                    t_f.append(time.perf_counter() - t)
                    t = time.perf_counter()
                    u_osqp, internal, status = solver.solve(qp)
                    t_o.append(time.perf_counter() - t)
                    t_oi.append(internal)
                    if status != "solved":
                        failures.append(f"OSQP: {status} in case {name}")
                    du = max(du, float(np.max(np.abs(u_osqp - r.u))))
            osqp_median = statistics.median(t_o)
            lines.append(
                f"{name:<12} {len(t_s):>5} {median_us(t_s):>7.1f}µs {median_us(t_core):>6.1f}µs {median_us(t_f):>8.1f}µs "
                f"{median_us(t_o):>7.1f}µs {median_us(t_oi):>6.1f}µs {osqp_median / statistics.median(t_s):>9.2f}× "
                f"{osqp_median / statistics.median(t_f):>8.2f}× {du:>9.1e} {statistics.median(rows):>5.0f}"
            )
            if du > 1e-4:
                failures.append(f"case {name}: sabre and OSQP disagree by {du:.2e} > 1e-4")
    print(header)
    print("-" * len(header))
    print("\n".join(lines))
    if failures:
        raise SystemExit("\n".join(failures))
    print(
        "\nsabre: SafetyFilter.filter from Python (median wall time; core = the Rust call alone); sabre full: the same\n"
        "with screening off (Clarabel on all 57 rows); OSQP: update + warm-started solve from Python (OSQP's own run\n"
        "time in parentheses); rows: rows in sabre's QP (0: the projected command met every row)."
    )


if __name__ == "__main__":
    main()
