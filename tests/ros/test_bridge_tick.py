"""The bridge's 1 kHz path in the core without a ROS process: the serialized messages against
rclpy's own serializer, and ``_core.BridgeTick`` against the same pipeline built from its Python
pieces (the merge, the estimator, the inner loop and the gate, called one by one)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import sabre
from sabre import _core
from sabre.realtime import RealtimeCascade
from sabre.ros.commands import CommandGate, CommandShaper, command_limits
from sabre.ros.conversions import world_to_base
from sabre.ros.inputs import JointStates

NO_EFFORT = np.zeros(0)


def test_messages_match_rclpys_serialization_both_ways():
    pytest.importorskip("rclpy")
    from geometry_msgs.msg import Twist, TwistStamped
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    rng = np.random.default_rng(3)
    for n in (0, 1, 9, 12):
        names = [f"joint_{'x' * k}{k}" for k in range(n)]  # names of every length mod 4
        p, v, e = rng.normal(size=n), rng.normal(size=n), rng.normal(size=n if n % 2 else 0)
        stamp_ns = int(rng.integers(0, 2**31 - 1)) * 10**9 + int(rng.integers(0, 10**9))
        raw = _core.encode_joint_state(stamp_ns, "frame_" * (n % 3), names, p, v, e)
        m = deserialize_message(raw, JointState)
        assert (m.header.stamp.sec * 10**9 + m.header.stamp.nanosec, m.header.frame_id) == (stamp_ns, "frame_" * (n % 3))
        assert list(m.name) == names and np.array_equal(m.position, p) and np.array_equal(m.velocity, v)
        assert np.array_equal(m.effort, e)
        stamp, frame, back_names, bp, bv, be = _core.decode_joint_state(serialize_message(m))
        assert (stamp, frame, back_names) == (stamp_ns, m.header.frame_id, names)
        assert np.array_equal(bp, p) and np.array_equal(bv, v) and np.array_equal(be, e)
    data = rng.normal(size=7)
    m = deserialize_message(_core.encode_float64_array(data, 12345), Float64MultiArray)
    assert np.array_equal(m.data, data) and m.layout.data_offset == 12345 and not m.layout.dim
    back, offset = _core.decode_float64_array(serialize_message(m))
    assert np.array_equal(back, data) and offset == 12345
    m = deserialize_message(_core.encode_twist([1.0, 2.0, 3.0], [4.0, 5.0, 6.0]), Twist)
    assert (m.linear.x, m.linear.y, m.linear.z, m.angular.x, m.angular.y, m.angular.z) == (1.0, 2.0, 3.0, 4.0, 5.0, 6.0)
    ms = deserialize_message(_core.encode_twist([0.5, 0.0, 0.0], [0.0, 0.0, -0.5], 7 * 10**9 + 8, "base_link"), TwistStamped)
    assert (ms.header.stamp.sec, ms.header.stamp.nanosec, ms.header.frame_id, ms.twist.angular.z) == (7, 8, "base_link", -0.5)
    assert _core.decode_twist(serialize_message(ms), True) == ([0.5, 0.0, 0.0], [0.0, 0.0, -0.5], 7 * 10**9 + 8)


@pytest.mark.parametrize("raw", [b"", b"\x00\x01\x00\x00\x05", b"\x00\x07\x00\x00" + bytes(40), bytes(3)])
def test_malformed_messages_raise_sabre_errors(raw):
    with pytest.raises(sabre.SabreError):
        _core.decode_joint_state(raw)
    with pytest.raises(sabre.SabreError):
        _core.decode_float64_array(raw)


class Pipeline:
    """A BridgeTick on the shelf and the same pipeline's Python pieces, fed the same states."""

    def __init__(self) -> None:
        scene = sabre.Scene.load(obj="shelf")
        self.scene, self.nq = scene, scene.nq
        self.names = list(scene.joint_names)
        self.base = list(scene.base_indices)
        self.arm = [i for i in range(self.nq) if i not in self.base]

        def controller() -> sabre.Controller:
            return sabre.Controller(scene, sabre.tasks.OpenObject(), sabre.ControllerConfig(seed=0, variant="IO"))

        frames = ("map", scene.wrist_sensor_link, "")
        self.cascade = RealtimeCascade(controller(), tau_ext_cutoff=10.0, tau_ext_timeout=0.1, wrench_frames=frames)
        self.x = sabre.paper.paper_start_state(scene)
        self.cascade.plan(self.x, 0.0)
        # the same plan on stages of their own: the reference the tick's cascade is compared with
        self.reference = RealtimeCascade(controller())
        assert self.cascade.current_plan is not None
        self.reference.hand_over(self.cascade.current_plan)
        limits = command_limits(
            scene.dq_limit[self.arm], scene.dq_limit[self.base], {"command_period": 1e-3, "cmd_vel_rate": 250.0}
        )
        arm_names = [self.names[i] for i in self.arm]
        joints = JointStates(self.names, arm_names, 0.05)
        self.gate = CommandGate(CommandShaper(limits), 0.05)  # the reference's: the tick takes a copy
        estimator = sabre.ObjectStateEstimator(scene)
        self.estimator = sabre.ObjectStateEstimator(scene)
        self.cascade.core.set_shaping(self.gate.core, self.arm, self.base)
        self.tick = _core.BridgeTick(
            self.cascade.core,
            joints.core,
            estimator.core,
            [0.0],
            [0.0],
            0.005,
            False,
            "",
            arm_names,
        )

    def state(self, k: int, q: np.ndarray, qd: np.ndarray, names: list[str] | None = None) -> bytes:
        return _core.encode_joint_state(10**9 + k * 10**6, "", names or self.names, q, qd, NO_EFFORT)


def test_the_core_tick_is_the_pipeline_of_its_python_pieces():
    """Over states scattered about the start: the same object estimate, the same inner-loop command,
    the same rate-limited arm and base commands (bit for bit), the answered stamp in data_offset."""
    pytest.importorskip("rclpy")
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    s = Pipeline()
    nq, x = s.nq, s.x.copy()
    horizon = s.cascade.controller.config.horizon
    rng = np.random.default_rng(0)
    for k in range(60):
        q, qd = x[:nq] + 1e-3 * k * rng.normal(size=nq), x[nq : 2 * nq] + 0.01 * rng.normal(size=nq)
        received = 1e-3 * k
        kind, t, error = s.tick.receive(s.state(k, q, qd), received)
        assert (kind, error) == ("tick", None) and t == pytest.approx(1e-3 * k)
        reason, answer, xs, energy, status = s.tick.follow(t, received, True, horizon)
        assert reason is None and answer is not None
        arm, base, echo, segment = answer
        assert segment is None  # the velocity stream: no segments
        e = s.estimator.update(q, t, math.inf, may_hook=True)
        expected_x = np.concatenate([q, qd, e.position, e.velocity])
        assert np.array_equal(xs, expected_x)
        # states 1 ms apart; the first integrates over one command period (1 ms too)
        r = s.reference.tick(expected_x, np.zeros(nq), t, 1e-3)
        u = r.command
        assert (energy, status) == (r.tank_energy, r.status)
        step = s.gate.on_tick(received, u[s.arm], np.asarray(world_to_base(u[s.base], q[s.base[2]])))
        m = deserialize_message(arm, Float64MultiArray)
        assert np.array_equal(m.data, step.arm) and m.layout.data_offset == (k * 10**6) % 10**9
        assert (base is None) == (step.base is None)
        if base is not None:
            b = _core.decode_twist(base, False)
            assert np.array_equal([b[0][0], b[0][1], b[1][2]], step.base)
        assert np.array_equal(deserialize_message(echo, JointState).velocity, step.arm)


def test_fingers_merge_bad_states_get_ramp_steps_and_a_stale_joint_stops_following():
    s = Pipeline()
    nq, x = s.nq, s.x
    q, qd = x[:nq].copy(), x[nq : 2 * nq].copy()
    fingers = _core.encode_joint_state(10**9, "", ["finger_1", "finger_2"], np.zeros(2), np.zeros(2), NO_EFFORT)
    assert s.tick.receive(fingers, 0.0)[0] == "merged"
    assert s.tick.receive(s.state(1, q, qd), 0.001)[0] == "tick"
    assert s.tick.receive(s.state(1, q, qd), 0.002)[0] == "rejected-tick"  # the same stamp again
    bad = q.copy()
    bad[4] = math.nan
    kind, _, error = s.tick.receive(s.state(2, bad, qd), 0.003)
    assert kind == "rejected-tick" and "non-finite" in error
    assert s.tick.receive(b"\x00\x01\x00\x00", 0.004)[0] == "rejected-tick"  # unreadable: still answered
    arm, _, _, _ = s.tick.stop(0.004)
    assert np.array_equal(_core.decode_float64_array(arm)[0], np.zeros(len(s.arm)))  # at rest: zero
    assert s.tick.counts["rejected"] == 3
    # the base's joints are not in the arm's messages: they go stale after their timeout
    arm_only = [s.names[i] for i in s.arm]
    assert s.tick.receive(s.state(3, q[s.arm], qd[s.arm], arm_only), 0.010)[0] == "tick"
    assert s.tick.receive(s.state(4, q[s.arm], qd[s.arm], arm_only), 0.100)[0] == "stale"


def test_wrenches_read_in_the_core_give_the_python_frames_tau_ext():
    """τ_ext from a serialized WrenchStamped equals J(q)ᵀ w computed here
    (NumPy on the scene's kinematics) for a header in the world frame, in the sensor's, in another
    robot frame and empty; an unknown frame is refused and changes nothing."""
    pytest.importorskip("rclpy")
    from geometry_msgs.msg import WrenchStamped
    from rclpy.serialization import serialize_message

    from sabre.ros.inputs import WrenchFrames

    s = Pipeline()
    nq, x = s.nq, s.x
    q = x[:nq] + 0.05
    assert s.tick.receive(s.state(1, q, x[nq : 2 * nq]), 0.0)[0] == "tick"
    reference = WrenchFrames(s.scene, "map", s.scene.wrist_sensor_link)
    rng = np.random.default_rng(5)
    for k, frame in enumerate(["map", s.scene.wrist_sensor_link, "panda_link5", ""]):
        w = rng.normal(size=6) * 10.0
        m = WrenchStamped()
        m.header.frame_id = frame
        m.wrench.force.x, m.wrench.force.y, m.wrench.force.z = (float(v) for v in w[:3])
        m.wrench.torque.x, m.wrench.torque.y, m.wrench.torque.z = (float(v) for v in w[3:])
        s.tick.set_wrench(serialize_message(m), 0.0)
        axes, point = reference.resolve(frame)
        # J(q)ᵀ w by hand: the wrench turned into world axes, about the point frame's origin
        r = np.eye(3) if axes is None else s.scene.fk(q, axes)[:3, :3]
        expected = s.scene.jacobian(q, point).T @ np.concatenate([r @ w[:3], r @ w[3:]])
        assert s.tick.counts["wrench_received"] == k + 1
        assert np.allclose(s.cascade.core.tau_ext, expected, atol=1e-9), frame
    m = WrenchStamped()
    m.header.frame_id = "nowhere"
    with pytest.raises(sabre.SabreError, match="nowhere"):
        s.tick.set_wrench(serialize_message(m), 0.0)
    assert s.tick.counts["wrench_received"] == 4
