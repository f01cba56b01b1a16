"""Bad input never crashes: every public entry point raises the documented sabre exception.

Documented behaviour (python/sabre/_validate.py): arrays are converted with ``np.asarray``; real
numeric dtypes (float, signed and unsigned int) are accepted and converted to float64; any other
dtype (bool, complex, strings, bytes, objects, datetimes) and any wrong shape or ragged nesting is a
:class:`ShapeError`; NaN and ±inf are :class:`InvalidValueError`. Both derive from SabreError and
ValueError.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

import sabre
from sabre import _core
from sabre.errors import (
    InvalidValueError,
    SabreError,
    ShapeError,
    UnknownAssetError,
    UnknownFrameError,
    UrdfError,
)

ASSETS = Path(__file__).resolve().parents[2] / "assets"
ROBOT_PATH = ASSETS / "robots" / "royalpanda.urdf"
SHELF_PATH = ASSETS / "objects" / "shelf.urdf"


@pytest.fixture(scope="module")
def objs():
    scene = sabre.Scene.load("royalpanda", "shelf")
    model = sabre.RolloutModel(scene)
    plant = sabre.Plant(scene)
    controller = sabre.LowLevelController(scene)
    planner = sabre.Controller(scene, sabre.tasks.OpenObject(), sabre.ControllerConfig(rollouts=4, horizon=0.06))
    return SimpleNamespace(scene=scene, model=model, plant=plant, controller=controller, planner=planner)


def check(excinfo, cls, *also):
    """The exception is exactly of the documented class family, a SabreError and the extra bases."""
    err = excinfo.value
    assert isinstance(err, cls), f"expected {cls.__name__}, got {type(err).__name__}: {err}"
    assert isinstance(err, SabreError)
    for base in also:
        assert isinstance(err, base)
    assert str(err), "the message must say what was wrong"


# --------------------------------------------------------------------------------------------------
# Vector arguments of every public entry point
# --------------------------------------------------------------------------------------------------

# name -> (call(objs, value), expected length given objs, a valid value given objs, None is valid)
TARGETS = {
    "Scene.fk(q)": (
        lambda o, v: o.scene.fk(v, "grasp"),
        lambda o: o.scene.nq,
        lambda o: o.scene.default_state()[: o.scene.nq],
        False,
    ),
    "Scene.jacobian(q)": (lambda o, v: o.scene.jacobian(v, "grasp"), lambda o: o.scene.nq, lambda o: np.zeros(o.scene.nq), False),
    "Scene.object_fk(o)": (
        lambda o, v: o.scene.object_fk(v, "handle_frame"),
        lambda o: o.scene.no,
        lambda o: np.full(o.scene.no, 0.3),
        False,
    ),
    "Scene.mass_matrix(q)": (lambda o, v: o.scene.mass_matrix(v), lambda o: o.scene.nq, lambda o: np.zeros(o.scene.nq), False),
    "RolloutModel.rollout(x0)": (
        lambda o, v: o.model.rollout(v, np.zeros((1, 2, o.scene.nu))),
        lambda o: o.scene.nx,
        lambda o: o.scene.default_state(),
        False,
    ),
    "Plant.reset(x0)": (lambda o, v: o.plant.reset(v), lambda o: o.scene.nx, lambda o: o.scene.default_state(), True),
    "Controller.update(x)": (
        lambda o, v: o.planner.update(v, 0.0),
        lambda o: o.scene.nx,
        lambda o: o.scene.default_state(),
        False,
    ),
    "Plant.step(tau)": (lambda o, v: o.plant.step(v), lambda o: o.scene.nq, lambda o: np.zeros(o.scene.nq), False),
    "LowLevelController.track(u_ref)": (
        lambda o, v: o.controller.track(o.plant, v, 1),
        lambda o: o.scene.nq,
        lambda o: np.zeros(o.scene.nq),
        False,
    ),
    "LowLevelController.torque(x)": (
        lambda o, v: o.controller.torque(v, np.zeros(o.scene.nq)),
        lambda o: o.scene.nx,
        lambda o: o.scene.default_state(),
        False,
    ),
    "LowLevelController.torque(u_ref)": (
        lambda o, v: o.controller.torque(o.scene.default_state(), v),
        lambda o: o.scene.nq,
        lambda o: np.zeros(o.scene.nq),
        False,
    ),
    "Scene.load(obj_pose)": (
        lambda o, v: sabre.Scene.load("royalpanda", "shelf", obj_pose=v),
        lambda o: 6,
        lambda o: np.array([1.0, 0, 0, 0, 0, 0]),
        True,
    ),
    "Scene.from_urdf(obj_pose)": (
        lambda o, v: sabre.Scene.from_urdf(ROBOT_PATH, SHELF_PATH, obj_pose=v),
        lambda o: 6,
        lambda o: np.array([1.0, 0, 0, 0, 0, 0.3]),
        True,
    ),
    "Scene.from_urdf_strings(obj_pose)": (
        lambda o, v: sabre.Scene.from_urdf_strings(ROBOT_PATH.read_text(), SHELF_PATH.read_text(), obj_pose=v),
        lambda o: 6,
        lambda o: np.array([1.0, 0, 0, 0, 0, 0]),
        True,
    ),
}

BAD_SHAPES = {
    "too short": lambda n: np.zeros(n - 1),
    "too long": lambda n: np.zeros(n + 1),
    "empty": lambda n: np.zeros(0),
    "0-d array": lambda n: np.array(0.5),
    "python float": lambda n: 0.5,
    "row matrix": lambda n: np.zeros((1, n)),
    "column matrix": lambda n: np.zeros((n, 1)),
    "3-d": lambda n: np.zeros((1, 1, n)),
    "ragged list": lambda n: [0.0] * (n - 1) + [[0.0, 1.0]],
    "ragged nested list": lambda n: [[0.0] * n, [0.0] * (n - 1)],
    "None": lambda n: None,
}

BAD_DTYPES = {
    "list of strings": lambda n: ["a"] * n,
    "numeric strings": lambda n: np.array(["1.0"] * n),
    "bytes": lambda n: np.zeros(n, dtype="S8"),
    "complex": lambda n: np.zeros(n, dtype=complex),
    "object array": lambda n: np.zeros(n, dtype=object),
    "bool": lambda n: np.zeros(n, dtype=bool),
    "datetime": lambda n: np.zeros(n, dtype="datetime64[s]"),
}


def _with(value, index, bad):
    v = np.array(value, dtype=float)
    v[index] = bad
    return v


BAD_VALUES = {
    "nan first": lambda good: _with(good, 0, np.nan),
    "nan last": lambda good: _with(good, -1, np.nan),
    "+inf": lambda good: _with(good, len(good) // 2, np.inf),
    "-inf": lambda good: _with(good, -1, -np.inf),
    "all nan list": lambda good: [float("nan")] * len(good),
}


@pytest.mark.parametrize(
    "target, case",
    # None is a valid argument where it means "the default" (e.g. Plant.reset(None)).
    [(t, c) for t in TARGETS for c in BAD_SHAPES if not (c == "None" and TARGETS[t][3])],
)
def test_wrong_shape_is_a_shape_error(objs, target, case):
    call, length, _, _none_ok = TARGETS[target]
    with pytest.raises(ShapeError) as e:
        call(objs, BAD_SHAPES[case](length(objs)))
    check(e, ShapeError, ValueError)


@pytest.mark.parametrize("case", list(BAD_DTYPES))
@pytest.mark.parametrize("target", list(TARGETS))
def test_non_numeric_dtype_is_a_shape_error(objs, target, case):
    call, length, _, _ = TARGETS[target]
    with pytest.raises(ShapeError) as e:
        call(objs, BAD_DTYPES[case](length(objs)))
    check(e, ShapeError, ValueError)


@pytest.mark.parametrize("case", list(BAD_VALUES))
@pytest.mark.parametrize("target", list(TARGETS))
def test_non_finite_values_are_invalid_value_errors(objs, target, case):
    call, _, good, _ = TARGETS[target]
    with pytest.raises(InvalidValueError) as e:
        call(objs, BAD_VALUES[case](good(objs)))
    check(e, InvalidValueError, ValueError)


@pytest.mark.parametrize("dtype", [np.int64, np.int32, np.uint8, np.float32, np.float64])
@pytest.mark.parametrize("target", list(TARGETS))
def test_real_numeric_dtypes_are_accepted(objs, target, dtype):
    call, _, good, _ = TARGETS[target]
    value = good(objs)
    if np.issubdtype(dtype, np.unsignedinteger):
        if target == "Plant.reset(x0)":
            pytest.skip("panda_joint4's whole range is negative: no unsigned state lies within the joint limits")
        value = np.abs(value)
    call(objs, np.asarray(value).astype(dtype))  # must not raise
    call(objs, np.asarray(value).astype(dtype).tolist())  # plain lists too


def test_integer_input_means_the_same_as_float(objs):
    q = np.array([1, 0, -1, 0, 1, 0, -2, 0, 2, 0])
    np.testing.assert_array_equal(objs.scene.fk(q, "grasp"), objs.scene.fk(q.astype(float), "grasp"))


# --------------------------------------------------------------------------------------------------
# Rollout inputs, thread counts, constructors
# --------------------------------------------------------------------------------------------------

U_BAD_SHAPES = {
    "1-d": lambda nu: np.zeros(nu),
    "2-d": lambda nu: np.zeros((3, nu)),
    "nu - 1": lambda nu: np.zeros((2, 3, nu - 1)),
    "nu + 1": lambda nu: np.zeros((2, 3, nu + 1)),
    "nu = 0": lambda nu: np.zeros((2, 3, 0)),
    "4-d": lambda nu: np.zeros((1, 2, 3, nu)),
    "0-d": lambda nu: np.array(1.0),
    "ragged": lambda nu: [[[0.0] * nu] * 2, [[0.0] * nu]],
    "None": lambda nu: None,
}


@pytest.mark.parametrize("case", list(U_BAD_SHAPES))
def test_rollout_inputs_of_wrong_shape(objs, case):
    with pytest.raises(ShapeError) as e:
        objs.model.rollout(objs.scene.default_state(), U_BAD_SHAPES[case](objs.scene.nu))
    check(e, ShapeError, ValueError)


@pytest.mark.parametrize("dtype", [bool, complex, object, "U3"])
def test_rollout_inputs_of_wrong_dtype(objs, dtype):
    with pytest.raises(ShapeError) as e:
        objs.model.rollout(objs.scene.default_state(), np.zeros((2, 3, objs.scene.nu), dtype=dtype))
    check(e, ShapeError, ValueError)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("where", [(0, 0, 0), (1, 2, -1)])
def test_rollout_inputs_with_non_finite_values(objs, bad, where):
    U = np.zeros((2, 3, objs.scene.nu))
    U[where] = bad
    with pytest.raises(InvalidValueError) as e:
        objs.model.rollout(objs.scene.default_state(), U)
    check(e, InvalidValueError, ValueError)


@pytest.mark.parametrize("shape", [(0, 0), (1, 0), (0, 5), (3, 0)])
def test_empty_rollout_batches_have_the_documented_shapes(objs, shape):
    n, k = shape
    x0 = objs.scene.default_state()
    r = objs.model.rollout(x0, np.zeros((n, k, objs.scene.nu)))
    assert r.states.shape == (n, k + 1, objs.scene.nx)
    assert r.tau_ext.shape == (n, k, objs.scene.nq)
    assert r.wrench.shape == (n, k, 6)
    assert r.contact.shape == (n, k) and r.contact.dtype == bool
    assert r.failed.shape == (n,) and not r.failed.any()
    np.testing.assert_array_equal(r.states[:, 0], np.broadcast_to(x0, (n, objs.scene.nx)))


@pytest.mark.parametrize("threads", [0, -1, -(2**70), 2**64, 1.5, True, "2", 2.0, [2]])
def test_bad_thread_counts(objs, threads):
    with pytest.raises(InvalidValueError) as e:
        objs.model.rollout(objs.scene.default_state(), np.zeros((1, 1, objs.scene.nu)), threads=threads)
    check(e, InvalidValueError, ValueError)


def test_numpy_integer_thread_count_is_accepted(objs):
    r = objs.model.rollout(objs.scene.default_state(), np.zeros((2, 1, objs.scene.nu)), threads=np.int64(1))
    assert r.states.shape == (2, 2, objs.scene.nx)


CONSTRUCTORS = {
    "RolloutModel dt=0": lambda s: sabre.RolloutModel(s, dt=0.0),
    "RolloutModel dt<0": lambda s: sabre.RolloutModel(s, dt=-0.015),
    "RolloutModel dt=nan": lambda s: sabre.RolloutModel(s, dt=float("nan")),
    "RolloutModel dt=inf": lambda s: sabre.RolloutModel(s, dt=float("inf")),
    "RolloutModel dt='fast'": lambda s: sabre.RolloutModel(s, dt="fast"),
    "RolloutModel dt=None": lambda s: sabre.RolloutModel(s, dt=None),
    "RolloutModel friction<0": lambda s: sabre.RolloutModel(s, contact_friction=-0.1),
    "RolloutModel friction=nan": lambda s: sabre.RolloutModel(s, contact_friction=float("nan")),
    "RolloutModel bandwidth=0": lambda s: sabre.RolloutModel(s, servo_bandwidth=0.0),
    "RolloutModel integral gain<0": lambda s: sabre.RolloutModel(s, servo_integral_gain=-1.0),
    "RolloutModel integral limit=inf": lambda s: sabre.RolloutModel(s, servo_integral_limit=float("inf")),
    "RolloutModel iterations=0": lambda s: sabre.RolloutModel(s, solver_iterations=0),
    "RolloutModel iterations=2.5": lambda s: sabre.RolloutModel(s, solver_iterations=2.5),
    "Plant dt=0": lambda s: sabre.Plant(s, dt=0.0),
    "Plant dt<0": lambda s: sabre.Plant(s, dt=-0.001),
    "Plant dt=nan": lambda s: sabre.Plant(s, dt=float("nan")),
    "Plant dt=-inf": lambda s: sabre.Plant(s, dt=float("-inf")),
    "Plant friction<0": lambda s: sabre.Plant(s, contact_friction=-1.0),
    "Plant friction=inf": lambda s: sabre.Plant(s, contact_friction=float("inf")),
    "Plant iterations=0": lambda s: sabre.Plant(s, solver_iterations=0),
    "LowLevelController dt=0": lambda s: sabre.LowLevelController(s, dt=0.0),
    "LowLevelController dt=nan": lambda s: sabre.LowLevelController(s, dt=float("nan")),
    "LowLevelController bandwidth<0": lambda s: sabre.LowLevelController(s, bandwidth=-40.0),
    "LowLevelController integral gain=nan": lambda s: sabre.LowLevelController(s, integral_gain=float("nan")),
    "LowLevelController inertia floor<0": lambda s: sabre.LowLevelController(s, gain_inertia_floor=-0.03),
}


@pytest.mark.parametrize("case", list(CONSTRUCTORS))
def test_bad_constructor_parameters(objs, case):
    with pytest.raises(InvalidValueError) as e:
        CONSTRUCTORS[case](objs.scene)
    check(e, InvalidValueError, ValueError)


@pytest.mark.parametrize("cls", [sabre.RolloutModel, sabre.Plant, sabre.LowLevelController])
@pytest.mark.parametrize("not_a_scene", ["shelf", None, 3])
def test_constructors_reject_things_that_are_not_scenes(cls, not_a_scene):
    with pytest.raises(TypeError):
        cls(not_a_scene)


def test_plant_keeps_working_after_rejected_input(objs):
    plant, scene = objs.plant, objs.scene
    plant.reset()
    before = plant.state.copy()
    for bad in (np.full(scene.nx, np.nan), np.zeros(3)):
        with pytest.raises(SabreError):
            plant.reset(bad)
    with pytest.raises(SabreError):
        plant.step(np.full(scene.nq, np.inf))
    np.testing.assert_array_equal(plant.state, before)
    assert plant.time == 0.0
    plant.step(np.zeros(scene.nq))
    assert plant.time == pytest.approx(plant.dt)


# --------------------------------------------------------------------------------------------------
# Names: frames, assets, URDF files
# --------------------------------------------------------------------------------------------------

FRAME_CALLS = {
    "fk unknown": lambda s: s.fk(np.zeros(s.nq), "gripper"),
    "fk object frame": lambda s: s.fk(np.zeros(s.nq), "handle_frame"),
    "fk empty name": lambda s: s.fk(np.zeros(s.nq), ""),
    "fk case": lambda s: s.fk(np.zeros(s.nq), "Grasp"),
    "jacobian unknown": lambda s: s.jacobian(np.zeros(s.nq), "tool0"),
    "object_fk robot frame": lambda s: s.object_fk(np.zeros(s.no), "grasp"),
    "object_fk unknown": lambda s: s.object_fk(np.zeros(s.no), "knob"),
    "object_fk_many unknown": lambda s: s.object_fk_many(np.zeros((3, s.no)), "knob"),
    "servo_guide unknown": lambda s: sabre.guides.servo_guide(
        s, np.zeros(s.nq), np.stack([np.eye(4)] * 3), 0.015, frame="gripper"
    ),
    "servo_guides unknown": lambda s: sabre.guides.servo_guides(
        s, np.zeros(s.nq), np.stack([np.stack([np.eye(4)] * 3)] * 2), 0.015, frame="gripper"
    ),
}


@pytest.mark.parametrize("case", list(FRAME_CALLS))
def test_unknown_frames(objs, case):
    with pytest.raises(KeyError) as e:  # catchable as KeyError ...
        FRAME_CALLS[case](objs.scene)
    check(e, UnknownFrameError, LookupError)  # ... and it is the sabre class
    message = str(e.value)
    assert not message.startswith(("'", '"')), "str() must not be the KeyError repr of the message"
    names = objs.scene.object_frame_names if "object_fk" in case else objs.scene.frame_names
    assert all(n in message for n in names), f"the message should list the frames: {message}"


@pytest.mark.parametrize(
    "robot, obj, kind, available",
    [
        ("r2d2", "shelf", "robot", ["royalpanda"]),
        ("", "shelf", "robot", ["royalpanda"]),
        ("royalpanda", "fridge", "object", ["shelf", "microwave", "dishwasher", "drawer"]),
        ("royalpanda", "Shelf", "object", ["shelf", "microwave", "dishwasher", "drawer"]),
        ("royalpanda", "shelf.urdf", "object", ["shelf", "microwave", "dishwasher", "drawer"]),
    ],
)
def test_unknown_assets_list_the_available_names(robot, obj, kind, available):
    with pytest.raises(UnknownAssetError) as e:
        sabre.Scene.load(robot, obj)
    check(e, UnknownAssetError, LookupError)
    message = str(e.value)
    assert kind in message
    for name in available:
        assert name in message, f"{name!r} missing from: {message}"
    assert set(available) <= set(sabre.ROBOTS if kind == "robot" else sabre.OBJECTS)


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
