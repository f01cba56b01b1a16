"""The core's rcl endpoints (the sabre-rcl crate behind `SimDriver.connect`) on real rcl and DDS, on a
private, machine-local domain: what an rclpy publisher sends is what the core takes, what the core
publishes is what an rclpy subscription receives, and the checks that guard the private handle and
the layouts refuse what they cannot vouch for."""

from __future__ import annotations

import os
import time

import numpy as np
import pytest

from sabre import _core
from sabre.errors import SabreError

rclpy = pytest.importorskip("rclpy", reason="the ROS 2 extra sabre-mpc[ros] (make test installs it)")

from sabre.ros import direct  # noqa: E402
from sabre.ros.launch import Domain  # noqa: E402
from sabre.ros.qos import profile  # noqa: E402

DEADLINE = 60.0  # s: a bound for conditions on a loaded machine, never asserted as a duration

try:
    _core.rcl_built_against()
    BUILT_WITH_RCL = True
except SabreError:
    BUILT_WITH_RCL = False
needs_rcl = pytest.mark.skipif(not BUILT_WITH_RCL, reason="sabre was built without the ROS 2 headers")


def wait_for(condition, what, spin=None):
    deadline = time.monotonic() + DEADLINE
    while time.monotonic() < deadline:
        if spin is not None:
            spin()
        value = condition()
        if value:
            return value
        time.sleep(0.002)
    raise AssertionError(f"timed out waiting for {what}")


@pytest.fixture
def context(monkeypatch):
    domain = Domain()
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain.id))
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    yield ctx
    ctx.try_shutdown()
    domain.release()


def driver(na: int) -> _core.SimDriver:
    names = [f"j{i}" for i in range(na)]
    return _core.SimDriver(na, list(range(na)), None, 1.0, 0.001, names, [], 0.0, 0.0, 0, False, 16)


@needs_rcl
def test_commands_published_by_rclpy_are_taken_and_states_published_by_the_core_are_received(context):
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    # the core's endpoints on a node no executor waits on, the peer's on another
    core_node = rclpy.create_node("sabre_direct_core", context=context)
    peer = rclpy.create_node("sabre_direct_peer", context=context)
    executor = rclpy.executors.SingleThreadedExecutor(context=context)
    executor.add_node(peer)
    received: list = []
    peer.create_subscription(JointState, "states", received.append, profile("reliable:100"))
    commands = peer.create_publisher(Float64MultiArray, "commands", profile("reliable:100"))
    sub = core_node.create_subscription(Float64MultiArray, "commands", lambda _: None, profile("reliable:100"), raw=True)
    pub = core_node.create_publisher(JointState, "states", profile("reliable:100"))
    d = driver(3)
    d.connect(direct.rcl_functions(), (sub, direct.handle_address(sub)), (pub, direct.handle_address(pub)))

    wait_for(lambda: commands.get_subscription_count() and pub.get_subscription_count(), "discovery")
    sent = [np.array([0.1, -0.2, 0.3]), np.array([0.15, -0.25, 0.35]), np.array([0.2, -0.3, 0.4])]
    for v in sent:
        commands.publish(Float64MultiArray(data=list(v)))
    taken = []

    def tick():
        u, _ = d.tick(0.0, 0.0, time.monotonic(), time.time(), np.zeros(3))
        taken.append(u.copy())
        return d.counts()["arm_commands"] >= len(sent)

    wait_for(tick, "the three commands taken through rcl")
    assert d.counts()["arm_commands"] == len(sent)  # each taken once, none invented
    np.testing.assert_array_equal(taken[-1], sent[-1])  # the newest one is in force
    step, step_change, speed, _ = d.arm_record()
    # taken in the order published: equal steps of 0.05 (any other order changes a step by 0.1 or more)
    np.testing.assert_allclose(step, [0.05, 0.05, 0.05], atol=1e-12)
    np.testing.assert_allclose(step_change, 0.0, atol=1e-12)
    np.testing.assert_allclose(speed, [0.2, 0.3, 0.4], atol=0)

    q, dq = np.array([0.5, -1.0, 1.5]), np.array([0.01, 0.02, -0.03])
    stamp = time.time_ns()  # the robot stamps its states with the wall clock; round trips start there
    assert d.publish_state(q, dq, stamp) is None  # published, not handed back
    wait_for(lambda: received, "the joint state published through rcl", spin=lambda: executor.spin_once(timeout_sec=0.01))
    msg = received[0]
    assert list(msg.name) == ["j0", "j1", "j2"]
    np.testing.assert_array_equal(msg.position, q)
    np.testing.assert_array_equal(msg.velocity, dq)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == divmod(stamp, 1_000_000_000)

    # an answer naming that state: its round trip ends at rmw's reception time, read from the
    # message info at the headers' offset, so it lies between the state's publication and now
    answer = Float64MultiArray(data=[0.2, -0.3, 0.4])
    answer.layout.data_offset = stamp % 1_000_000_000
    commands.publish(answer)
    wait_for(lambda: tick() and d.counts()["arm_commands"] > len(sent), "the answer taken through rcl")
    latencies = d.take_latencies()
    assert len(latencies) == 1
    assert 0.0 <= latencies[0] <= time.time() - stamp * 1e-9

    d.disconnect()  # the endpoints may go after this
    assert d.publish_state(q, dq, 0) is not None
    core_node.destroy_node()
    peer.destroy_node()


def test_another_release_of_rcl_than_the_build_checked_is_refused(monkeypatch):
    import rclpy as _  # noqa: F401  (loads rcl)

    monkeypatch.setattr(direct._core, "rcl_built_against", lambda: ("/opt/ros/old", [("rcl", "1.2.0")]))
    loaded = direct.loaded_versions(("rcl",))["rcl"]
    with pytest.raises(SabreError, match=rf"rcl 1\.2\.0 .*loaded rcl {loaded}"):
        direct.rcl_functions()


def test_another_patch_of_the_release_the_build_checked_is_accepted(monkeypatch):
    """Layouts change between releases (major.minor), not between their patches: a build checked against
    another patch of each loaded library's release looks the functions up."""
    import rclpy as _  # noqa: F401  (loads rcl)

    def patched(version: str) -> str:
        major, minor, patch = version.split(".")
        return f"{major}.{minor}.{int(patch) + 1}"

    loaded = direct.loaded_versions()
    built = [(package, patched(version)) for package, version in loaded.items()]
    monkeypatch.setattr(direct._core, "rcl_built_against", lambda: ("/opt/ros/other", built))
    assert len(direct.rcl_functions()) == len(_core.rcl_function_names())


def test_a_build_without_the_ros_headers_says_how_to_get_them(monkeypatch):
    def missing():
        raise SabreError("sabre was built without the ROS 2 headers")

    monkeypatch.setattr(direct._core, "rcl_built_against", missing)
    with pytest.raises(SabreError, match="without the ROS 2 headers"):
        direct.rcl_functions()


def test_an_endpoint_without_an_rcl_handle_is_refused():
    with pytest.raises(SabreError, match="no rcl handle"):
        direct.handle_address(object())


def test_the_loaded_releases_are_read_beside_the_libraries():
    import rclpy as _  # noqa: F401

    versions = direct.loaded_versions()
    assert set(versions) == {"rcl", "rcutils", "rmw"}
    assert all(v.count(".") == 2 and v.replace(".", "").isdigit() for v in versions.values())
    assert os.path.exists("/proc/self/maps")
