"""The command line (python -m sabre): help text with units and defaults, option checking, one dispatch
per subcommand, and the commands run end to end with small settings (demo, episode, scripted, view,
the ros-demo report)."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import threading
import urllib.error
import urllib.request

import numpy as np
import pytest

import sabre
from sabre.cli import main
from sabre.cli.main import build_parser


@pytest.mark.parametrize("command", ["demo", "episode", "scripted"])
def test_every_option_of_every_command_has_help(command, capsys):
    with pytest.raises(SystemExit) as exit_:
        main([command, "--help"])
    assert exit_.value.code == 0
    text = capsys.readouterr().out
    assert "--object" in text and "(default: shelf)" in text
    if command != "scripted":
        for option, default in (("--duration S", "seconds"), ("--replan-rate HZ", "Hz"), ("--threads N", "threads")):
            assert option in text and default in text
        assert "(default: 60.0)" in text if command == "demo" else "(default: 30.0)" in text


@pytest.mark.parametrize(
    "args",
    [
        ["--duration", "-1"],
        ["--replan-rate", "0"],
        ["--threads", "0"],
        ["--seed", "-3"],
        ["--variant", "X"],
        ["--duration", "nan"],
    ],
)
def test_bad_options_are_rejected_with_a_usage_error(args, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["episode", *args])
    assert exit_.value.code == 2
    assert "error" in capsys.readouterr().err


def _subcommands() -> dict:
    parser = build_parser()
    action = next(a for a in parser._actions if a.dest == "command")
    return action.choices


def test_every_subcommand_dispatches_through_one_run_function():
    commands = _subcommands()
    assert set(commands) == {
        "demo",
        "episode",
        "scripted",
        "view",
        "experiment",
        "control",
        "sim-robot",
        "ros-demo",
        "robot-check",
    }
    for name, sub in commands.items():
        run = sub.get_default("run")
        assert callable(run) and run.__module__.startswith("sabre.cli."), name
    assert commands["ros-demo"].get_default("run").__name__ == "ros_demo_command"


def test_a_sabre_error_of_a_command_is_one_line_and_exit_code_one(tmp_path, capsys):
    other = tmp_path / "other.npz"
    np.savez(other, a=np.zeros(3))
    assert main(["view", str(other)]) == 1
    err = capsys.readouterr().err
    assert "python -m sabre view: error:" in err and "not a sabre episode file" in err
    assert "Traceback" not in err


def test_a_short_episode_that_does_not_open_exits_with_one(tmp_path, capsys):
    pytest.importorskip("matplotlib")
    plot = tmp_path / "episode.png"
    code = main(["episode", "--duration", "0.1", "--threads", "1", "--replan-rate", "50", "--plot", str(plot)])
    assert code == 1
    assert plot.exists()
    assert "success: False" in capsys.readouterr().out


def test_episode_exit_code_follows_the_printed_success_line(capsys):
    code = main(["episode", "--object", "drawer", "--start", "default", "--duration", "0.1", "--threads", "1"])
    out = capsys.readouterr().out
    assert "from the default start, re-planning at 100 Hz" in out
    success = re.search(r"\[drawer\] success: (True|False), final opening (-?[\d.]+)", out)
    assert success is not None, out
    assert code == (0 if success.group(1) == "True" else 1)
    assert re.search(r"planning iteration median [\d.]+ ms, real-time factor [\d.]+", out)


def test_demo_writes_its_figure_in_the_working_folder_and_exits_zero(tmp_path, monkeypatch, capsys):
    pytest.importorskip("matplotlib")
    monkeypatch.chdir(tmp_path)
    # the object does not open in 0.1 s: demo exits 0 all the same
    assert main(["demo", "--object", "drawer", "--duration", "0.1", "--threads", "1"]) == 0
    figure = tmp_path / "sabre_demo_drawer.png"
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and figure.stat().st_size > 10_000
    out = capsys.readouterr().out
    assert "from the paper start" in out and "success: False" in out and "wrote sabre_demo_drawer.png" in out


def test_scripted_opens_the_drawer_and_reports_a_throughput_that_matches_its_timing(capsys):
    assert main(["scripted", "--object", "drawer", "--threads", "1"]) == 0
    out = capsys.readouterr().out
    opening = re.search(r"rollout model: final opening ([\d.]+) of ([\d.]+) \(m\)", out)
    assert opening is not None, out
    assert float(opening.group(1)) > 0.5 * float(opening.group(2))  # what exit code 0 promises
    line = re.search(r"throughput: (\d+)x(\d+) rollouts in ([\d.]+) ms on 1 thread = ([\d,]+) steps/s", out)
    assert line is not None, out
    n, k, ms, rate = int(line.group(1)), int(line.group(2)), float(line.group(3)), float(line.group(4).replace(",", ""))
    assert (n, k) == (40, 66)
    assert rate == pytest.approx(n * k / (ms * 1e-3), rel=0.01)


def _saved_episode(path) -> None:
    scene = sabre.Scene.load(obj="drawer")
    controller = sabre.Controller(scene, sabre.tasks.OpenObject(), sabre.ControllerConfig(seed=1, rollouts=8, threads=1))
    episode = sabre.run_episode(scene, controller, 0.1, seed=1, x0=scene.default_state(), record_plans=True, progress=False)
    episode.save(path)


def test_view_serves_the_saved_episode_until_ctrl_c_then_exits_zero(tmp_path):
    pytest.importorskip("viser")
    path = tmp_path / "episode.npz"
    _saved_episode(path)
    process = subprocess.Popen(
        [sys.executable, "-u", "-m", "sabre", "view", str(path), "--port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    guard = threading.Timer(60.0, process.kill)  # a hung server fails the test instead of the run
    guard.start()
    try:
        printed = []
        for line in process.stdout:
            printed.append(line)
            if line.startswith("sabre viewer: "):
                break
        url = re.search(r"sabre viewer: (http://127\.0\.0\.1:\d+)", "".join(printed))
        assert url is not None, "".join(printed)
        assert "(drawer, " in printed[-1]
        with urllib.request.urlopen(url.group(1), timeout=10) as response:
            page = response.read().decode()
        assert "<title>Viser</title>" in page
        process.send_signal(signal.SIGINT)
        rest, _ = process.communicate(timeout=30)
    finally:
        guard.cancel()
        process.kill()
    assert process.returncode == 0, "".join(printed) + rest
    with pytest.raises(urllib.error.URLError):  # the server is gone with the process
        urllib.request.urlopen(url.group(1), timeout=2)


def _bridge_run(launch, sim=None, controller=None):
    sim_summary = {
        "object": "microwave",
        "success": True,
        "time_to_open": 12.346,
        "opening": 1.2346,
        "mean_wrench": 6.78,
        "latency_p50_ms": 0.4321,
        "latency_p99_ms": 1.9876,
        "latency_max_ms": 7.654,
        "states_published": 20000,
        "ticks": 20010,
        "echoes": 19950,
        "answered_window": 19960,
        "delivered_fraction": 0.9995,
        "period_ms": 1.0,
        "late_echoes": 12,
        "sim_time": 20.01,
        "wall_time": 20.5,
        "late_ticks": 3,
        "skipped_ticks": 1,
        "loop_work_p99_ms": 0.1234,
        "reflex_aborts": 0,
        "cpu_share": 0.312,
    }
    controller_summary = {
        "tank_energy": 8.5,
        "tank_min": 2.25,
        "tank_floor": 2.0,
        "filter_fallbacks": 4,
        "rejected": 2,
        "planner_rate_hz": 48.7,
        "planner_iterations": 974,
        "tick_compute_p50_ms": 0.21,
        "tick_compute_p99_ms": 0.55,
        "stale_events": 0,
        "state_age_p50_ms": 0.31,
        "state_age_p99_ms": 0.92,
        "cpu_share": 0.2049,
    }
    return launch.BridgeRun(
        sim=sim_summary if sim is None else sim,
        controller=controller_summary if controller is None else controller,
        sim_exit=0,
        controller_exit=1,
        logs={"sim-robot": "x" * 5000 + "sim tail", "control": "control tail"},
    )


@pytest.fixture
def launch_without_rclpy(monkeypatch):
    """sabre.ros.launch imported afresh with rclpy unimportable: the report needs no ROS."""
    import importlib

    import sabre.ros

    monkeypatch.setitem(sys.modules, "rclpy", None)
    monkeypatch.delitem(sys.modules, "sabre.ros.launch", raising=False)
    monkeypatch.setattr(sabre.ros, "launch", getattr(sabre.ros, "launch", None), raising=False)
    return importlib.import_module("sabre.ros.launch")


def test_ros_demo_report_names_each_number(launch_without_rclpy):
    lines = launch_without_rclpy.format_run(_bridge_run(launch_without_rclpy)).splitlines()
    assert lines[0] == "[microwave] success: True, time to open: 12.35 s, final opening 1.235"
    assert lines[1] == "  mean wrench in contact 6.8 N; tank 8.50 J (min 2.25, floor 2.00), filter fallbacks 4"
    assert lines[2] == "  state-to-command latency p50 0.432 ms, p99 1.988 ms, max 7.65 ms"
    # dropped: the commands never echoed among those published while the controller ran (19960 − 19950)
    assert lines[3] == (
        "  states 20000 for 20010 plant ticks; commands back for 19950 of the 19960 published while the "
        "controller ran (99.95 %), dropped 10, late (> 1 ms) 12, rejected 2"
    )
    assert lines[4] == (
        "  plant: 20.01 s simulated in 20.50 s wall, late ticks 3, skipped 1, loop work p99 0.123 ms; reflex aborts 0"
    )
    assert lines[5] == "  CPU: controller node 20.5 % of a core (planner process apart), simulated robot 31.2 %"
    assert lines[6] == ("  planner 48.7 Hz (974 iterations), inner tick compute p50 0.210 ms p99 0.550 ms, stale-state events 0")
    assert lines[7] == "  state age on arrival at the controller p50 0.310 ms, p99 0.920 ms"
    assert lines[8] == "  exit codes: sim-robot 0, controller 1"


def test_ros_demo_report_without_a_summary_shows_the_tail_of_each_log(launch_without_rclpy):
    text = launch_without_rclpy.format_run(_bridge_run(launch_without_rclpy, controller={}))
    assert text.startswith("a node exited without a summary; logs:")
    sim_log = "x" * 5000 + "sim tail"
    assert f"--- sim-robot\n{sim_log[-3000:]}\n" in text and sim_log[-3001:] not in text
    assert "--- control\ncontrol tail" in text
    assert "success" not in text
