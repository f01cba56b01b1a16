"""The bridge's CPU per process: the simulated robot and the controller opening an object on
loopback, each process's CPU time (user and system, every thread of it; the controller's planner
process apart) over a window of wall time once both run, and the planner's rate through the bridge.

Starts both nodes with `sabre.ros.launch.start_node` in a private ROS_DOMAIN_ID (discovery on this
machine only), waits ``--warmup`` s (start-up, configure, the first plan), reads each process's and
each of its threads' CPU time from /proc, again ``--seconds`` s later, then stops both with SIGINT and
prints the shares (CPU over wall time of the window), the busiest threads by name (Fast DDS names
its own; Python's are ``python``), the load average and the nodes' summaries' planner rate,
answered states and latency. `run_episode` re-plans at 50 Hz of simulated time: the rate to compare.

    .venv/bin/python benches/ros_cpu.py --seconds 20
"""

from __future__ import annotations

import argparse
import collections
import os
import time

#: The clock ticks per second /proc counts CPU time in.
TICKS = os.sysconf("SC_CLK_TCK")


def thread_times(pid: int) -> dict[int, tuple[str, float]]:
    """tid → (thread name, CPU seconds so far) of every thread of ``pid``."""
    times = {}
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            with open(f"/proc/{pid}/task/{tid}/stat", encoding="ascii") as f:
                text = f.read()
        except OSError:
            continue  # the thread ended meanwhile
        name = text[text.index("(") + 1 : text.rindex(")")]
        if int(tid) == pid:
            name += " (main: the executor)"
        fields = text[text.rindex(")") + 2 :].split()
        times[int(tid)] = (name, (int(fields[11]) + int(fields[12])) / TICKS)
    return times


def shares(before: dict[int, tuple[str, float]], after: dict[int, tuple[str, float]], wall: float) -> tuple[float, list]:
    """(the process's share of a core, [(thread name, threads, share)] busiest first) over ``wall`` s."""
    by_name: dict[str, float] = collections.defaultdict(float)
    count: collections.Counter[str] = collections.Counter()
    for tid, (name, cpu) in after.items():
        by_name[name] += cpu - before.get(tid, (name, 0.0))[1]
        count[name] += 1
    total = sum(by_name.values())
    ranked = sorted(((n, count[n], c / wall) for n, c in by_name.items()), key=lambda r: -r[2])
    return total / wall, ranked


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=20.0, help="the measured window")
    parser.add_argument("--warmup", type=float, default=12.0, help="from the start to the window")
    parser.add_argument("--object", default="shelf")
    parser.add_argument("--variant", default="IO")
    parser.add_argument(
        "--executor-path",
        action="store_true",
        help="the simulated robot takes its arm commands in an executor callback and publishes its states "
        "through rclpy (direct_middleware: false) instead of through rcl from the core",
    )
    args = parser.parse_args()
    from sabre.ros.launch import Domain, start_node

    total = args.warmup + args.seconds
    with Domain() as domain:
        sim_params = {"duration": total + 30.0, "direct_middleware": not args.executor_path}
        sim = start_node("sim-robot", domain.id, ["--object", args.object], sim_params)
        ctrl = start_node("control", domain.id, ["--object", args.object, "--variant", args.variant], {"autostart": True})
        nodes = {"controller": ctrl, "sim robot": sim}
        try:
            time.sleep(args.warmup)
            before = {k: thread_times(n.process.pid) for k, n in nodes.items()}
            start = time.monotonic()
            load_before = os.getloadavg()[0]
            time.sleep(args.seconds)
            after = {k: thread_times(n.process.pid) for k, n in nodes.items()}
            wall = time.monotonic() - start
            load_after = os.getloadavg()[0]
            for n in nodes.values():
                n.stop()
        finally:
            for n in nodes.values():
                n.kill()
    print(f"window {wall:.1f} s after {args.warmup:.0f} s; load average (1 min) {load_before:.2f} → {load_after:.2f}")
    for key in nodes:
        share, ranked = shares(before[key], after[key], wall)
        top = ", ".join(f"{name} ×{k} {100 * s:.1f} %" for name, k, s in ranked[:5])
        print(f"{key}: {100 * share:.1f} % of a core ({top})")
    s, c = sim.summary() or {}, ctrl.summary() or {}
    if not s or not c:
        print("a node exited without a summary:\n" + "\n".join(n.output()[-2000:] for n in nodes.values()))
        return
    print(
        f"planner {c['planner_rate_hz']:.1f} Hz through the bridge (run_episode re-plans at 50 Hz); "
        f"states {s['states_published']} for {s['ticks']} ticks, answered {100 * s['delivered_fraction']:.2f} %, "
        f"latency p50 {s['latency_p50_ms']:.2f} ms p99 {s['latency_p99_ms']:.2f} ms; opened {s['success']} "
        f"({s['time_to_open']} s); summaries' CPU (since start): controller {100 * c['cpu_share']:.1f} %, "
        f"sim robot {100 * s['cpu_share']:.1f} %; the controller's tick (receive to publish) p50 "
        f"{c['tick_compute_p50_ms']:.3f} ms p99 {c['tick_compute_p99_ms']:.3f} ms"
    )


if __name__ == "__main__":
    main()
