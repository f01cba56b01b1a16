"""Second engines: the FILTER-QP against OSQP, the rollout model's door against MuJoCo.

The scenes, cases and solver set-ups are the ones the benchmarks time (``support/filter_qp.py``,
``support/mujoco_scene.py``, shared with ``benches/compare_osqp.py`` and ``benches/compare_mujoco.py``),
so the numbers the benchmarks print and what these tests assert come from the same code.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

import sabre
from support import filter_qp
from support.mujoco_scene import TIMESTEP, build_mujoco_model, mujoco_state, mujoco_step_through


@pytest.fixture(scope="module")
def osqp_cases(scene):
    return filter_qp.cases(scene, np.random.default_rng(3))


@pytest.mark.filterwarnings("ignore::PendingDeprecationWarning")  # osqp announces a future default
@pytest.mark.parametrize("screening", [True, False], ids=["screened", "full_qp"])
def test_filter_qp_agrees_with_osqp_within_1e_4_on_every_case(scene, osqp_cases, screening):
    """Clarabel behind SafetyFilter.filter and OSQP (eps 1e-7, polished) on the exported QP give
    the same filtered command within 1e-4 rad/s on the free, binding, inner-loop and random cases."""
    sabre_filter = filter_qp.make_filter(scene, screening)
    exporter = filter_qp.make_filter(scene, True)
    qps = {
        name: [exporter.qp_matrices(x, u, tau_ext=t, tank_energy=s) for x, u, t, s in inputs]
        for name, inputs in osqp_cases.items()
    }
    solver = filter_qp.OsqpFilter([qp for qs in qps.values() for qp in qs])
    worst: dict[str, float] = {}
    binding_rows = 0
    with filter_qp.c_stdout_silenced():
        for name, inputs in osqp_cases.items():
            worst[name] = 0.0
            for (x, u, tau, s), qp in zip(inputs, qps[name]):
                if name == "binding cold":
                    sabre_filter.forget_active_set()
                r = sabre_filter.filter(x, u, tau_ext=tau, tank_energy=s)
                u_osqp, _, status = solver.solve(qp)
                assert status == "solved", f"OSQP: {status} in case {name}"
                worst[name] = max(worst[name], float(np.max(np.abs(u_osqp - r.u))))
                binding_rows += int(np.max(np.abs(r.u - u)) > 1e-6)
    assert max(worst.values()) < 1e-4, worst
    # the comparison must cover commands the filter changes, not only pass-throughs
    assert binding_rows > 50


@pytest.mark.filterwarnings("ignore::PendingDeprecationWarning")
@pytest.mark.parametrize("screening", [True, False], ids=["screened", "full_qp"])
def test_task_metric_filter_agrees_with_osqp(scene, osqp_cases, screening):
    """The FILTER-QP in the task metric (SafetyConfig.task_weight): Clarabel behind SafetyFilter.filter
    and OSQP on the exported QP, whose P now has a dense command block, agree within 1e-3 rad/s
    (the metric's small eigenvalues make both solvers' answers less sharp than the paper's QP)."""
    import osqp
    import scipy.sparse as sp

    config = sabre.SafetyConfig(screening=screening, task_weight=100.0)
    f = sabre.SafetyFilter(scene, config)
    exporter = sabre.SafetyFilter(scene, config)
    for obstacle in filter_qp.make_filter(scene, True).obstacles:
        f.add_obstacle(obstacle.center, obstacle.radius)
        exporter.add_obstacle(obstacle.center, obstacle.radius)
    worst, changed = 0.0, 0
    with filter_qp.c_stdout_silenced():
        for name, inputs in osqp_cases.items():
            for x, u, tau, s in inputs[:40]:
                qp = exporter.qp_matrices(x, u, tau_ext=tau, tank_energy=s)
                assert not np.allclose(qp.P[: qp.nu, : qp.nu], np.diag(np.diag(qp.P[: qp.nu, : qp.nu])))
                solver = osqp.OSQP()
                solver.setup(
                    sp.csc_matrix(np.triu(qp.P)),
                    qp.q,
                    sp.csc_matrix(qp.A),
                    np.full(len(qp.b), -np.inf),
                    qp.b,
                    eps_abs=1e-9,
                    eps_rel=1e-9,
                    polishing=True,
                    verbose=False,
                    max_iter=200000,
                )
                ref = solver.solve()
                assert ref.info.status == "solved", f"OSQP: {ref.info.status} in case {name}"
                r = f.filter(x, u, tau_ext=tau, tank_energy=s)
                worst = max(worst, float(np.max(np.abs(ref.x[: qp.nu] - r.u))))
                changed += int(np.max(np.abs(r.u - u)) > 1e-6)
    assert worst < 1e-3, worst
    assert changed > 30


def scripted_pull(obj: str):
    """sabre's state at the start of the scripted pull (hook on the handle) and the pull's commands."""
    scene = sabre.Scene.load("royalpanda", obj)
    model = sabre.RolloutModel(scene, TIMESTEP)
    motion = sabre.hook_and_pull(scene, dt=TIMESTEP)
    start = int(np.flatnonzero(motion.phases == 3)[0])
    approach = model.rollout(scene.default_state(), motion.U[None, :start], threads=1)
    assert not approach.failed[0]
    x0 = np.array(approach.states[0, -1])
    pull = motion.U[start:][motion.phases[start:] == 3]
    return scene, model, x0, pull, float(motion.planned_opening[start + len(pull)])


@pytest.mark.parametrize(("obj", "tolerance"), [("shelf", 0.05), ("drawer", 0.01)])
def test_scripted_pull_opening_agrees_with_mujoco(obj, tolerance):
    """The opening along the whole scripted pull (333 steps of 15 ms) in sabre's rollout model and
    in MuJoCo's model of the same URDFs with PI velocity servos (the structure of sabre's servo).
    Tolerance: 0.05 rad of a 1.18 rad swing for the shelf door, 1 cm of 41 cm for the drawer; the
    scenes differ in contact model and servo coupling (see support/mujoco_scene.py), not in what
    the pull does to the object."""
    scene, model, x0, pull, planned = scripted_pull(obj)
    opening_sabre = model.rollout(x0, pull[None], threads=1).states[0, 1:, 2 * scene.nq]
    mj = build_mujoco_model(obj, scene, servo_integral=True)
    data = mujoco.MjData(mj)
    state0 = mujoco_state(mj, data, scene, x0)
    opening_mujoco, contact = mujoco_step_through(mj, data, state0, pull, scene.nq)
    # the pull really opens the object in both, to about what the script planned
    assert opening_sabre[-1] > 0.9 * planned and opening_mujoco[-1] > 0.9 * planned
    assert contact.mean() > 0.5
    np.testing.assert_allclose(opening_mujoco, opening_sabre, rtol=0, atol=tolerance)
