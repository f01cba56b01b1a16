"""The simulated robot's joint_trajectory_controller on trajectories serialized by rclpy (an
independent writer of the message): what the arm is commanded at each cycle against the analytic
polynomial the points were sampled from, the stamp's wait, the hold at the end, JTC's refusals, and
what the robot reports of the cycles it saw."""

from __future__ import annotations

import numpy as np
import pytest

from sabre import _core
from sabre.ros.durations import gap_percentiles

pytest.importorskip("rclpy", reason="the ROS 2 extra sabre-mpc[ros] (make test installs it)")
from builtin_interfaces.msg import Duration, Time
from rclpy.serialization import serialize_message
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

NAMES = ["j0", "j1"]
GAIN = 4.0


def driver() -> _core.SimDriver:
    return _core.SimDriver(2, [0, 1], None, 0.05, 0.001, NAMES, [], 0.0, 0.0, 0, False, 16, None, [GAIN, GAIN])


def trajectory(points, stamp=0.0, names=("j1", "j0")) -> bytes:
    """Points (t, q (2,), v (2,) or None) in sabre's joint order, written in the order ``names``."""
    msg = JointTrajectory(joint_names=list(names))
    sec = int(stamp)
    msg.header.stamp = Time(sec=sec, nanosec=int(round((stamp - sec) * 1e9)))
    order = [NAMES.index(n) if n in NAMES else i for i, n in enumerate(names)]
    for t, q, v in points:
        p = JointTrajectoryPoint(positions=[float(q[i]) for i in order])
        if v is not None:
            p.velocities = [float(v[i]) for i in order]
        p.time_from_start = Duration(sec=int(t), nanosec=int(round((t - int(t)) * 1e9)))
        msg.points.append(p)
    return serialize_message(msg)


def cubic(t):
    """Joint 0: 0.1 + 0.5 t − 2 t² + 3 t³; joint 1: −0.2 t²: positions and velocities."""
    q = np.array([0.1 + 0.5 * t - 2 * t**2 + 3 * t**3, -0.2 * t**2])
    v = np.array([0.5 - 4 * t + 9 * t**2, -0.4 * t])
    return q, v


def test_the_arm_is_commanded_the_cubic_through_the_points_plus_the_position_feedback():
    d = driver()
    times = [0.0, 0.02, 0.05, 0.1]
    d.receive_arm(trajectory([(t, *cubic(t)) for t in times]), 0.0, 1000.0)
    assert d.counts()["arm_commands"] == 1 and d.take_events() == ([], [])
    offset = np.array([0.01, -0.02])  # the arm lags its desired position by this much
    for t in np.arange(0.0, 0.1, 0.001):
        q_d, v_d = cubic(t)
        u, _ = d.tick(t, 0.0, 0.0, 1000.0, q_d - offset)
        np.testing.assert_allclose(u, v_d + GAIN * offset, atol=1e-9, err_msg=f"t = {t}")
    q_end, _ = cubic(0.1)
    u, _ = d.tick(0.5, 0.0, 0.0, 1000.0, q_end - offset)
    np.testing.assert_allclose(u, GAIN * offset, atol=1e-12, err_msg="the last point held at rest")


def test_a_stamped_trajectory_waits_for_its_stamp():
    d = driver()
    # in force: joint 0 at 0.3 rad/s along a straight line (positions only: linear)
    d.receive_arm(trajectory([(1.0, [0.3, 0.0], None)]), 0.0, 1000.0)
    np.testing.assert_allclose(d.tick(0.1, 0.0, 0.1, 1000.1, np.array([0.03, 0.0]))[0], [0.3, 0.0], atol=1e-12)
    # stamped 0.25 s after it arrives (wall clock), to hold joint 0 where it will be then
    d.receive_arm(trajectory([(0.25, [0.15, 0.0], [0.0, 0.0])], stamp=1000.375), 0.125, 1000.125)
    np.testing.assert_allclose(d.tick(0.374, 0.0, 0.374, 1000.374, np.array([0.1122, 0.0]))[0], [0.3, 0.0], atol=1e-9)
    u, _ = d.tick(0.625, 0.0, 0.625, 1000.625, np.array([0.15, 0.0]))
    np.testing.assert_allclose(u, [0.0, 0.0], atol=1e-9)


def test_trajectories_jtc_refuses_are_refused_and_the_arm_holds_where_it_was():
    d = driver()
    q0 = np.array([0.2, -0.1])
    d.tick(0.0, 0.0, 0.0, 1000.0, q0)
    for raw in (
        trajectory([(0.1, [0.0, 0.0], None)], names=("j0",)),  # a partial goal
        trajectory([(0.1, [0.0, 0.0], None)], names=("j0", "elbow")),  # another arm's joint
        trajectory([(0.1, [0.0, 0.0], None), (0.05, [0.0, 0.0], None)]),  # time goes back
        trajectory([(0.1, [0.0, 0.0], None)], stamp=990.0),  # ended before it arrived
        b"\x00\x01\x00\x00garbage",
    ):
        d.receive_arm(raw, 0.001, 1000.001)
    rejected, _ = d.take_events()
    assert len(rejected) == 5 and d.counts()["rejected_commands"] == 5
    u, _ = d.tick(0.002, 0.0, 0.002, 1000.002, q0 + np.array([0.01, 0.0]))
    np.testing.assert_allclose(u, [-GAIN * 0.01, 0.0], atol=1e-12, err_msg="held at the first measured position")


def test_the_gaps_between_deliveries_are_reported_in_cycles():
    d = driver()
    q = np.zeros(2)
    raw = trajectory([(1.0, [0.0, 0.0], [0.0, 0.0])])
    delivered_at = [0, 1, 2, 12, 13, 40]
    for k in range(45):
        if k in delivered_at:
            d.receive_arm(raw, k * 0.001, 1000.0 + k * 0.001)
        d.tick(k * 0.001, 0.0, k * 0.001, 1000.0 + k * 0.001, q, excused=k in (30, 31))
    counts = d.delivery_gaps()
    # 0→1, 1→2 one cycle each, 2→12 ten, 12→13 one; 13→40 crosses the robot's own late ticks: not booked
    assert counts[1] == 3 and counts[10] == 1 and counts.sum() == 4
    stats = gap_percentiles(counts, 0.001)
    assert stats["count"] == 4 and stats["p50_ms"] == 1.0 and stats["max_ms"] == 10.0
