"""The FILTER-QP's test inputs and OSQP set up on the identical QP: what benches/compare_osqp.py times and
tests/sim/test_second_engines.py checks for agreement.

The QP is the one `SafetyFilter.filter` solves: 57 ZBF rows (10 joint limits, 3 self-collision
pairs, arm reach, base box x/y, 8 obstacles × 5 robot spheres, passivity) with one slack each, and
the 20 input bounds, exported densely by `SafetyFilter.qp_matrices` as min ½zᵀPz + qᵀz s.t. Az ≤ b.
`OsqpFilter` gives OSQP the union sparsity pattern of all cases once and then updates it in place,
warm-started from its previous solution, the way a 1 kHz filter would use it (eps 1e-7, polished).

`cases(scene, rng)`: each a sequence of filter inputs (state, command, τ_ext, tank energy):
- free: the home posture, obstacles clear, a moderate command (no constraint binds);
- binding: the Rust bench's posture (elbow near its limit, base 5 cm from the box edge, an obstacle
  3.5 cm from the hand, the tank 0.1 J above its floor) with a command pressing into all of them,
  repeated (sabre re-solves the remembered active set, OSQP is warm-started);
- binding cold: the same, with sabre's remembered active set dropped before every call (Clarabel
  runs on the rows that can bind);
- inner loop: 500 consecutive 1 kHz inputs of the plant following a reference into joint 4's limit
  with the filter and the tank engaged;
- random: 300 random states near and beyond the limits with random commands and torques.
"""

from __future__ import annotations

import contextlib
import os
import sys

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
            self.P,
            first.q,
            A,
            np.full(len(first.b), -np.inf),
            first.b,
            eps_abs=1e-7,
            eps_rel=1e-7,
            polishing=True,
            warm_starting=True,
            verbose=False,
            max_iter=20000,
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
