"""The MuJoCo plant (:class:`MujocoPlant`): a second 1 kHz plant with a joint-velocity interface, the readings
of :class:`sabre.Plant` and its stuck-object fault."""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .. import _core
from .._validate import as_float_array, as_non_negative, as_positive
from ..errors import InvalidValueError, SimulationError, UrdfError, require_extra
from ..scene import OBJECTS, ROBOTS, Scene
from ..sim import DEFAULT_TAU_EXT_CUTOFF, ContactPoint
from .model import builtin_path, check_against_scene, compile_model, layout

__all__ = ["MujocoPlant"]

# The core's defaults, the one source of the plant's and servo's defaults below.
_PLANT = _core.PlantConfig()
_LOW_LEVEL = _core.LowLevelConfig()

# sabre.Plant's ranges: how far a reset may lie beyond a joint limit, and the joint speeds that mean the
# integration diverged (20 × a robot joint's velocity limit, 100 rad/s or m/s for an object joint).
_RESET_LIMIT_TOLERANCE = 0.05
_DIVERGENCE_VELOCITY_FACTOR = 20.0
_MAX_OBJECT_SPEED = 100.0
# A held object's joint limits act within this many steps (MuJoCo's stiffest stable time constant is 2 dt),
# so that the stuck door yields by about a milliradian under the robot's pull instead of centimetres.
_HOLD_TIME_CONSTANT_STEPS = 2.0


# -- the plant ------------------------------------------------------------------------------------
def _within_effort(bias: np.ndarray, drive: np.ndarray, effort: np.ndarray) -> tuple[np.ndarray, float]:
    """(bias + s · drive, s) with the largest s ≤ 1 that keeps every joint within its effort limit, clamped.

    Scaling the whole servo torque keeps the commanded joint accelerations' direction: clamping joint by
    joint instead turns a decoupled command into a coupled one (a saturated wrist joint lets the shoulder's
    torque swing the wrist), and under commands that jump (the planner's samples held step by step) the arm
    is then thrown about faster and faster until the integration diverges."""
    with np.errstate(divide="ignore", invalid="ignore"):
        room = np.where(drive > 0.0, (effort - bias) / drive, np.where(drive < 0.0, (-effort - bias) / drive, np.inf))
    scale = float(np.clip(np.min(room), 0.0, 1.0))
    return np.clip(bias + scale * drive, -effort, effort), scale


def _full_mass_matrix(mujoco: Any, model: Any, data: Any, out: np.ndarray) -> None:
    """MuJoCo's joint-space mass matrix at data's state into ``out`` (nv, nv), in MuJoCo 3's and 4's calls."""
    try:
        mujoco.mj_fullM(model, data, out)
    except TypeError:
        mujoco.mj_fullM(model, out, data.qM)


@dataclass
class _Readings:
    """What the last step measured: contact flag, τ_ext, wrist wrench and the contact points."""

    contact: bool
    tau_ext: np.ndarray
    wrench: np.ndarray
    points: list[ContactPoint]


class MujocoPlant:
    """A second 1 kHz plant in MuJoCo, independent of sabre's Rapier physics: the same robot and object URDFs
    read by MuJoCo's own importer, MuJoCo's rigid-body dynamics, contact solver and joint constraints.

    Built from ``scene`` (a :class:`sabre.Scene`, or a built-in object's name for ``Scene.load(obj=name)``):
    the robot and object URDFs are the built-in assets (:mod:`sabre.assets`) when the scene's names are built
    in, else ``robot_urdf`` and ``object_urdf`` (paths; meshes are found as sabre finds them). The object is
    attached to the world at :attr:`Scene.object_pose`; every URDF link stays a MuJoCo body (``fusestatic``
    off) named as in the URDF (the object's with :data:`sabre.mujoco.OBJECT_PREFIX`); capsules written as a cylinder with a
    sphere on each end cap are the three geoms MuJoCo reads; joint limits, damping and dry friction
    (``frictionloss``) are the importer's reading of ``<limit>`` and ``<dynamics>``. A model that disagrees
    with the scene (limits, the object's damping or friction, frame poses) raises :class:`InvalidValueError`.
    Contacts: robot against object only (as in :class:`sabre.Plant`), friction ``contact_friction``, MuJoCo's
    default soft contacts, the implicit-fast integrator at ``dt``.

    **Velocity interface** (:attr:`command_interface` ``"velocity"``): :meth:`step` takes joint velocity
    commands u (nu,), projected onto the velocity limits, and a joint-space servo turns them into joint
    torques, τ = M(q) (u̇ + Λ_D (u − q̇) + Λ_I ∫(u − q̇)) + A (Λ_D (u − q̇) + Λ_I ∫(u − q̇)) + b(q, q̇), clamped to
    the effort limits: M and b (gravity, Coriolis and centrifugal forces, ``qfrc_bias``) are MuJoCo's at the
    step's state, u̇ the difference of consecutive commands, ∫ clipped to ±``servo_integral_limit`` per joint,
    A = diag(max(0, ``gain_inertia_floor`` − M_ii)). Base joints (x, y in m, yaw) are servoed alike. The
    defaults are :class:`sabre.LowLevelController`'s (Λ_D = 40/s, Λ_I = 400/s², ±0.1 rad, no floor): free motion
    follows a command like the rollout model's servo, and contact forces push the joints back through the same
    PI loop as (53) on :class:`sabre.Plant`. Where a joint would exceed its effort limit, the servo's share of
    τ (all but b) is scaled down as a whole, which keeps the commanded accelerations' direction (so a command
    the heavy base cannot follow at once slows the arm with it), and the integral stands still meanwhile.

    **Readings** (as :class:`sabre.Plant`): :attr:`tau_ext` = Σ J_cᵀ f_c over the step's robot–object contacts
    (35), f_c from ``mj_contactForce`` acting on the robot, J_c the robot's point Jacobian at the contact;
    :attr:`measured_tau_ext` its first-order low-pass at ``tau_ext_cutoff`` Hz (None: unfiltered); :attr:`wrench`
    the force (world frame) and torque about the wrist sensor's origin (:attr:`sabre.Scene.wrist_sensor_link`) of
    the contacts on the links at and beyond it. Fault injection: :meth:`hold_object` (a stuck door) and :meth:`push`.
    """

    command_interface = "velocity"

    def __init__(
        self,
        scene: Scene | str,
        dt: float = _PLANT.dt,
        *,
        robot_urdf: str | os.PathLike[str] | None = None,
        object_urdf: str | os.PathLike[str] | None = None,
        contact_friction: float = _PLANT.contact_friction,
        tau_ext_cutoff: float | None = DEFAULT_TAU_EXT_CUTOFF,
        servo_bandwidth: float = _LOW_LEVEL.bandwidth,
        servo_integral_gain: float = _LOW_LEVEL.integral_gain,
        servo_integral_limit: float = _LOW_LEVEL.integral_limit,
        gain_inertia_floor: float = _LOW_LEVEL.gain_inertia_floor,
    ) -> None:
        (mujoco,) = require_extra("mujoco", "sabre.MujocoPlant", "mujoco")
        self._mj = mujoco
        if isinstance(scene, str):
            scene = Scene.load(obj=scene)
        if not isinstance(scene, Scene):
            raise TypeError(f"scene must be a sabre.Scene or a built-in object's name, got {type(scene).__name__}")
        self.scene = scene
        dt = as_positive("dt", dt)
        if dt > 0.005:
            raise InvalidValueError(f"dt: the plant steps at most 0.005 s (a 1 kHz robot: 0.001), got {dt}")
        robot_path = Path(robot_urdf) if robot_urdf is not None else builtin_path(scene.robot_name, ROBOTS, "robot")
        object_path = Path(object_urdf) if object_urdf is not None else builtin_path(scene.object_name, OBJECTS, "object")
        for label, path in (("robot", robot_path), ("object", object_path)):
            if not path.is_file():
                raise UrdfError(f"URDF {path}: {label} file does not exist")
        friction = as_non_negative("contact_friction", contact_friction)
        self.model = compile_model(mujoco, robot_path, object_path, scene.object_pose, dt, friction)
        self.data = mujoco.MjData(self.model)
        self._layout = layout(mujoco, self.model, scene)
        check_against_scene(mujoco, self.model, self._layout, scene)
        self.servo_bandwidth = as_positive("servo_bandwidth", servo_bandwidth)
        self.servo_integral_gain = as_non_negative("servo_integral_gain", servo_integral_gain)
        self.servo_integral_limit = as_non_negative("servo_integral_limit", servo_integral_limit)
        self.gain_inertia_floor = as_non_negative("gain_inertia_floor", gain_inertia_floor)
        cutoff = None if tau_ext_cutoff is None else as_positive("tau_ext_cutoff", tau_ext_cutoff)
        self._blend = 1.0 if cutoff is None else _core.low_pass_blend(cutoff, dt)
        self._object_range = self.model.jnt_range[self._layout.object_joints].copy()
        self._object_solref = self.model.jnt_solref[self._layout.object_joints].copy()
        self._speed_bounds = np.concatenate([_DIVERGENCE_VELOCITY_FACTOR * scene.dq_limit, np.full(scene.no, _MAX_OBJECT_SPEED)])
        self._names = tuple(scene.joint_names) + tuple(scene.object_joint_names)
        self._full = np.zeros(self.model.nv)
        self._product = np.zeros(self.model.nv)
        self._mass = np.zeros((self.model.nv, self.model.nv))
        self._jacobian = np.zeros((3, self.model.nv))
        self._force = np.zeros(6)
        self.reset()

    # -- the protocol ------------------------------------------------------------------------------
    @property
    def dt(self) -> float:
        """Plant step (s)."""
        return float(self.model.opt.timestep)

    @property
    def time(self) -> float:
        """Simulated time since the last :meth:`reset` (s)."""
        return self._steps * self.dt

    @property
    def state(self) -> np.ndarray:
        """(nx,) current state [q, q̇, o, ȯ]."""
        lay, d = self._layout, self.data
        return np.concatenate([d.qpos[lay.robot_qpos], d.qvel[lay.robot_dofs], d.qpos[lay.object_qpos], d.qvel[lay.object_dofs]])

    @property
    def tau_ext(self) -> np.ndarray:
        """(nq,) external joint torques of the last step, τ_ext = Σ J_cᵀ f_c (35)."""
        return self._readings.tau_ext.copy()

    @property
    def measured_tau_ext(self) -> np.ndarray:
        """(nq,) :attr:`tau_ext` through a first-order low-pass at ``tau_ext_cutoff`` Hz."""
        return self._measured.copy()

    @property
    def wrench(self) -> np.ndarray:
        """(6,) wrist force-torque reading of the last step (on the hand and hook, world frame)."""
        return self._readings.wrench.copy()

    @property
    def contact(self) -> bool:
        """Whether any robot–object contact carried force in the last step."""
        return self._readings.contact

    @property
    def applied_torque(self) -> np.ndarray:
        """(nq,) joint torques the servo applied in the last step, after the effort limits."""
        return self._applied.copy()

    @property
    def object_held(self) -> bool:
        """Whether the object is held in place by :meth:`hold_object` (fault injection)."""
        return self._held

    def contacts(self) -> list[ContactPoint]:
        """Every robot–object contact point of the last step, with the force it put on the robot (world frame)."""
        return list(self._readings.points)

    def reset(self, x0: Sequence[float] | np.ndarray | None = None) -> None:
        """Puts the plant at x0 (nx,) (default: the scene's default state), time 0, servo and measurement
        cleared, object released.

        Raises:
            ShapeError: x0 is not (nx,). InvalidValueError: non-finite x0, a joint more than 0.05 (rad or m)
            beyond its limits, or a joint faster than the plant's divergence bound.
        """
        scene = self.scene
        x0 = scene.default_state() if x0 is None else as_float_array("x0", x0, (scene.nx,))
        self._check_within_limits(x0)
        self._mj.mj_resetData(self.model, self.data)
        self._release()
        self._set_state(x0)
        self._steps = 0
        self._integral = np.zeros(scene.nq)
        self._previous: np.ndarray | None = None
        self._applied = np.zeros(scene.nq)
        self._measured = np.zeros(scene.nq)
        self._readings = _Readings(False, np.zeros(scene.nq), np.zeros(6), [])

    def step(self, command: Sequence[float] | np.ndarray) -> None:
        """Advances one step of dt with the robot servoing the joint velocity command (nu,) (rad/s, m/s for the
        base translation), projected onto the velocity limits.

        Raises:
            ShapeError: command is not (nu,). InvalidValueError: non-finite command.
            SimulationError: the step diverged (non-finite state, MuJoCo's instability warning, or a joint
            faster than the divergence bound); reset the plant.
        """
        u = np.clip(as_float_array("command", command, (self.scene.nu,)), -self.scene.dq_limit, self.scene.dq_limit)
        mj, model, data = self._mj, self.model, self.data
        unstable = int(data.warning[mj.mjtWarning.mjWARN_BADQACC].number)
        mj.mj_step1(model, data)
        self._applied = self._servo_torque(u)
        data.qfrc_applied[:] = 0.0
        data.qfrc_applied[self._layout.robot_dofs] = self._applied
        mj.mj_step2(model, data)
        self._steps += 1
        self._check_step(unstable)
        self._readings = self._measure()
        self._measured += self._blend * (self._readings.tau_ext - self._measured)

    def hold_object(self, flag: bool) -> None:
        """Fault injection: ``True`` holds the object's joint where it is (a stuck door): its limits close on
        its position, stiff, and its velocity is zeroed; ``False`` releases it to its URDF limits."""
        lay = self._layout
        if flag:
            o = self.data.qpos[lay.object_qpos]
            self.model.jnt_range[lay.object_joints] = np.column_stack([o, o])
            self.model.jnt_solref[lay.object_joints] = [_HOLD_TIME_CONSTANT_STEPS * self.dt, 1.0]
            self.data.qvel[lay.object_dofs] = 0.0
            self._held = True
        else:
            self._release()

    def push(self, dv: Sequence[float] | np.ndarray) -> None:
        """Fault injection: adds ``dv`` (nq + no,: robot joints, then object joints; rad/s or m/s) to the joint
        velocities now. Raises InvalidValueError if the resulting speeds leave the plant's range."""
        dv = as_float_array("dv", dv, (self.scene.nq + self.scene.no,))
        x = self.state
        parts = self.scene.split_state(x)
        parts.q_dot[:] += dv[: self.scene.nq]
        parts.o_dot[:] += dv[self.scene.nq :]
        self._check_within_limits(x)
        self._set_state(x)

    # -- internals -----------------------------------------------------------------------------------
    def _release(self) -> None:
        lay = self._layout
        self.model.jnt_range[lay.object_joints] = self._object_range
        self.model.jnt_solref[lay.object_joints] = self._object_solref
        self._held = False

    def _set_state(self, x: np.ndarray) -> None:
        lay, d = self._layout, self.data
        q, q_dot, o, o_dot = self.scene.split_state(x)
        d.qpos[lay.robot_qpos], d.qvel[lay.robot_dofs] = q, q_dot
        d.qpos[lay.object_qpos], d.qvel[lay.object_dofs] = o, o_dot

    def _servo_torque(self, u: np.ndarray) -> np.ndarray:
        """The velocity servo's joint torques for command u at the state mj_step1 just evaluated; the integral
        stands still while the effort limits scale the torque down (anti-windup)."""
        lay, data, dt = self._layout, self.data, self.dt
        error = u - data.qvel[lay.robot_dofs]
        integral = np.clip(self._integral + error * dt, -self.servo_integral_limit, self.servo_integral_limit)
        feedback = self.servo_bandwidth * error + self.servo_integral_gain * integral
        feedforward = np.zeros_like(u) if self._previous is None else (u - self._previous) / dt
        self._previous = u
        self._full[:] = 0.0
        self._full[lay.robot_dofs] = feedforward + feedback
        self._mj.mj_mulM(self.model, data, self._product, self._full)
        drive = self._product[lay.robot_dofs]
        if self.gain_inertia_floor > 0.0:
            _full_mass_matrix(self._mj, self.model, data, self._mass)
            inertia = np.diag(self._mass)[lay.robot_dofs]
            drive = drive + np.maximum(0.0, self.gain_inertia_floor - inertia) * feedback
        torque, scale = _within_effort(data.qfrc_bias[lay.robot_dofs], drive, self.scene.effort_limit)
        if scale == 1.0:
            self._integral = integral
        return torque

    def _measure(self) -> _Readings:
        """The contact forces of the step just taken, on the robot: τ_ext (35), the wrist wrench, the points.

        After mj_step2 the kinematics and contacts are still those of the step's start, where the solver
        computed the forces, so each force is mapped through the Jacobian at its own point."""
        mj, model, data, lay = self._mj, self.model, self.data, self._layout
        tau = np.zeros(self.scene.nq)
        wrench = np.zeros(6)
        points: list[ContactPoint] = []
        sensor = data.xpos[lay.sensor_body]
        for i in range(data.ncon):
            contact = data.contact[i]
            bodies = model.geom_bodyid[contact.geom1], model.geom_bodyid[contact.geom2]
            robot_side = [lay.is_robot_body[b] for b in bodies]
            if contact.efc_address < 0 or robot_side[0] == robot_side[1]:
                continue
            mj.mj_contactForce(model, data, i, self._force)
            if self._force[0] <= 0.0:
                continue
            # the force is the one geom1 exerts on geom2, in the contact frame (rows: normal, two tangents)
            on_second = contact.frame.reshape(3, 3).T @ self._force[:3]
            robot, other = (bodies[1], bodies[0]) if robot_side[1] else (bodies[0], bodies[1])
            force = on_second if robot_side[1] else -on_second
            point = np.array(contact.pos, dtype=np.float64)
            mj.mj_jac(model, data, self._jacobian, None, point, robot)
            tau += self._jacobian[:, lay.robot_dofs].T @ force
            if lay.is_sensor_body[robot]:
                wrench += np.concatenate([force, np.cross(point - sensor, force)])
            points.append(ContactPoint(lay.link_names[robot], lay.link_names[other], point, force))
        return _Readings(bool(points), tau, wrench, points)

    def _check_step(self, unstable_before: int) -> None:
        mj, data = self._mj, self.data
        x = self.state
        if int(data.warning[mj.mjtWarning.mjWARN_BADQACC].number) > unstable_before or not np.isfinite(x).all():
            raise SimulationError(f"the MuJoCo plant became unstable at t = {self.time:.3f} s; reset the plant")
        parts = self.scene.split_state(x)
        speeds = np.abs(np.concatenate([parts.q_dot, parts.o_dot]))
        fast = np.flatnonzero(speeds > self._speed_bounds)
        if fast.size:
            i = int(fast[0])
            raise SimulationError(
                f"the MuJoCo plant diverged at t = {self.time:.3f} s: joint {self._names[i]!r} moves at {speeds[i]:.3e} "
                f"(bound {self._speed_bounds[i]}); reset the plant"
            )

    def _check_within_limits(self, x: np.ndarray) -> None:
        scene = self.scene
        q, q_dot, o, o_dot = scene.split_state(x)
        position = np.concatenate([q, o])
        lower = np.concatenate([scene.q_lower, scene.o_lower]) - _RESET_LIMIT_TOLERANCE
        upper = np.concatenate([scene.q_upper, scene.o_upper]) + _RESET_LIMIT_TOLERANCE
        for i in np.flatnonzero((position < lower) | (position > upper)):
            raise InvalidValueError(f"x: joint {self._names[i]!r} at {position[i]} is outside its limits (by more than 0.05)")
        speed = np.abs(np.concatenate([q_dot, o_dot]))
        for i in np.flatnonzero(speed > self._speed_bounds):
            raise InvalidValueError(f"x: joint {self._names[i]!r} moves at {speed[i]}, beyond the plant's range")

    def __repr__(self) -> str:
        return f"MujocoPlant({self.scene!r}, dt={self.dt})"
