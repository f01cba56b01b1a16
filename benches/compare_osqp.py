"""sabre's FILTER-QP next to OSQP (the solver the paper used) on the identical QP.

    python benches/compare_osqp.py [--repeats 300]

The QP is the one `SafetyFilter.filter` solves: 57 ZBF rows (10 joint limits, 3 self-collision
pairs, arm reach, base box x/y, 8 obstacles × 5 robot spheres, passivity) with one slack each, and
the 20 input bounds, exported densely by `SafetyFilter.qp_matrices` as min ½zᵀPz + qᵀz s.t. Az ≤ b.
OSQP gets it once with the union sparsity pattern of all cases and is then updated in place and
warm-started from its previous solution, the way a 1 kHz filter would use it (eps 1e-7, polished).
sabre is called through its public Python API (`SafetyFilter.filter`: input checks, rows,
screening, Clarabel), once with screening (the default) and once solving the full QP every call.

Cases, each a sequence of filter inputs (state, command, τ_ext, tank energy):
- free: the home posture, obstacles clear, a moderate command (no constraint binds);
- binding: the Rust bench's posture (elbow near its limit, base 5 cm from the box edge, an obstacle
  3.5 cm from the hand, the tank 0.1 J above its floor) with a command pressing into all of them,
  repeated (sabre re-solves the remembered active set, OSQP is warm-started);
- binding cold: the same, with sabre's remembered active set dropped before every call (Clarabel
  runs on the rows that can bind);
- inner loop: 500 consecutive 1 kHz inputs of the plant following a reference into joint 4's limit
  with the filter and the tank engaged;
- random: 300 random states near and beyond the limits with random commands and torques.
Calls alternate between the solvers; medians are printed with the ratio and the largest difference
of the filtered commands (they must agree to 1e-4).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import statistics
import sys
import time

import numpy as np
import osqp
import scipy.sparse as sp

import sabre


def make_filter(scene: sabre.Scene, screening: bool) -> sabre.SafetyFilter:
    f = sabre.SafetyFilter(scene, sabre.SafetyConfig(screening=screening))
    f.add_obstacle([2.62, 0.005, 0.885], 0.08)  # in front of the binding posture's hand
    for i in range(7):
        a = i * 0.9
        f.add_obstacle([1.2 * np.cos(a), 1.2 * np.sin(a), 0.3 + 0.15 * i], 0.1)
    return f


def cases(scene: sabre.Scene, rng: np.random.Generator) -> dict[str, list[tuple]]:
    nq = scene.nq
    names = scene.joint_names
    free_x = np.asarray(scene.default_state())
    free_u = np.array([0.1, -0.1, 0.05, 0.2, -0.2, 0.1, 0.1, -0.1, 0.2, 0.1])
    out = {"free": [(free_x, free_u, np.zeros(nq), 10.0)]}

    x = np.asarray(scene.default_state())
    for name, value in (("panda_joint2", -1.6), ("panda_joint4", -2.95), ("panda_joint6", 1.6)):
        x[names.index(name)] = value
    x[0] = 1.95
    u = np.zeros(nq)
    u[0] = 0.8
    u[names.index("panda_joint4")] = -1.5
    u[names.index("panda_joint2")] = -0.8
    u[names.index("panda_joint6")] = 0.5
    tau = np.where(np.arange(nq) < 3, 0.0, -3.0)
    out["binding"] = [(x, u, tau, 2.1)]
    out["binding cold"] = [(x, u, tau, 2.1)]

    # The inner loop: the plant pushed into joint 4's upper limit with filter and tank engaged.
    plant, controller = sabre.Plant(scene), sabre.LowLevelController(scene)
    j4 = names.index("panda_joint4")
    x0 = np.asarray(scene.default_state())
    x0[j4] = scene.q_upper[j4] - 0.2
    plant.reset(x0)
    reference = np.zeros((40, nq))
    reference[:, j4] = 1.2
    reference[:, 3] = 0.3
    tank = sabre.EnergyTank()
    trace = controller.follow(plant, reference, 0.0, 0.015, 500, safety=make_filter(scene, True), tank=tank)
    energies = np.concatenate([[10.0], trace.tank_energy[:-1]])
    states = np.vstack([x0, trace.state[:-1]])
    taus = np.vstack([np.zeros(nq), trace.tau_ext_measured[:-1]])  # what the filter read before each step
    out["inner loop"] = [(states[k], trace.reference[k], taus[k], energies[k]) for k in range(500)]

    lower, upper = np.maximum(scene.q_lower, -6.0), np.minimum(scene.q_upper, 6.0)
    lower[:2], upper[:2] = -2.2, 2.2
    v = make_filter(scene, True).input_limits
    rand = []
    for _ in range(300):
        x = np.asarray(scene.default_state())
        q = rng.uniform(lower, upper)
        near = rng.random(nq) < 0.33
        q[near] = np.where(rng.random(near.sum()) < 0.5, lower[near] + 0.05, upper[near] - 0.05)
        x[:nq] = q
        rand.append((x, rng.uniform(-1.5, 1.5, nq) * v, rng.uniform(-5, 5, nq), rng.uniform(1.5, 10.0)))
    out["random"] = rand
    return out


class OsqpFilter:
    """OSQP on the exported QP, set up once with a fixed pattern, then updated and warm-started."""

    def __init__(self, qps: list[sabre.QPMatrices]) -> None:
        pattern = np.zeros_like(qps[0].A, dtype=bool)
        for qp in qps:
            pattern |= qp.A != 0.0
        # Entries by column, then row: CSC order, so values can be handed to OSQP as they come.
        self.cols, self.rows = np.nonzero(pattern.T)
        first = qps[0]
        self.P = sp.csc_matrix(np.triu(first.P))
        A = sp.csc_matrix((first.A[self.rows, self.cols], (self.rows, self.cols)), shape=first.A.shape)
        assert A.nnz == len(self.rows) and np.array_equal(A.indices, self.rows), "explicit zeros must stay in the pattern"
        self.solver = osqp.OSQP()
        self.solver.setup(
            self.P, first.q, A, np.full(len(first.b), -np.inf), first.b,
            eps_abs=1e-7, eps_rel=1e-7, polishing=True, warm_starting=True, verbose=False, max_iter=20000,
        )
        self.nu = first.nu

    def solve(self, qp: sabre.QPMatrices) -> tuple[np.ndarray, float, str]:
        self.solver.update(q=qp.q, u=qp.b, Ax=qp.A[self.rows, self.cols])
        r = self.solver.solve()
        return r.x[: self.nu], r.info.run_time, r.info.status


@contextlib.contextmanager
def c_stdout_silenced():
    """OSQP's C code prints "Polishing not needed ..." even with verbose=False; send fd 1 away."""
    sys.stdout.flush()
    saved = os.dup(1)
    with open(os.devnull, "w") as null:
        os.dup2(null.fileno(), 1)
        try:
            yield
        finally:
            os.dup2(saved, 1)
            os.close(saved)


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

    print(f"FILTER-QP: {len(screened.row_names)} ZBF rows + {2 * scene.nq} input bounds; "
          f"Clarabel (sabre) vs OSQP {osqp.__version__}")
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
