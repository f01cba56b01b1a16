"""Bad input never crashes: every public entry point raises the documented sabre exception.

Documented behaviour (python/sabre/_validate.py): arrays are converted with ``np.asarray``; real
numeric dtypes (float, signed and unsigned int) are accepted and converted to float64; any other
dtype (bool, complex, strings, bytes, objects, datetimes) and any wrong shape or ragged nesting is a
:class:`ShapeError`; NaN and ±inf are :class:`InvalidValueError`. Both derive from SabreError and
ValueError.
"""

from __future__ import annotations

import numpy as np
import pytest
from bad_input_support import ROBOT_PATH, SHELF_PATH, check, make_objs

import sabre
from sabre.errors import (
    InvalidValueError,
    SabreError,
    ShapeError,
    UnknownAssetError,
    UnknownFrameError,
)


@pytest.fixture(scope="module")
def objs():
    return make_objs()


# --------------------------------------------------------------------------------------------------
# Vector arguments of every public entry point
# --------------------------------------------------------------------------------------------------


def _reset(o, x0):
    o.plant.reset(x0)
    return o.plant.state


def _step_from_rest(o, tau):
    o.plant.reset()
    o.plant.step(tau)
    return o.plant.state


def _track_from_rest(o, u_ref):
    o.plant.reset()
    o.controller.reset()
    o.controller.track(o.plant, u_ref, 1)
    return o.plant.state


def _torque(o, x, u_ref):
    o.controller.reset()
    return o.controller.torque(x, u_ref)


def _plan(o, x):
    o.planner.reset()  # the same random stream for every call
    o.planner.update(x, 0.0)
    return o.planner.nominal


# name -> (call(objs, value) -> what the call returned or left behind, expected length given objs,
# a valid value given objs, None is valid)
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
    "Scene.mass_matrix(q)": (
        lambda o, v: np.vstack(o.scene.mass_matrix(v)),  # M (nq, nq) over the gravity torque (nq,)
        lambda o: o.scene.nq,
        lambda o: np.zeros(o.scene.nq),
        False,
    ),
    "RolloutModel.rollout(x0)": (
        lambda o, v: o.model.rollout(v, np.zeros((1, 2, o.scene.nu))).states,
        lambda o: o.scene.nx,
        lambda o: o.scene.default_state(),
        False,
    ),
    "Plant.reset(x0)": (_reset, lambda o: o.scene.nx, lambda o: o.scene.default_state(), True),
    "Controller.update(x)": (_plan, lambda o: o.scene.nx, lambda o: o.scene.default_state(), False),
    "Plant.step(tau)": (_step_from_rest, lambda o: o.scene.nq, lambda o: np.zeros(o.scene.nq), False),
    "LowLevelController.track(u_ref)": (_track_from_rest, lambda o: o.scene.nq, lambda o: np.zeros(o.scene.nq), False),
    "LowLevelController.torque(x)": (
        lambda o, v: _torque(o, v, np.zeros(o.scene.nq)),
        lambda o: o.scene.nx,
        lambda o: o.scene.default_state(),
        False,
    ),
    "LowLevelController.torque(u_ref)": (
        lambda o, v: _torque(o, o.scene.default_state(), v),
        lambda o: o.scene.nq,
        lambda o: np.zeros(o.scene.nq),
        False,
    ),
    "Scene.load(obj_pose)": (
        lambda o, v: sabre.Scene.load("royalpanda", "shelf", obj_pose=v).object_pose,
        lambda o: 6,
        lambda o: np.array([1.0, 0, 0, 0, 0, 0]),
        True,
    ),
    "Scene.from_urdf(obj_pose)": (
        lambda o, v: sabre.Scene.from_urdf(ROBOT_PATH, SHELF_PATH, obj_pose=v).object_pose,
        lambda o: 6,
        lambda o: np.array([1.0, 0, 0, 0, 0, 0.3]),
        True,
    ),
    "Scene.from_urdf_strings(obj_pose)": (
        lambda o, v: sabre.Scene.from_urdf_strings(ROBOT_PATH.read_text(), SHELF_PATH.read_text(), obj_pose=v).object_pose,
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


def _pose(xyz_rpy):
    """The (4, 4) pose of (x, y, z, roll, pitch, yaw): R = Rz(yaw) Ry(pitch) Rx(roll), as in a URDF origin."""
    x, y, z, roll, pitch, yaw = xyz_rpy
    c, s = np.cos, np.sin
    rx = np.array([[1, 0, 0], [0, c(roll), -s(roll)], [0, s(roll), c(roll)]])
    ry = np.array([[c(pitch), 0, s(pitch)], [0, 1, 0], [-s(pitch), 0, c(pitch)]])
    rz = np.array([[c(yaw), -s(yaw), 0], [s(yaw), c(yaw), 0], [0, 0, 1]])
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rz @ ry @ rx, (x, y, z)
    return pose


# where the outcome holds the input itself: (that part of the outcome, what it is for a float64 input)
HOLDS_INPUT = {
    "Plant.reset(x0)": (lambda out: out, lambda v: v),
    "RolloutModel.rollout(x0)": (lambda out: out[0, 0], lambda v: v),
    "Scene.load(obj_pose)": (lambda out: out, _pose),
    "Scene.from_urdf(obj_pose)": (lambda out: out, _pose),
    "Scene.from_urdf_strings(obj_pose)": (lambda out: out, _pose),
}


@pytest.mark.parametrize("dtype", [np.int64, np.int32, np.uint8, np.float32, np.float64])
@pytest.mark.parametrize("target", list(TARGETS))
def test_real_numeric_dtypes_are_read_as_their_float64_values(objs, target, dtype):
    """Documented: a real numeric array is converted to float64. The call on it (and on it as a plain
    list) does exactly what it does on the float64 array of the same numbers, converted here; where
    casting to ``dtype`` moved the numbers, the outcome moved with them (the numbers given are the
    ones used); where the outcome holds the input, it holds those numbers."""
    call, _, good, _ = TARGETS[target]
    value = np.asarray(good(objs), dtype=np.float64)
    unsigned = np.issubdtype(dtype, np.unsignedinteger)
    if unsigned:
        # panda_joint4's whole range is negative: no unsigned state lies within the joint limits
        if target == "Plant.reset(x0)":
            pytest.skip("the plant refuses a state outside the joint limits")
        value = np.abs(value)
    given = value.astype(dtype)
    as_float = given.astype(np.float64)
    expected = np.array(call(objs, as_float))
    np.testing.assert_array_equal(call(objs, given), expected)
    np.testing.assert_array_equal(call(objs, given.tolist()), expected)
    # (from outside the joint limits every rollout fails: the plan is zero whatever the state)
    if np.abs(as_float - value).max() > 1e-3 and not (unsigned and target == "Controller.update(x)"):
        assert not np.array_equal(call(objs, value), expected), "the cast moved the numbers, not the outcome"
    if target in HOLDS_INPUT:
        part, holds = HOLDS_INPUT[target]
        np.testing.assert_allclose(part(expected), holds(as_float), rtol=0, atol=1e-12)


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
