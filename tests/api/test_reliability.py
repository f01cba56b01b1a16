"""Inputs that used to crash, hang, diverge silently or escape the exception hierarchy: each now gets
a clear SabreError (or a documented behaviour), checked against what the input means."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import sabre
from sabre import costs
from sabre.errors import InvalidValueError, SabreError, ShapeError, SimulationError

HANG_GUARD = 120  # s: only bounds a wait for a hung child or a condition; nothing asserts on time


@pytest.fixture(scope="module")
def scene():
    return sabre.Scene.load("royalpanda", "shelf")


def small_config(**fields):
    return sabre.ControllerConfig(**{"rollouts": 8, "horizon": 0.15, "threads": 1, **fields})


# Sizes a configuration implies are checked before anything is allocated --------------------------
@pytest.mark.parametrize(
    "fields, named",
    [
        ({"horizon": 1000.0}, "horizon"),
        ({"rollouts": 10**8}, "rollouts"),
        ({"dt": 1e-6}, "horizon"),
        ({"dt": 1e-300}, "horizon"),
        ({"rollouts": 2**62}, "rollouts"),
    ],
)
def test_a_configuration_too_large_to_allocate_is_refused_by_name(scene, fields, named):
    with pytest.raises(InvalidValueError, match=named):
        sabre.Controller(scene, sabre.tasks.OpenObject(), sabre.ControllerConfig(**fields))


def test_a_base_clearance_sampling_too_fine_is_refused_when_compiled(scene):
    with pytest.raises(InvalidValueError, match="spacing"):
        costs.Cost([costs.BaseClearance(spacing=1e-4)]).compile(scene)
    # a fine but sane spacing still compiles
    costs.Cost([costs.BaseClearance(spacing=0.05)]).compile(scene)


# The plant refuses what is outside the model's range ---------------------------------------------
@pytest.mark.parametrize("index, value, joint", [(0, 10.5, "base_x"), (3, 5.0, "panda_joint1")])
def test_a_plant_state_beyond_a_joint_limit_is_refused_naming_the_joint(scene, index, value, joint):
    plant = sabre.Plant(scene)
    x = scene.default_state()
    x[index] = value
    with pytest.raises(InvalidValueError, match=joint):
        plant.reset(x)


def test_a_plant_state_at_the_reset_tolerance_stays_bounded(scene):
    # 0.04 rad beyond panda_joint1's limit (within the tolerance): the limit pushes it back without
    # the integration blowing up.
    plant = sabre.Plant(scene)
    low_level = sabre.LowLevelController(scene)
    x = scene.default_state()
    x[3] = scene.q_upper[3] + 0.04
    plant.reset(x)
    hold = x[: scene.nq].copy()
    for _ in range(300):
        plant.step(low_level.torque(plant.state, np.zeros(scene.nq)))
    assert np.all(np.isfinite(plant.state))
    assert abs(plant.state[scene.nq + 3]) < 5.0  # rad/s: well inside a Panda joint's range
    assert plant.state[3] <= hold[3] + 1e-6  # the limit did not let it go further out


@pytest.mark.parametrize("dt", [0.5, 0.02])
def test_a_plant_step_longer_than_the_stable_range_is_refused(scene, dt):
    with pytest.raises(InvalidValueError, match="dt"):
        sabre.Plant(scene, dt=dt)


def test_coordinates_beyond_the_model_range_are_refused_not_nan(scene):
    q = scene.default_state()[: scene.nq]
    q[3] = 1e155
    for call in (
        lambda: scene.fk(q, "grasp"),
        lambda: scene.jacobian(q, "grasp"),
        lambda: scene.mass_matrix(q),
        lambda: scene.fk_many(q[None, :], "grasp"),
    ):
        with pytest.raises(InvalidValueError, match="range"):
            call()


# Interrupts and time -----------------------------------------------------------------------------
INTERRUPTIBLE = textwrap.dedent(
    """
    import os, signal, sys, threading, time, numpy as np, sabre
    scene = sabre.Scene.load("royalpanda", "shelf")
    x0 = scene.default_state()
    scene.fk(x0[: scene.nq], "grasp")  # the first array argument loads NumPy's C API (Python code)
    what, core_call = sys.argv[1], sys.argv[2]
    caller = []

    def entering(frame, event, arg):
        # called just before each builtin call, with the frame making it
        if event == "c_call" and getattr(arg, "__qualname__", None) == core_call:
            sys.setprofile(None)
            caller.append(frame)

    def report_when_inside():
        # Once the profiler has returned, the main thread runs no Python code until the call returns,
        # its current frame the caller's; in the profiler, the current frame is the profiler's.
        main = threading.main_thread().ident
        while not (caller and sys._current_frames().get(main) is caller[0]):
            time.sleep(0.001)
        os.write(1, b"inside\\n")

    def on_sigint(signum, frame):
        if not caller or frame is not caller[0]:  # Python's handler ran outside the core's check for signals
            os.write(1, f"outside: in {frame and frame.f_code.co_name}\\n".encode())
            os._exit(4)
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, on_sigint)
    threading.Thread(target=report_when_inside, daemon=True).start()
    sys.setprofile(entering)
    try:
        if what == "follow":
            plant = sabre.Plant(scene); plant.reset(x0)
            sabre.LowLevelController(scene).follow(plant, np.zeros((5, scene.nq)), 0.0, 0.015, 10**12, 10**9)
        elif what == "rollout":
            sabre.RolloutModel(scene, dt=0.015).rollout(x0, np.zeros((4000, 2000, scene.nq)), threads=1)
        elif what == "episode":
            c = sabre.Controller(scene, sabre.tasks.OpenObject(), sabre.ControllerConfig(rollouts=8, horizon=0.15))
            sabre.run_episode(scene, c, duration=10**6, replan_rate=1e-6, x0=x0, progress=False)
    except KeyboardInterrupt:
        print("interrupted", flush=True)
        sys.exit(3)
    print("finished", flush=True)
    """
)


@pytest.mark.parametrize(
    "what, core_call",
    [("follow", "Cascade.follow"), ("rollout", "RolloutModel.rollout"), ("episode", "Cascade.follow")],
)
def test_ctrl_c_interrupts_a_long_core_call(what, core_call):
    """SIGINT, sent once the child reports its main thread inside the core's long call, ends the call
    with KeyboardInterrupt, raised by Python's handler from the core's check for signals."""
    child = subprocess.Popen([sys.executable, "-c", INTERRUPTIBLE, what, core_call], stdout=subprocess.PIPE, text=True)
    # a child that never reaches the call (a renamed core call) must fail the test, not hang it
    guard = threading.Timer(HANG_GUARD, child.kill)
    guard.start()
    try:
        line = child.stdout.readline().strip()
        if line == "inside":
            child.send_signal(signal.SIGINT)
        out, _ = child.communicate(timeout=HANG_GUARD)
    finally:
        guard.cancel()
        child.kill()
    assert line == "inside", line
    assert child.returncode == 3 and out.strip() == "interrupted", out


def test_run_episode_simulates_the_duration_asked_for_not_a_whole_plan(scene):
    controller = sabre.Controller(scene, sabre.tasks.OpenObject(), small_config())
    episode = sabre.run_episode(
        scene, controller, duration=0.05, replan_rate=1.0, x0=scene.default_state(), record_every=1, progress=False
    )
    assert episode.time[-1] == pytest.approx(0.05, abs=1e-9)


# Determinism and state ---------------------------------------------------------------------------
def test_a_reset_controller_filters_exactly_like_a_fresh_one(scene):
    # The filter remembers the previous call's active set and tries it first; after reset() the next
    # command must not depend on what was filtered before it (bit-identical to a fresh controller).
    config = small_config(variant="IO")
    used, fresh = (sabre.Controller(scene, sabre.tasks.OpenObject(), config) for _ in range(2))
    x = sabre.paper.paper_start_state(scene)  # base outside its box, arm near its limits: rows bind
    rng = np.random.default_rng(0)
    for _ in range(20):
        before, after = rng.uniform(-1.0, 1.0, (2, scene.nq))
        x_next = x.copy()
        x_next[: scene.nq] += rng.uniform(-0.01, 0.01, scene.nq)
        used.inner_filter.filter(x, before)
        used.reset()
        fresh.reset()
        np.testing.assert_array_equal(used.inner_filter.filter(x_next, after).u, fresh.inner_filter.filter(x_next, after).u)


# Every error a SabreError ------------------------------------------------------------------------
def test_realtime_cascade_refuses_bad_timing_and_ticks_after_stop(scene):
    controller = sabre.Controller(scene, sabre.tasks.OpenObject(), small_config())
    with pytest.raises(InvalidValueError, match="min_replan_period"):
        sabre.RealtimeCascade(controller, min_replan_period=float("inf"))
    cascade = sabre.RealtimeCascade(controller, min_replan_period=0.01)
    x0 = scene.default_state()
    cascade.start(x0)
    tau = np.zeros(scene.nq)
    with pytest.raises(InvalidValueError, match="t"):
        cascade.tick(x0, tau, float("nan"))
    cascade.tick(x0, tau, 0.001)
    cascade.stop()
    with pytest.raises(InvalidValueError, match="stopped"):
        cascade.tick(x0, tau, 0.002)


@pytest.mark.parametrize(
    "call, error",
    [
        (lambda s: s.fk_many([s.default_state()[: s.nq], [0.0, 1.0]], "grasp"), ShapeError),
        (lambda s: sabre.ControllerConfig(seed=2**64), InvalidValueError),
        (lambda s: sabre.EnergyTank(initial=None), InvalidValueError),
        (lambda s: sabre.EnergyTank(initial=10.0, floor="1"), InvalidValueError),
        (lambda s: sabre.EnergyTank(initial=1j), InvalidValueError),
        (lambda s: sabre.SafetyFilter(s, sabre.SafetyConfig()).move_obstacle(2**64, [0.0, 0.0, 1.0]), InvalidValueError),
    ],
    ids=["ragged fk_many", "seed 2**64", "tank None", "tank floor str", "tank complex", "obstacle id 2**64"],
)
def test_bad_values_raise_sabre_errors(scene, call, error):
    with pytest.raises(error) as raised:
        call(scene)
    assert isinstance(raised.value, SabreError)


# Resources ---------------------------------------------------------------------------------------
def _rollout_workers() -> int:
    """The process's rollout pool workers (the core names them sabre-rollout-<i>)."""
    names = []
    for tid in os.listdir("/proc/self/task"):
        try:
            with open(f"/proc/self/task/{tid}/comm") as comm:
                names.append(comm.read().strip())
        except OSError:  # the thread ended meanwhile (no such file, or no such process on reading)
            pass
    return sum(name.startswith("sabre-rollout-") for name in names)


@pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="counts threads through /proc")
def test_rollouts_with_many_thread_counts_keep_only_the_two_most_recent_pools(scene):
    """A batch of 32 rollouts on n threads runs one slot on the caller and n - 1 on a pool; of the
    pools of 1 to 31 workers started here, the two most recent (31 and 30 workers) stay and the
    others' workers exit. They exit asynchronously: the count is polled until it settles, within a
    deadline."""
    model = sabre.RolloutModel(scene, dt=0.015)
    x0 = scene.default_state()
    U = np.zeros((32, 2, scene.nq))
    for threads in range(2, 33):
        model.rollout(x0, U, threads=threads)
    kept = (32 - 1) + (31 - 1)
    deadline = time.monotonic() + HANG_GUARD
    while (workers := _rollout_workers()) != kept and time.monotonic() < deadline:
        time.sleep(0.01)
    assert workers == kept, f"{workers} rollout workers alive, expected the two most recent pools' {kept}"


@pytest.mark.skipif(not os.path.exists("/proc/self/status"), reason="reads the address space's size from /proc")
def test_a_failure_the_core_reports_is_a_simulation_error_caught_as_a_sabre_error(scene):
    """Rollouts whose outputs cannot be allocated (2 GiB of states, in a child allowed 1 GiB more
    address space than it has) fail in the core; the error arrives as a SimulationError that
    ``except sabre.SabreError`` and ``except RuntimeError`` both catch, saying what it could not
    allocate."""
    script = textwrap.dedent(
        """
        import resource, numpy as np, sabre
        scene = sabre.Scene.load("royalpanda", "shelf")
        with open("/proc/self/status") as status:
            size = next(int(line.split()[1]) * 1024 for line in status if line.startswith("VmSize:"))
        resource.setrlimit(resource.RLIMIT_AS, (size + 2**30, size + 2**30))
        n = 2**28 // scene.nx  # states of n rollouts of 0 steps: 2**28 values, the most a batch may have
        try:
            sabre.RolloutModel(scene).rollout(scene.default_state(), np.zeros((n, 0, scene.nu)), threads=1)
        except sabre.SabreError as e:
            print(type(e).__name__, isinstance(e, RuntimeError), e)
        """
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=HANG_GUARD)
    assert out.returncode == 0, out.stderr[-2000:]
    name, runtime, message = out.stdout.strip().split(" ", 2)
    assert (name, runtime) == (SimulationError.__name__, "True"), out.stdout
    assert f"cannot allocate {2**28 // scene.nx * scene.nx} values" in message and "rollout outputs" in message, message


# Validated at construction ------------------------------------------------------------------------
def _pose(**change):
    pose = np.eye(4)
    for key, value in change.items():
        pose[tuple(int(c) for c in key[1:])] = value
    return pose


@pytest.mark.parametrize(
    "pose, says",
    [
        (_pose(m30=0.1), "bottom row"),
        (_pose(m33=2.0), "bottom row"),
        (_pose(m00=2.0), "rotation"),
        (np.diag([1.0, 1.0, -1.0, 1.0]), "rotation"),
    ],
    ids=["shear row", "scaled w", "scaled axis", "reflection"],
)
def test_a_pose_that_is_not_a_rigid_transform_is_refused_when_the_term_is_made(pose, says):
    with pytest.raises(InvalidValueError, match=says):
        costs.TargetPose(pose)
    with pytest.raises(InvalidValueError, match=says):
        sabre.tasks.Reach(target_pose=pose)


def test_a_rotated_translated_pose_is_accepted():
    c, s = np.cos(0.3), np.sin(0.3)
    pose = np.array([[c, -s, 0.0, 1.0], [s, c, 0.0, 2.0], [0.0, 0.0, 1.0, 0.5], [0.0, 0.0, 0.0, 1.0]])
    np.testing.assert_array_equal(costs.TargetPose(pose).target, pose)


@pytest.mark.parametrize(
    "make",
    [
        lambda: costs.JointLimits(lower=[0.0, 1.0], upper=[1.0, 0.5]),
        lambda: costs.BaseBox(lower=(1.0, -1.0), upper=(0.0, 1.0)),
        lambda: costs.Obstacles(centers=[[0.0, 0.0, 1.0]], radii=[-0.1]),
    ],
    ids=["joint limits inverted", "base box inverted", "negative radius"],
)
def test_inverted_bounds_and_negative_radii_are_refused_when_the_term_is_made(make):
    with pytest.raises(InvalidValueError):
        make()


def _batch_term(values):
    return costs.PythonTerm(lambda batch: values(batch.states.shape[0]))


def _iterate_with(scene, term):
    task = sabre.tasks.Reach(target_pose=scene.fk(scene.default_state()[: scene.nq], "grasp"), extra=costs.Cost([term]))
    controller = sabre.Controller(scene, task, small_config())
    return controller.update(scene.default_state(), 0.0)


def test_complex_costs_from_a_python_term_are_refused_not_truncated(scene):
    with pytest.raises(InvalidValueError, match="dtype"):
        _iterate_with(scene, _batch_term(lambda n: np.ones(n) + 1j))


def test_nan_costs_from_a_python_term_warn_and_weigh_zero(scene):
    with pytest.warns(RuntimeWarning, match="NaN"):
        _iterate_with(scene, _batch_term(lambda n: np.where(np.arange(n) == 3, np.nan, 1.0)))


def test_open_object_fields_that_cannot_work_on_the_scene_fail_when_the_controller_is_built(scene):
    for task in (
        sabre.tasks.OpenObject(opening=5.0),
        sabre.tasks.OpenObject(approach=sabre.tasks.ApproachConfig(posture=(0.0, 1.0))),
    ):
        with pytest.raises(InvalidValueError):
            sabre.Controller(scene, task, small_config())


@pytest.mark.parametrize("mapping", ["naive", "baseline", "invariant"])
@pytest.mark.parametrize("parameter", [-5.0, 0.0, float("nan"), float("inf")])
def test_likelihood_weights_refuse_a_parameter_that_is_not_positive(mapping, parameter):
    with pytest.raises(InvalidValueError):
        sabre.paper.likelihood_weights([1.0, 2.0, 3.0], mapping, parameter)


def test_invariant_weights_of_costs_whose_span_overflows_match_the_scaled_problem():
    # (55) is invariant to the cost scale: costs spanning ±1e308 weigh like the same costs / 1e308.
    huge = np.array([1e308, 0.0, -1e308, 5e307])
    np.testing.assert_allclose(
        sabre.paper.likelihood_weights(huge, "invariant", 10.0),
        sabre.paper.likelihood_weights(huge / 1e308, "invariant", 10.0),
        rtol=1e-12,
    )


def test_complex_costs_are_refused_by_likelihood_weights():
    with pytest.raises(ShapeError):
        sabre.paper.likelihood_weights(np.array([1.0 + 1j, 2.0]), "invariant", 10.0)


def test_open_object_on_a_scene_without_its_frames_or_with_swapped_files_fails_when_the_controller_is_built():
    assets = Path(__file__).resolve().parents[2] / "assets"
    robot_urdf = (assets / "robots" / "royalpanda.urdf").read_text()
    shelf_urdf = (assets / "objects" / "shelf.urdf").read_text()
    swapped = sabre.Scene.from_urdf_strings(shelf_urdf, robot_urdf)
    with pytest.raises(InvalidValueError, match="swapped"):
        sabre.Controller(swapped, sabre.tasks.OpenObject(), small_config())
    no_handle = sabre.Scene.from_urdf_strings(robot_urdf, shelf_urdf.replace("handle_frame", "knob"))
    with pytest.raises(sabre.errors.UnknownFrameError, match=r"handle_frame.*knob"):
        sabre.Controller(no_handle, sabre.tasks.OpenObject(), small_config())


def test_plant_push_adds_to_the_joint_velocities_and_keeps_time(scene):
    plant = sabre.Plant(scene)
    plant.reset(scene.default_state())
    for _ in range(10):
        plant.step(np.zeros(scene.nq))
    before, t = plant.state.copy(), plant.time
    dv = np.zeros(scene.nq + scene.no)
    dv[4], dv[-1] = 0.3, 0.2
    plant.push(dv)
    after = plant.state
    assert plant.time == t
    np.testing.assert_allclose(after[scene.nq + 4] - before[scene.nq + 4], 0.3, atol=1e-12)
    np.testing.assert_allclose(after[-1] - before[-1], 0.2, atol=1e-12)
    np.testing.assert_array_equal(after[: scene.nq], before[: scene.nq])
    with pytest.raises(InvalidValueError, match="moves at"):
        plant.push(np.full(scene.nq + scene.no, 1e3))


def test_a_tank_step_whose_energy_overflows_is_refused_and_leaves_the_tank_unchanged():
    # found by the fuzz test: each input finite, their product not
    tank = sabre.EnergyTank(initial=0.0, floor=0.0)
    tau = np.zeros(10)
    tau[0] = 1e200
    with pytest.raises(InvalidValueError, match="overflows"):
        tank.step(tau, np.ones(10), 1e200)
    assert tank.energy == 0.0
    assert tank.step(tau, np.ones(10), 1e-200) == pytest.approx(1.0)
