"""Starts the two nodes as separate processes on a private, machine-local ROS 2 domain and
collects their summaries (``python -m sabre ros-demo``, the tests and the acceptance bench)."""

from __future__ import annotations

import fcntl
import json
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from typing import Any

from ..errors import SabreError

__all__ = ["Domain", "ros_environment", "NodeProcess", "start_node", "BridgeRun", "run_bridge", "format_run", "robot_file"]

#: Domain ids 1..100 work on every platform (Linux allows up to 101 with the default ports).
DOMAIN_RANGE = range(1, 101)


class Domain:
    """A ROS_DOMAIN_ID no other sabre run on this machine holds: claimed with an exclusive lock
    on a file in the temp directory, starting from one derived from the pid. Release with
    :meth:`release` (or use as a context manager)."""

    def __init__(self) -> None:
        self._file = None
        start = os.getpid() % len(DOMAIN_RANGE)
        for k in range(len(DOMAIN_RANGE)):
            candidate = DOMAIN_RANGE[(start + k) % len(DOMAIN_RANGE)]
            f = open(os.path.join(tempfile.gettempdir(), f"sabre-ros-domain-{candidate}.lock"), "w")
            try:
                fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                f.close()
                continue
            self._file = f
            self.id = candidate
            return
        raise RuntimeError("no free ROS_DOMAIN_ID among 1..100")

    def release(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None

    def __enter__(self) -> Domain:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def ros_environment(domain_id: int) -> dict[str, str]:
    """The environment for a bridge process: discovery kept on this machine, a private domain,
    Fast DDS, unbuffered output."""
    env = dict(os.environ)
    env.update(
        {
            "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
            "ROS_DOMAIN_ID": str(int(domain_id)),
            "RMW_IMPLEMENTATION": env.get("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp"),
            "PYTHONUNBUFFERED": "1",
        }
    )
    return env


@dataclass
class NodeProcess:
    """A running node: the process, and its output collected into a temp file."""

    kind: str
    process: subprocess.Popen
    log_path: str

    def output(self) -> str:
        with open(self.log_path, encoding="utf-8", errors="replace") as f:
            return f.read()

    def summary(self) -> dict[str, Any] | None:
        """The node's ``SABRE_SUMMARY`` line, once it has exited."""
        for line in reversed(self.output().splitlines()):
            if line.startswith("SABRE_SUMMARY "):
                return json.loads(line[len("SABRE_SUMMARY ") :])
        return None

    def stop(self, timeout: float = 20.0) -> int:
        """SIGINT, then SIGKILL after ``timeout`` s; returns the exit code."""
        if self.process.poll() is None:
            self.process.send_signal(2)
            try:
                self.process.wait(timeout)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        return self.process.returncode

    def kill(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait()


def start_node(kind: str, domain_id: int, args: list[str] | None = None, params: dict[str, Any] | None = None) -> NodeProcess:
    """Starts ``python -m sabre <kind> [args] --ros-args -p name:=value ...`` (kind: "control" or
    "sim-robot") in the private domain."""
    cmd = [sys.executable, "-m", "sabre", kind] + list(args or [])
    if params:
        cmd.append("--ros-args")
        for k, v in params.items():
            # YAML values: an empty string must be written as '' (a bare `name:=` does not parse)
            value = json.dumps(v) if not isinstance(v, str) else (v or "''")
            cmd += ["-p", f"{k}:={value}"]
    log = tempfile.NamedTemporaryFile(prefix=f"sabre-{kind}-", suffix=".log", delete=False)
    process = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=ros_environment(domain_id))
    log.close()
    return NodeProcess(kind, process, log.name)


@dataclass
class BridgeRun:
    """One run of both nodes: their summaries (see the nodes' ``summary``) and exit codes."""

    sim: dict[str, Any]
    controller: dict[str, Any]
    sim_exit: int
    controller_exit: int
    logs: dict[str, str] = field(default_factory=dict)


def robot_file(robot: str, obj: str) -> tuple[str, list[float] | None]:
    """The URDF file of ``robot`` (an example robot's name, :data:`sabre.robot_examples.EXAMPLE_ROBOTS`,
    or a URDF path) and where the example robot opens ``obj`` (None: the object's default pose)."""
    from ..robot_examples import EXAMPLE_OBJECTS, EXAMPLE_ROBOTS, example_robot_urdf

    if robot in EXAMPLE_ROBOTS:
        pose = EXAMPLE_OBJECTS[robot].get(obj)
        return str(example_robot_urdf(robot)), None if pose is None else [float(v) for v in pose]
    if not os.path.isfile(robot):
        raise SabreError(f"robot {robot!r} is neither an example robot ({', '.join(EXAMPLE_ROBOTS)}) nor a URDF file")
    return robot, None


def run_bridge(
    obj: str = "shelf",
    variant: str = "IO",
    seed: int = 0,
    timeout: float = 60.0,
    *,
    object_pose: list[float] | None = None,
    plant: str = "rapier",
    robot: str | None = None,
    sim_params: dict[str, Any] | None = None,
    controller_params: dict[str, Any] | None = None,
) -> BridgeRun:
    """Starts the simulated robot (the object at ``object_pose``, published on the pose topic as a
    perception node would) and the controller (``autostart``: it configures once the robot
    description, the pose and the inputs are there, then activates), waits until the robot
    reports the object open (plus its settle time) or ``timeout`` s of wall time, stops both with
    SIGINT. ``robot``: an example robot or a URDF file (see :func:`robot_file`; None: the
    RoyalPanda), which the simulated robot is and publishes as the robot description."""
    sim_overrides: dict[str, Any] = {"stop_on_success": True, "duration": float(timeout), "plant": plant}
    if robot is not None:
        sim_overrides["robot_description_file"], example_pose = robot_file(robot, obj)
        object_pose = example_pose if object_pose is None else object_pose
    if object_pose is not None:
        sim_overrides["object_pose"] = [float(v) for v in object_pose]
    with Domain() as domain:
        sim = start_node("sim-robot", domain.id, ["--object", obj], sim_overrides | (sim_params or {}))
        ctrl = start_node(
            "control",
            domain.id,
            ["--object", obj, "--variant", variant, "--seed", str(seed)],
            {"autostart": True} | (controller_params or {}),
        )
        try:
            deadline = time.monotonic() + timeout + 60.0
            while sim.process.poll() is None and ctrl.process.poll() is None and time.monotonic() < deadline:
                time.sleep(0.2)
            controller_exit = ctrl.stop()
            sim_exit = sim.stop()
        finally:
            ctrl.kill()
            sim.kill()
        return BridgeRun(
            sim=sim.summary() or {},
            controller=ctrl.summary() or {},
            sim_exit=sim_exit,
            controller_exit=controller_exit,
            logs={"sim-robot": sim.output(), "control": ctrl.output()},
        )


def format_run(run: BridgeRun) -> str:
    """The ros-demo report: success, time to open, mean wrench, latency, dropped or late
    messages, planner rate, overruns."""
    s, c = run.sim, run.controller
    if not s or not c:
        return "a node exited without a summary; logs:\n" + "\n".join(f"--- {k}\n{v[-3000:]}" for k, v in run.logs.items())
    when = "—" if s["time_to_open"] is None else f"{s['time_to_open']:.2f} s"
    dropped = s["answered_window"] - s["echoes"]
    lines = [
        f"[{s['object']}] success: {s['success']}, time to open: {when}, final opening {s['opening']:.3f}",
        f"  mean wrench in contact {s['mean_wrench']:.1f} N; tank {c['tank_energy']:.2f} J (min {c['tank_min']:.2f}, "
        f"floor {c['tank_floor']:.2f}), filter fallbacks {c['filter_fallbacks']}",
        f"  state-to-command latency p50 {s['latency_p50_ms']:.3f} ms, p99 {s['latency_p99_ms']:.3f} ms, "
        f"max {s['latency_max_ms']:.2f} ms",
        f"  states {s['states_published']} for {s['ticks']} plant ticks; commands back for {s['echoes']} of the "
        f"{s['answered_window']} published while the controller ran ({100 * s['delivered_fraction']:.2f} %), dropped {dropped}, "
        f"late (> {s['period_ms']:.0f} ms) {s['late_echoes']}, rejected {c['rejected']}",
        f"  plant: {s['sim_time']:.2f} s simulated in {s['wall_time']:.2f} s wall, late ticks {s['late_ticks']}, "
        f"skipped {s['skipped_ticks']}, loop work p99 {s['loop_work_p99_ms']:.3f} ms; reflex aborts {s['reflex_aborts']}",
        f"  CPU: controller node {100 * c.get('cpu_share', float('nan')):.1f} % of a core (planner process apart), "
        f"simulated robot {100 * s['cpu_share']:.1f} %",
        f"  planner {c['planner_rate_hz']:.1f} Hz ({c['planner_iterations']} iterations), inner tick compute "
        f"p50 {c['tick_compute_p50_ms']:.3f} ms p99 {c['tick_compute_p99_ms']:.3f} ms, stale-state events {c['stale_events']}",
        f"  state age on arrival at the controller p50 {c['state_age_p50_ms']:.3f} ms, p99 {c['state_age_p99_ms']:.3f} ms",
        f"  exit codes: sim-robot {run.sim_exit}, controller {run.controller_exit}",
    ]
    return "\n".join(lines)
