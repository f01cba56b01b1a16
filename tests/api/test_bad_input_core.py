"""Bad input never crashes, past the wrappers: URDF files and strings that are not descriptions sabre
can use, every entry point of the compiled module called directly, and garbage thrown at all of it
in a child interpreter, which must end with an exception and never abort."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from bad_input_support import ROBOT_PATH, SHELF_PATH, check, make_objs

import sabre
from sabre import _core
from sabre.errors import InvalidValueError, SabreError, ShapeError, UnknownAssetError, UrdfError


@pytest.fixture(scope="module")
def objs():
    return make_objs()


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


SHELF = SHELF_PATH.read_text()
URDF_FILE_CASES = {
    "missing robot": lambda t: (t / "nope.urdf", SHELF_PATH),
    "missing object": lambda t: (ROBOT_PATH, t / "nope.urdf"),
    "directory": lambda t: (t, SHELF_PATH),
    "empty file": lambda t: (ROBOT_PATH, _write(t, "empty.urdf", "")),
    "malformed xml": lambda t: (ROBOT_PATH, _write(t, "bad.urdf", SHELF[: len(SHELF) // 2])),
    "not xml": lambda t: (_write(t, "bad.urdf", "robot: royalpanda\n"), SHELF_PATH),
    "binary garbage": lambda t: (ROBOT_PATH, _write(t, "bin.urdf", "\x00\x01\x02<robot>\x00")),
    "mesh geometry": lambda t: (
        ROBOT_PATH,
        # the door's <visual> and <collision> share the box: replace both (the collision is what matters)
        _write(t, "mesh.urdf", SHELF.replace('<box size="0.016 0.295 0.9"/>', '<mesh filename="package://shelf/door.stl"/>')),
    ),
    "floating joint": lambda t: (ROBOT_PATH, _write(t, "floating.urdf", SHELF.replace('type="revolute"', 'type="floating"'))),
    "planar joint": lambda t: (ROBOT_PATH, _write(t, "planar.urdf", SHELF.replace('type="revolute"', 'type="planar"'))),
    "joint to unknown link": lambda t: (
        ROBOT_PATH,
        _write(t, "link.urdf", SHELF.replace('<child link="door"/>', '<child link="dooor"/>')),
    ),
    "no movable joint": lambda t: (ROBOT_PATH, _write(t, "fixed.urdf", SHELF.replace('type="revolute"', 'type="fixed"'))),
}


@pytest.mark.parametrize("case", list(URDF_FILE_CASES))
def test_bad_urdf_files(tmp_path, case):
    robot, obj = URDF_FILE_CASES[case](tmp_path)
    if case in ("mesh geometry", "floating joint", "planar joint", "joint to unknown link", "no movable joint"):
        assert obj.read_text() != SHELF, "the test's edit of the asset did not apply"
    with pytest.raises(UrdfError) as e:
        sabre.Scene.from_urdf(robot, obj)
    check(e, UrdfError)
    with pytest.raises(UrdfError):
        sabre.Scene.from_urdf(str(robot), str(obj))


def test_bad_urdf_strings():
    for robot, obj in [("", SHELF), ("<robot", SHELF), (ROBOT_PATH.read_text(), "<robot name='x'/>")]:
        with pytest.raises(UrdfError) as e:
            sabre.Scene.from_urdf_strings(robot, obj)
        check(e, UrdfError)


# --------------------------------------------------------------------------------------------------
# The private extension module on its own: still sabre errors, never a panic
# --------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def core(objs):
    return SimpleNamespace(
        scene=objs.scene._core,
        model=objs.model._core,
        plant=objs.plant._core,
        controller=objs.controller._core,
        nq=objs.scene.nq,
        no=objs.scene.no,
        nx=objs.scene.nx,
        x0=objs.scene.default_state(),
    )


CORE_CALLS = {
    "Scene.fk": (lambda c, a: c.scene.fk(a, "grasp"), "nq"),
    "Scene.jacobian": (lambda c, a: c.scene.jacobian(a, "grasp"), "nq"),
    "Scene.object_fk": (lambda c, a: c.scene.object_fk(a, "handle_frame"), "no"),
    "Scene.mass_matrix_and_gravity": (lambda c, a: c.scene.mass_matrix_and_gravity(a), "nq"),
    "servo_guide q0": (
        lambda c, a: _core.servo_guide(c.scene, a, np.stack([np.eye(4)] * 3), 0.015, "grasp", _core.ServoGuideConfig()),
        "nq",
    ),
    "RolloutModel.rollout x0": (lambda c, a: c.model.rollout(a, np.zeros((1, 1, c.nq)), None), "nx"),
    "Plant.reset": (lambda c, a: c.plant.reset(a), "nx"),
    "Plant.step": (lambda c, a: c.plant.step(a), "nq"),
    "LowLevelController.track": (lambda c, a: c.controller.track(c.plant, a, 1), "nq"),
    "LowLevelController.torque x": (lambda c, a: c.controller.torque(a, np.zeros(c.nq)), "nx"),
    "LowLevelController.torque u_ref": (lambda c, a: c.controller.torque(c.x0, a), "nq"),
}

CORE_SHAPES = {
    "short": lambda n: np.zeros(n - 1),
    "long": lambda n: np.zeros(n + 1),
    "empty": lambda n: np.zeros(0),
    "0-d": lambda n: np.array(0.0),
    "2-d": lambda n: np.zeros((2, n)),
    "3-d empty": lambda n: np.zeros((0, 0, n)),
}


@pytest.mark.parametrize("case", list(CORE_SHAPES))
@pytest.mark.parametrize("call", list(CORE_CALLS))
def test_core_wrong_shapes_are_shape_errors(core, call, case):
    fn, size = CORE_CALLS[call]
    with pytest.raises(ShapeError) as e:
        fn(core, CORE_SHAPES[case](getattr(core, size)))
    check(e, ShapeError, ValueError)


@pytest.mark.parametrize("call", list(CORE_CALLS))
def test_core_non_finite_and_strided_input(core, call):
    fn, size = CORE_CALLS[call]
    n = getattr(core, size)
    with pytest.raises(InvalidValueError) as e:
        fn(core, np.full(n, np.nan))
    check(e, InvalidValueError, ValueError)
    if n > 1:  # a strided view of one element is still contiguous
        strided = np.zeros(2 * n)[::2]  # right shape, not contiguous
        with pytest.raises(InvalidValueError) as e:
            fn(core, strided)
        check(e, InvalidValueError, ValueError)
        with pytest.raises(InvalidValueError):
            fn(core, np.zeros(n)[::-1])  # negative stride


@pytest.mark.parametrize("dtype", [np.int64, np.float32, bool, complex, object])
@pytest.mark.parametrize("call", list(CORE_CALLS))
def test_core_wrong_dtype_is_an_ordinary_exception(core, call, dtype):
    fn, size = CORE_CALLS[call]
    # pyo3's argument conversion raises TypeError; a PanicException (a BaseException) would escape this.
    with pytest.raises((TypeError, SabreError)):
        fn(core, np.zeros(getattr(core, size), dtype=dtype))


@pytest.mark.parametrize(
    "U, cls",
    [
        (np.zeros((2, 3, 9)), ShapeError),
        (np.zeros((3, 10)), ShapeError),
        (np.zeros(10), ShapeError),
        (np.zeros((1, 2, 3, 10)), ShapeError),
        # Fortran order: right shape, but the memory is not in the (N, K, nu) row-major order the
        # core reads; it must be refused like any other non-C-contiguous array, not reinterpreted.
        (np.zeros((2, 3, 10), order="F"), InvalidValueError),
        (np.zeros((3, 2, 10)).transpose(1, 0, 2), InvalidValueError),
        (np.full((2, 3, 10), np.nan), InvalidValueError),
    ],
    ids=["nu-1", "2-d", "1-d", "4-d", "fortran-order", "transposed", "nan"],
)
def test_core_rollout_inputs(core, U, cls):
    with pytest.raises(cls) as e:
        core.model.rollout(core.x0, U, None)
    check(e, cls, ValueError)


def test_core_rollout_zero_threads(core):
    with pytest.raises(InvalidValueError) as e:
        core.model.rollout(core.x0, np.zeros((1, 1, core.nq)), 0)
    check(e, InvalidValueError)
    with pytest.raises((OverflowError, TypeError, SabreError)):
        core.model.rollout(core.x0, np.zeros((1, 1, core.nq)), -1)


def test_core_constructors_and_loaders():
    with pytest.raises(ShapeError):
        _core.Scene.load("royalpanda", "shelf", [1.0, 2.0, 3.0])
    with pytest.raises(InvalidValueError):
        _core.Scene.load("royalpanda", "shelf", [1.0, 0.0, 0.0, float("nan"), 0.0, 0.0])
    with pytest.raises(UnknownAssetError):
        _core.Scene.load("royalpanda", "fridge", None)
    with pytest.raises(UrdfError):
        _core.Scene.from_urdf("/nonexistent/robot.urdf", str(SHELF_PATH), None)
    with pytest.raises(UrdfError):
        _core.Scene.from_urdf_strings("<robot", SHELF, None)
    scene = _core.Scene.load("royalpanda", "shelf", None)

    def config(cls, **fields):
        c = cls()
        for name, value in fields.items():
            setattr(c, name, value)
        return c

    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(InvalidValueError):
            _core.RolloutModel(scene, config(_core.RolloutConfig, dt=bad))
        with pytest.raises(InvalidValueError):
            _core.Plant(scene, config(_core.PlantConfig, dt=bad))
        with pytest.raises(InvalidValueError):
            _core.LowLevelController(scene, bad, _core.LowLevelConfig())
    with pytest.raises(InvalidValueError):
        _core.RolloutModel(scene, config(_core.RolloutConfig, contact_friction=-0.2))
    with pytest.raises(InvalidValueError):
        _core.LowLevelController(scene, 0.001, config(_core.LowLevelConfig, gain_inertia_floor=float("inf")))
    with pytest.raises(InvalidValueError):
        _core.Plant(scene, config(_core.PlantConfig, contact_friction=float("nan")))


# --------------------------------------------------------------------------------------------------
# Nothing aborts the interpreter
# --------------------------------------------------------------------------------------------------

GARBAGE_SCRIPT = r"""
import numpy as np
import sabre
from sabre import _core

scene = sabre.Scene.load()
nq, nx, nu = scene.nq, scene.nx, scene.nu
x0 = scene.default_state()
model = sabre.RolloutModel(scene)
plant = sabre.Plant(scene)
controller = sabre.LowLevelController(scene)
raised = ok = 0

def attempt(f):
    global raised, ok
    try:
        f()
        ok += 1
    except Exception:  # any ordinary exception is fine; a crash or a BaseException is not
        raised += 1

huge_nan = np.full(10**7, np.nan)
for f in (
    lambda: scene.fk(huge_nan, "grasp"),
    lambda: scene.jacobian(huge_nan, "grasp"),
    lambda: scene.mass_matrix(huge_nan),
    lambda: scene.object_fk(huge_nan, "handle_frame"),
    lambda: plant.reset(huge_nan),
    lambda: plant.step(huge_nan),
    lambda: controller.torque(huge_nan, huge_nan),
    lambda: model.rollout(huge_nan, np.zeros((1, 1, nu))),
    lambda: model.rollout(x0, np.full((4000, 50, nu), np.nan)),
    lambda: model.rollout(x0, np.full((1, 200000, nu), np.inf)),
    lambda: scene._core.fk(huge_nan, "grasp"),
    lambda: model._core.rollout(x0, np.full((4000, 50, nu), np.nan), None),
):
    attempt(f)

for shape in [(0, 0, nu), (1, 0, nu), (0, 7, nu), (0, 0, 10**6), (1, 0, 0), (0, 0, 0), (0,), (0, 0), (0, 0, 0, 0), (1, 1, nu)]:
    attempt(lambda: model.rollout(x0, np.zeros(shape)))
    attempt(lambda: model._core.rollout(x0, np.zeros(shape), None))
    attempt(lambda: model._core.rollout(x0, np.zeros(shape), 1))

for value in (np.zeros(nx) + 1e308, np.full(nx, -1e308), np.r_[np.zeros(nq), np.full(nq, 1e300), 0.0, 0.0]):
    attempt(lambda: model.rollout(value, np.full((2, 3, nu), 1e308)))
    attempt(lambda: plant.reset(value))
    for _ in range(3):
        attempt(lambda: plant.step(np.full(nq, 1e308)))
        attempt(lambda: controller.torque(value, np.full(nq, 1e308)))
    attempt(lambda: controller.track(plant, np.full(nq, -1e308), 5))
plant.reset()
attempt(lambda: plant.step(np.zeros(nq)))

for text in ("", "<", "<robot/>", "\x00" * 100, "<robot name='x'>" + "<link name='a'/>" * 5000 + "</robot>", "<robot>" * 10000):
    attempt(lambda: sabre.Scene.from_urdf_strings(text, text))
    attempt(lambda: _core.Scene.from_urdf_strings(text, text, None))
for junk in ([np.nan] * 6, [1e308] * 6, [0] * 7, "abcdef", [[1, 2], [3]], object()):
    attempt(lambda: sabre.Scene.load("royalpanda", "drawer", junk))
for frame in ("", "\x00", "grasp" * 10000, "ü"):
    attempt(lambda: scene.fk(x0[:nq], frame))
    attempt(lambda: scene.object_fk([0.0], frame))

assert raised > 40 and ok > 5, (raised, ok)
print("survived", raised, ok)
"""


#: CPU seconds a child interpreter may use: a guard against a spinning hang that does not depend
#: on how busy the machine is (CPU time, unlike wall time, does not grow with the load).
CPU_SECONDS = 300


def _run(script: str, memory_limit: int | None = None) -> subprocess.CompletedProcess:
    def limit():
        import resource

        resource.setrlimit(resource.RLIMIT_CPU, (CPU_SECONDS, CPU_SECONDS))
        if memory_limit:  # bound the address space so huge allocations fail the same way on every machine
            resource.setrlimit(resource.RLIMIT_AS, (memory_limit, memory_limit))

    env = dict(os.environ, RUST_BACKTRACE="0")
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(script)],
        capture_output=True,
        text=True,
        env=env,
        preexec_fn=limit,
    )


def test_garbage_never_aborts_the_interpreter():
    proc = _run(GARBAGE_SCRIPT)
    assert proc.returncode == 0, f"exit code {proc.returncode}\nstdout:\n{proc.stdout}\nstderr:\n{proc.stderr[-3000:]}"
    assert "survived" in proc.stdout


@pytest.mark.parametrize("n", [10**9, 2**40])
def test_huge_batch_of_empty_rollouts_does_not_abort(n):
    # U of shape (n, 0, nu) holds no data, but the result's states have shape (n, 1, nx): that
    # cannot be allocated, which must surface as an exception, not a process abort.
    script = f"""
    import numpy as np, sabre
    scene = sabre.Scene.load()
    model = sabre.RolloutModel(scene)
    try:
        r = model.rollout(scene.default_state(), np.zeros(({n}, 0, scene.nu)))
        print("returned", r.states.shape)
    except (MemoryError, sabre.SabreError) as e:
        print("raised", type(e).__name__, e)
    """
    proc = _run(script, memory_limit=4 * 2**30)
    assert proc.returncode == 0, f"exit code {proc.returncode}\nstdout:\n{proc.stdout}\nstderr:\n{proc.stderr[-1500:]}"
    assert "raised" in proc.stdout


def _os_threads() -> int:
    return len(os.listdir("/proc/self/task"))


@pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="counts threads through Linux /proc")
def test_absurd_thread_count_starts_no_more_than_max_threads():
    # threads is an upper bound on parallelism, not a request for 100 000 OS threads: it must be
    # rejected or clamped, not spawn (and cache forever) a pool of that size.
    scene = sabre.Scene.load()
    model = sabre.RolloutModel(scene)
    before = _os_threads()
    try:
        model.rollout(scene.default_state(), np.zeros((2, 1, scene.nu)), threads=100_000)
    except sabre.SabreError:
        pass
    assert _os_threads() - before <= sabre.sim.MAX_THREADS


@pytest.mark.parametrize(
    "make",
    [
        lambda t: t.OpenConfig(slip_distance=-0.01),
        lambda t: t.HookConfig(drag_speed=float("nan")),
        lambda t: t.HookConfig(tolerance="tight"),
        lambda t: t.NoiseConfig(distance=0.0),
        lambda t: t.OpenConfig(success_fraction=1.5),
        lambda t: t.OpenObject(opening=float("inf")),
        lambda t: t.HookConfig(insert_depth_tolerance=-0.005),
        lambda t: t.HookConfig(insert_depth_tolerance=float("nan")),
        lambda t: t.HookConfig(backout=-0.01),
        lambda t: t.HookConfig(blocked_depth=-0.008),
        lambda t: t.HookConfig(blocked_speed=float("nan")),
        lambda t: t.HookConfig(backout=float("nan")),
        lambda t: t.ApproachConfig(pregrasp_offset=(0.0, float("nan"), 0.0)),
        lambda t: t.OpenConfig(pose_weights=(1.0, 1.0, 1.0, 1.0, 1.0, -1.0)),
        lambda t: t.ReleaseConfig(probe=0.0),
        lambda t: t.GuideConfig(gain=-1.0),
    ],
)
def test_open_object_settings_reject_bad_values(make):
    with pytest.raises(InvalidValueError):
        make(sabre.tasks)


def test_open_object_rejects_a_settings_group_of_the_wrong_type():
    with pytest.raises(TypeError):
        sabre.tasks.OpenObject(hook=sabre.tasks.OpenConfig())


@pytest.mark.parametrize(
    "spec, field",
    [
        ({"kind": "contact"}, "weight"),
        ({"kind": "contact", "weight": float("inf")}, "weight"),
        ({"kind": "power", "weight": "heavy", "p_max": 0.0}, "weight"),
        (
            {"kind": "pose", "frame": "grasp", "target": np.eye(4).ravel().tolist(), "object_frame": None, "weights": [1.0] * 5},
            "weights",
        ),
        ({"kind": "base_box", "lower": [0.0, 0.0], "upper": [1.0], "weight": 1.0, "weight_slope": 1.0}, "upper"),
        ({"weight": 1.0}, "kind"),
    ],
)
def test_core_bad_cost_spec_is_an_invalid_value_naming_the_field(spec, field):
    scene = _core.Scene.load("royalpanda", "shelf", None)
    with pytest.raises(InvalidValueError, match=field):
        _core.Cost(scene, [spec])
