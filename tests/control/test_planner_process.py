"""The real-time cascade with its planner in a process of its own (RealtimeCascade(planner_process=...))."""

from __future__ import annotations

import functools
import os

import numpy as np
import planner_factories
import pytest

import sabre


def test_first_plan_from_the_process_equals_the_same_controllers_plan_in_this_process():
    """The process builds its controller with the factory and plans from the shared x0 at t0: the
    same seed gives the plan Controller.update gives here, to rounding."""
    factory = functools.partial(planner_factories.open_shelf, "IO", 3)
    reference = factory()
    x0 = sabre.paper.paper_start_state(reference.scene)
    reference.reset(t0=0.25)
    reference.update(x0, 0.25)
    cascade = sabre.RealtimeCascade(factory(), planner_process=factory, min_replan_period=10.0)
    with cascade.start(x0, t0=0.25):
        assert cascade.planner_in_process and cascade.running and cascade.iterations == 1
        assert cascade.plan_start == pytest.approx(reference.nominal_t0)
        assert cascade.phase == reference.phase
        np.testing.assert_allclose(cascade.reference(cascade.plan_start), reference.nominal[0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(
            cascade.reference(cascade.plan_start + 2 * reference.config.dt), reference.nominal[2], rtol=0, atol=1e-12
        )
        # The process hands over the plan as the snapshot the controller makes in-process.
        handed, made = cascade.current_plan, reference.snapshot()
        assert isinstance(handed, sabre.PlanSnapshot)
        assert (handed.phase, handed.iterations, handed.gain_inertia_floor) == (made.phase, 1, made.gain_inertia_floor)
        assert handed.nominal_cost == pytest.approx(made.nominal_cost, rel=1e-12)
        np.testing.assert_allclose(handed.nominal, made.nominal, rtol=0, atol=1e-12)
        np.testing.assert_allclose(handed.predicted, made.predicted, rtol=0, atol=1e-9)
    assert not cascade.running


def test_process_planner_replans_on_the_states_the_inner_loop_shares():
    """The inner loop drives the plant at 1 kHz while plans arrive from the process; every tick's
    command is finite and inside the limits, and the plans start at the times of shared states."""
    factory = functools.partial(planner_factories.open_shelf, "IO", 5)
    controller = factory()
    scene = controller.scene
    plant = sabre.Plant(scene)
    low = sabre.LowLevelController(scene, dt=plant.dt)
    x0 = scene.default_state()
    plant.reset(x0)
    starts = set()
    with sabre.RealtimeCascade(controller, low_level=low, inner_dt=plant.dt, planner_process=factory).start(x0) as rt:
        ticks = 0
        while ticks < 300 or rt.iterations < 4:
            r = rt.tick(plant.state, plant.measured_tau_ext, plant.time)
            assert np.all(np.isfinite(r.command)) and np.all(np.abs(r.command) <= scene.dq_limit + 1e-9)
            assert r.torque is not None and np.all(np.isfinite(r.torque))
            plant.step(r.torque)
            starts.add(rt.plan_start)
            ticks += 1
            assert ticks < 200_000, "the planner process delivered no plans"
        assert np.isfinite(rt.iteration_time) and rt.iteration_time > 0.0
    assert not rt.running
    assert len(starts) >= 3
    # each plan starts at a time the inner loop ticked at (a state it shared), on the plant's 1 ms grid
    assert all(abs(s * 1000.0 - round(s * 1000.0)) < 1e-6 for s in starts)
    with pytest.raises(sabre.InvalidValueError, match="stopped"):
        rt.tick(plant.state, plant.measured_tau_ext, plant.time)


def test_obstacle_changes_reach_the_planner_process_and_its_failures_reach_the_inner_loop():
    """An obstacle added through the cascade before start and one added while running both reach
    the process's controller: removing them there succeeds. Removing an id the process never had
    fails in the process, and the next tick raises PlannerError (a SabreError) with its cause."""
    factory = functools.partial(planner_factories.open_shelf, "IO", 1)
    controller = factory()
    x0 = controller.scene.default_state()
    rt = sabre.RealtimeCascade(controller, planner_process=factory)
    before = rt.add_obstacle([2.0, 2.0, 1.0], 0.1)
    with rt.start(x0):
        during = rt.add_obstacle([2.0, -2.0, 1.0], 0.1)
        assert (before, during) == (0, 1)
        rt.remove_obstacle(before)
        rt.remove_obstacle(during)
        seen = rt.iterations
        t = 0.0
        while rt.iterations < seen + 3:  # the process has run both removals and planned again
            t += 0.001
            rt.tick(x0, np.zeros(controller.scene.nq), t)
        assert [o.id for f in controller.filters for o in f.obstacles] == []
        rt._forward("remove_obstacle", 7)  # an id only the process is told about
        with pytest.raises(sabre.PlannerError, match="obstacle"):
            for _ in range(200_000):
                t += 0.001
                rt.tick(x0, np.zeros(controller.scene.nq), t)


def test_a_factory_that_fails_is_a_planner_error_at_start_not_a_hang():
    factory = planner_factories.open_shelf
    controller = factory()
    rt = sabre.RealtimeCascade(controller, planner_process=planner_factories.broken)
    with pytest.raises(sabre.PlannerError, match="cannot build"):
        rt.start(controller.scene.default_state())
    assert not rt.running
    with pytest.raises(sabre.InvalidValueError):
        sabre.RealtimeCascade(controller, planner_process=42)  # type: ignore[arg-type]
    rt = sabre.RealtimeCascade(controller, planner_process=lambda: factory())
    with pytest.raises(sabre.PlannerError, match="picklable"):
        rt.start(controller.scene.default_state())
    assert not rt.running


def test_start_without_waiting_is_ready_once_the_first_plan_arrives():
    """start(wait=False) returns at once; until the first plan, ticking raises and observe() is the
    way to hand states over; then the cascade ticks as usual."""
    factory = functools.partial(planner_factories.open_shelf, "N", 2)
    controller = factory()
    x0 = controller.scene.default_state()
    tau = np.zeros(controller.scene.nq)
    with sabre.RealtimeCascade(controller, planner_process=factory).start(x0, wait=False) as rt:
        assert rt.running
        if not rt.ready:
            with pytest.raises(sabre.InvalidValueError, match="no plan yet"):
                rt.tick(x0, tau, 0.0)
        t = 0.0
        while not rt.ready:
            t += 0.001
            rt.observe(x0, t)
            assert t < 600.0, "no first plan"
        r = rt.tick(x0, tau, t)
        assert np.all(np.isfinite(r.command)) and rt.iterations >= 1


_ORPHAN = """
import functools, multiprocessing, sys, time
sys.path.insert(0, {here!r})
import planner_factories, sabre
if __name__ == "__main__":
    factory = functools.partial(planner_factories.open_shelf, "N", 0)
    controller = factory()
    rt = sabre.RealtimeCascade(controller, planner_process=factory).start(controller.scene.default_state())
    print(*[p.pid for p in multiprocessing.active_children() if p.name == "sabre-planner"], flush=True)
    time.sleep(600)
"""


def test_planner_process_ends_when_its_parent_is_killed(tmp_path):
    """A parent killed outright (SIGKILL: no clean-up runs) leaves no planner behind."""
    import os
    import subprocess
    import sys
    import time

    script = tmp_path / "orphan.py"
    script.write_text(_ORPHAN.format(here=os.path.dirname(__file__)))
    parent = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    try:
        line = parent.stdout.readline()
        planner = int(line.split()[0])
        os.kill(planner, 0)  # alive while its parent is
    finally:
        parent.kill()
        parent.wait()
    deadline = time.monotonic() + 60.0
    while time.monotonic() < deadline:
        try:
            os.kill(planner, 0)
        except ProcessLookupError:
            return
        try:  # reap it if it became our child's orphan under us (it is re-parented to init, not us)
            os.waitpid(planner, os.WNOHANG)
        except ChildProcessError:
            pass
        time.sleep(0.05)
    os.kill(planner, 9)
    raise AssertionError("the planner process outlived its killed parent")


@pytest.mark.skipif(not hasattr(os, "SCHED_IDLE"), reason="SCHED_IDLE is Linux's")
@pytest.mark.parametrize("idle", [True, False])
def test_the_planner_process_runs_niced_and_under_sched_idle_when_asked(idle):
    """planner_nice adds niceness to the process and planner_idle puts it under SCHED_IDLE, as the
    OS reports for its main thread; the id is gone once the cascade stops."""
    factory = functools.partial(planner_factories.open_shelf, "IO", 3)
    cascade = sabre.RealtimeCascade(factory(), planner_process=factory, min_replan_period=10.0, planner_nice=7, planner_idle=idle)
    x0 = sabre.paper.paper_start_state(cascade.controller.scene)
    assert cascade.planner_pid is None
    with cascade.start(x0):
        pid = cascade.planner_pid
        assert pid is not None and pid != os.getpid()
        assert os.sched_getscheduler(pid) == (os.SCHED_IDLE if idle else os.SCHED_OTHER)
        assert os.getpriority(os.PRIO_PROCESS, pid) == os.getpriority(os.PRIO_PROCESS, 0) + 7
    assert cascade.planner_pid is None


@pytest.mark.parametrize("user_setting", [None, "2"])
def test_the_planner_process_runs_single_threaded_blas_unless_the_user_chose(monkeypatch, user_setting):
    """The planner process starts with OPENBLAS_NUM_THREADS=1 (as the OS shows its environment),
    a value the user set is passed on as it is, and this process's environment is left as it was."""
    if user_setting is None:
        monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    else:
        monkeypatch.setenv("OPENBLAS_NUM_THREADS", user_setting)
    factory = functools.partial(planner_factories.open_shelf, "IO", 3)
    cascade = sabre.RealtimeCascade(factory(), planner_process=factory, min_replan_period=10.0)
    with cascade.start(sabre.paper.paper_start_state(cascade.controller.scene)):
        with open(f"/proc/{cascade.planner_pid}/environ", "rb") as f:
            environ = dict(item.split(b"=", 1) for item in f.read().split(b"\0") if b"=" in item)
    assert environ[b"OPENBLAS_NUM_THREADS"] == (user_setting or "1").encode()
    assert os.environ.get("OPENBLAS_NUM_THREADS") == user_setting


def test_a_plan_read_that_overlaps_a_write_is_skipped_not_waited_for():
    """The inner loop's read tries once: on a block whose counter is odd (a write under way) it
    returns nothing at once; the planner's read retries; a completed write reads back whole."""
    from sabre.planner_process import _read, _write

    block = np.zeros(6)
    _write(block, [(1, [1.0, 2.0]), (3, np.array([3.0, 4.0, 5.0]))])
    read = _read(block, tries=1)
    assert read is not None and read[0] == 2.0
    np.testing.assert_array_equal(read[1], [2.0, 1.0, 2.0, 3.0, 4.0, 5.0])
    block[0] += 1.0  # a writer stopped midway
    assert _read(block, tries=1) is None
    assert _read(block, tries=3) is None
