"""The floor under the bridge's latency: a bare rclpy round trip between two processes.

One process publishes a 10-joint JointState at 1 kHz from a SCHED_FIFO thread, the other answers
each with a JointState carrying the same stamp, both with the executor and GIL settings of the
bridge's nodes (sabre.ros.make_executor, GIL_SWITCH_INTERVAL, the Fast DDS profile of
sabre.ros.realtime_middleware unless --no-profile); prints the round trip's p50, p99
and max over the messages after the first 500. Loopback only, a private ROS_DOMAIN_ID.

    .venv/bin/python benches/ros_echo.py --seconds 10
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import threading
import time

import numpy as np


def run(role: str, seconds: float, profile: bool) -> None:
    from sabre.ros import GIL_SWITCH_INTERVAL, make_executor, realtime_middleware, realtime_thread, require_ros

    rclpy = require_ros()
    if profile:
        realtime_middleware()
    from sensor_msgs.msg import JointState

    rclpy.init()
    node = rclpy.create_node(f"sabre_echo_{role}")
    sys.setswitchinterval(GIL_SWITCH_INTERVAL)
    realtime_thread(70)
    executor = make_executor(rclpy)
    executor.add_node(node)
    if role == "echo":
        pub = node.create_publisher(JointState, "/sabre_echo/back", 10)
        out = JointState()

        def answer(msg: JointState) -> None:
            out.header.stamp = msg.header.stamp
            out.velocity = list(msg.position)
            pub.publish(out)

        node.create_subscription(JointState, "/sabre_echo/state", answer, 10)
        end = time.monotonic() + seconds + 6.0
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
        return
    pub = node.create_publisher(JointState, "/sabre_echo/state", 10)
    latency: list[float] = []

    def back(msg: JointState) -> None:
        s = msg.header.stamp
        latency.append(time.time() - (s.sec + 1e-9 * s.nanosec))

    node.create_subscription(JointState, "/sabre_echo/back", back, 10)

    def publish() -> None:
        realtime_thread(80)
        m = JointState()
        m.name = [f"joint{i}" for i in range(10)]
        start, k = time.monotonic(), 0
        while time.monotonic() - start < seconds:
            k += 1
            m.header.stamp = node.get_clock().now().to_msg()
            m.position = [float(i) for i in range(10)]
            pub.publish(m)
            rest = start + k * 0.001 - time.monotonic()
            if rest > 0:
                time.sleep(rest)

    time.sleep(2.0)  # discovery
    thread = threading.Thread(target=publish)
    thread.start()
    while thread.is_alive():
        executor.spin_once(timeout_sec=0.05)
    ms = np.array(latency[500:]) * 1e3
    print(
        f"{len(latency)} answers; round trip p50 {np.percentile(ms, 50):.3f} ms, p99 {np.percentile(ms, 99):.3f} ms, "
        f"max {ms.max():.2f} ms"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument(
        "--no-profile", action="store_true", help="without sabre's Fast DDS profile (the receive threads under normal scheduling)"
    )
    parser.add_argument("--role", choices=("source", "echo"), default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.role is not None:
        run(args.role, args.seconds, not args.no_profile)
        return
    from sabre.ros.launch import Domain, ros_environment

    with Domain() as domain:
        env = ros_environment(domain.id)
        flags = ["--seconds", str(args.seconds)] + (["--no-profile"] if args.no_profile else [])
        echo = subprocess.Popen([sys.executable, __file__, "--role", "echo"] + flags, env=env)
        try:
            subprocess.run([sys.executable, __file__, "--role", "source"] + flags, env=env, check=True)
        finally:
            echo.wait(args.seconds + 30.0)


if __name__ == "__main__":
    main()
