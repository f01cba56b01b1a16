"""The bridge's scheduling: sabre's Fast DDS profile puts the middleware's receive and timed-events
threads (and only those) under SCHED_FIFO in a node's process, a user's own profile or another middleware
wins, and the status thread runs its work periodically and survives a failing call."""

from __future__ import annotations

import itertools
import json
import os
import subprocess
import sys
import threading
import time

import pytest

import sabre.ros
from sabre.ros import MIDDLEWARE_PRIORITY, PeriodicThread, realtime_middleware, realtime_thread
from sabre.ros.launch import Domain, ros_environment

THREADS = r"""
import json, os, sys, time
from sabre.ros import realtime_middleware, require_ros
rclpy = require_ros()
chosen = realtime_middleware()
rclpy.init()
node = rclpy.create_node("sabre_profile_probe")
pub = node.create_publisher(__import__("std_msgs.msg").msg.Bool, "/sabre/profile_probe", 10)
need = json.loads(sys.argv[1])  # "prefix|prefix": how many threads so named the test reads


def threads():
    found = []
    for tid in os.listdir("/proc/self/task"):
        try:
            name = open(f"/proc/self/task/{tid}/comm").read().strip()
            policy = os.sched_getscheduler(int(tid)) & 0xFF
            found.append([name, policy, os.sched_getparam(int(tid)).sched_priority])
        except OSError:  # the thread ended meanwhile
            pass
    return found


def started(found):
    names = [t[0] for t in found]
    return all(sum(n.startswith(tuple(p.split("|"))) for n in names) >= k for p, k in need.items())


# The middleware starts its threads as the participant and its endpoints come up: read them once
# those the test checks are there (or after a minute, for the test to report what there was).
deadline = time.monotonic() + 60.0
found = threads()
while not started(found) and time.monotonic() < deadline:
    time.sleep(0.01)
    found = threads()
print("RESULT " + json.dumps({"chosen": chosen, "profile": os.environ.get("FASTDDS_DEFAULT_PROFILES_FILE"), "threads": found}))
node.destroy_node()
rclpy.shutdown()
"""

#: the receive threads' name prefixes (a transport; the port follows)
RECEIVE = ("dds.shm.", "dds.udp.")


def fifo_permitted() -> bool:
    result: list[bool] = []
    probe = threading.Thread(target=lambda: result.append(realtime_thread(1)))
    probe.start()
    probe.join()
    return result[0]


def run_probe(env_changes: dict[str, str | None], need: dict[str, int]) -> dict:
    """Runs THREADS in a node's process with the environment changed; ``need``: the threads it waits
    for (name prefixes, "|" between alternatives, to how many)."""
    pytest.importorskip("rclpy", reason="the ROS 2 extra sabre-mpc[ros] (make test installs it)")
    with Domain() as domain:
        env = ros_environment(domain.id)
        env.pop("FASTDDS_DEFAULT_PROFILES_FILE", None)
        for k, v in env_changes.items():
            if v is None:
                env.pop(k, None)
            else:
                env[k] = v
        out = subprocess.run(
            [sys.executable, "-c", THREADS, json.dumps(need)], capture_output=True, text=True, timeout=120, env=env
        )
    assert out.returncode == 0, out.stdout + out.stderr
    line = next(ln for ln in out.stdout.splitlines() if ln.startswith("RESULT "))
    return json.loads(line[len("RESULT ") :]) | {"output": out.stdout + out.stderr}


def test_the_profile_puts_the_message_path_threads_and_only_them_under_sched_fifo():
    if not fifo_permitted():
        pytest.skip("SCHED_FIFO is not permitted here (no CAP_SYS_NICE or rtprio limit)")
    if not sabre.ros.middleware_thread_settings():
        result = run_probe({}, {})
        assert not result["chosen"]  # Jazzy's Fast DDS 2.14: the profile would change nothing, so none is chosen
        pytest.skip("this Fast DDS does not apply a profile's thread settings (ROS 2 Jazzy)")
    result = run_probe({}, {"|".join(RECEIVE): 2, "dds.ev.": 1, "dds.asyn.": 1})
    assert result["chosen"] and result["profile"] == sabre.ros.MIDDLEWARE_PROFILE
    assert "Error" not in result["output"], result["output"]  # Fast DDS logs a profile it cannot parse
    receive = [t for t in result["threads"] if t[0].startswith(RECEIVE) and t[0].split(".")[-1].isdigit()]
    assert len(receive) >= 2, result["threads"]  # shared memory and UDP, at least one port each
    assert all(policy == os.SCHED_FIFO and priority == MIDDLEWARE_PRIORITY for _, policy, priority in receive), receive
    # the timed-events thread (heartbeats, acknowledgements) locks a writer's history as a publication does
    events = [t for t in result["threads"] if t[0].startswith("dds.ev.")]
    assert events and all(policy == os.SCHED_FIFO and priority == MIDDLEWARE_PRIORITY for _, policy, priority in events), events
    # the asynchronous writers' sender busy-waits during discovery: under SCHED_FIFO it would starve the machine
    senders = [t for t in result["threads"] if t[0].startswith("dds.asyn.")]
    assert senders and all(policy == os.SCHED_OTHER for _, policy, _ in senders), senders
    others = [t for t in result["threads"] if t[0].startswith("dds.") and t not in receive + events]
    assert all(policy == os.SCHED_OTHER for _, policy, _ in others), others


def test_a_users_profile_or_another_middleware_is_left_alone(monkeypatch, tmp_path):
    own = tmp_path / "mine.xml"
    own.write_text("<dds/>")
    monkeypatch.setenv("FASTDDS_DEFAULT_PROFILES_FILE", str(own))
    assert realtime_middleware() is False
    assert os.environ["FASTDDS_DEFAULT_PROFILES_FILE"] == str(own)
    monkeypatch.delenv("FASTDDS_DEFAULT_PROFILES_FILE")
    monkeypatch.setenv("RMW_IMPLEMENTATION", "rmw_cyclonedds_cpp")
    assert realtime_middleware() is False
    assert "FASTDDS_DEFAULT_PROFILES_FILE" not in os.environ


def test_with_a_users_profile_the_receive_threads_keep_normal_scheduling(tmp_path):
    own = tmp_path / "mine.xml"
    own.write_text(
        '<?xml version="1.0" encoding="UTF-8" ?><dds xmlns="http://www.eprosima.com"><profiles>'
        '<participant profile_name="mine" is_default_profile="true"><rtps/></participant></profiles></dds>'
    )
    result = run_probe({"FASTDDS_DEFAULT_PROFILES_FILE": str(own)}, {"|".join(RECEIVE): 1})
    assert not result["chosen"] and result["profile"] == str(own)
    assert "Error" not in result["output"], result["output"]
    receive = [t for t in result["threads"] if t[0].startswith(RECEIVE)]
    assert receive and all(policy == os.SCHED_OTHER for _, policy, _ in receive), receive


def test_periodic_thread_calls_its_work_and_carries_on_after_an_error():
    """The work runs again after the call that raised (its error reported once), and once stop()
    returns the thread has ended: no call can follow, read off the thread list rather than timed."""
    calls: list[float] = []
    errors: list[Exception] = []
    sixth = threading.Event()

    def work():
        calls.append(time.monotonic())
        if len(calls) == 2:
            raise ValueError("status failed once")
        if len(calls) == 6:
            sixth.set()

    name = "sabre-test-periodic"
    thread = PeriodicThread(0.01, work, name, errors.append).start()
    assert name in {t.name for t in threading.enumerate()}
    assert sixth.wait(60.0), f"the work ran {len(calls)} times, not 6, within 60 s"
    thread.stop()
    assert name not in {t.name for t in threading.enumerate()}, "stop() returned with the thread still running"
    assert len(calls) >= 6
    assert len(errors) == 1 and str(errors[0]) == "status failed once"
    assert all(b > a for a, b in itertools.pairwise(calls))


def test_single_threaded_blas_limits_numpys_blas_to_the_calling_thread():
    """After sabre.ros.single_threaded_blas() every BLAS library NumPy loaded reports one thread
    (threadpoolctl's own account of the libraries in this process)."""
    pytest.importorskip("threadpoolctl", reason="the ROS 2 extra sabre-mpc[ros] (make test installs it)")
    import numpy as np
    from threadpoolctl import threadpool_info, threadpool_limits

    np.ones((64, 64)) @ np.ones((64, 64))  # NumPy's BLAS is loaded
    with threadpool_limits(limits=None):  # restores this process's setting afterwards
        sabre.ros.single_threaded_blas()
        blas = [lib for lib in threadpool_info() if lib["user_api"] == "blas"]
        assert blas and all(lib["num_threads"] == 1 for lib in blas), blas
