"""Hand-made mutants of the ROS 2 bridge (its tick, the simulated robot's driver and reflexes, the messages, the
command gate, and its Python side): each is applied to a checkout, the tests that cover it run, and the mutant is
put back; prints killed or SURVIVED.

    CARGO_TARGET_DIR=<its own target dir> python tools/bridge_mutants.py <a scratch checkout>   # never this one

The checkout needs a compiled extension in its python/sabre/ (the Python tests run on it, with its python/ first
on PYTHONPATH); a mutant of the Rust code runs the Rust tests only, so the extension is never rebuilt.
"""

import pathlib
import sys

from mutants import Mutant, run

RUST = "cargo test --profile quick-release --lib -- bridge:: control::command_stream"


def pytest(*tests: str) -> str:
    """The narrowest pytest selection that covers a mutant, stopping at the first failure (a test that waits on
    ROS 2 processes gives up after its own deadline; the run's timeout bounds the rest)."""
    return "{python} -m pytest -q -x -p no:cacheprovider " + " ".join(tests)


ROS = "tests/ros/test_ros.py::"
LOGIC = "tests/ros/test_bridge_logic.py::"
TICK = "src/bridge/tick.rs"
DRIVER = "src/bridge/sim_driver.rs"
REFLEXES = "src/bridge/reflexes.rs"
GATE = "src/control/command_stream.rs"
LOOP = "python/sabre/ros/controller_loop.py"
MALFORMED = ROS + "test_malformed_and_withheld_states_are_answered_with_ramps_never_steps"
MUTANTS = [
    Mutant(TICK, "if t_abs <= last {", "if t_abs < last {", "a state with the previous stamp ticks again", RUST),
    Mutant(TICK, "fresh: self.joints.fresh(received),", "fresh: true,", "a stale joint never reported", RUST),
    Mutant(TICK, "(t - last).min(self.layout.max_tick_dt)", "t - last", "the step after a gap not capped", RUST),
    Mutant(TICK, "map(|plan| t - plan.t0())", "map(|plan| plan.t0() - t)", "the plan's age with its sign turned", RUST),
    Mutant(
        TICK,
        "answers.map_or(0, |s| s.nanosec)",
        "stamp.nanosec",
        "a watchdog step carries a stamp as if it answered a state",
        RUST,
    ),
    Mutant(TICK, "stamped.then_some(stamp),", "None,", "a stamped base command sent as a Twist", RUST),
    Mutant(DRIVER, "self.u[x] = c * vx - s * vy;", "self.u[x] = c * vx + s * vy;", "the base's world rates: a sign", RUST),
    Mutant(
        DRIVER,
        "if latency > self.layout.period {",
        "if latency > self.layout.command_timeout {",
        "a late answer measured against the command timeout",
        RUST,
    ),
    Mutant(
        DRIVER,
        "while self.order.len() > self.layout.recent_states.max(1) {",
        "while self.order.len() >= self.layout.recent_states.max(1) {",
        "one state fewer kept to match answers against",
        RUST,
    ),
    Mutant(
        DRIVER,
        "self.velocity[k] = dq[i] + self.layout.velocity_noise * noise;",
        "self.velocity[k] = dq[i] + self.layout.position_noise * noise;",
        "the velocities' noise is the positions'",
        RUST,
    ),
    Mutant(REFLEXES, "            *previous_a = a;\n", "", "the jerk taken against a stale acceleration", RUST),
    Mutant(REFLEXES, "v * (1.0 + LIMIT_TOLERANCE)", "v * (1.0 - LIMIT_TOLERANCE)", "the limit itself trips the reflex", RUST),
    Mutant(
        "src/bridge/messages.rs",
        "0x00 => Ok((&raw[4..], false)),",
        "0x00 => Ok((&raw[4..], true)),",
        "big-endian CDR read as little-endian",
        RUST,
    ),
    Mutant(
        GATE,
        "self.last_command = self.last_command.max(now - self.period);",
        "self.last_command = now;",
        "the ramp's first step a period late",
        RUST,
    ),
    Mutant(GATE, "(None, _) => self.base_target.fill(0.0),", "(None, _) => {}", "the base keeps its target in a ramp", RUST),
    Mutant(
        LOOP,
        '        if not fresh:\n            return "stale state"\n',
        "",
        "a tick with a stale joint follows the plan",
        pytest(MALFORMED),
    ),
    Mutant(
        LOOP,
        "        if reason is not None:\n            self._publish(*self.tick.stop(received))\n",
        "",
        "a blocked tick (e-stop, inactive) answers nothing",
        pytest(ROS + "test_lifecycle_ramps_in_and_down_on_estop_deactivate_and_sigterm_within_the_urdfs_limits"),
    ),
    Mutant(
        LOOP,
        "                    self._publish(*tick.stop(received))  # a ramp step, never a step to zero\n",
        "",
        "a rejected state goes unanswered",
        pytest(MALFORMED),
    ),
    Mutant(
        "python/sabre/ros/params.py",
        '        elif isinstance(value, (list, tuple)) and all(v == "" for v in value):\n            values[name] = []\n',
        "",
        'a list parameter left at [""] is not read as unset',
        pytest(MALFORMED),
    ),
    Mutant(
        "python/sabre/ros/inputs.py",
        "tau[dst] = self.sign * values",
        "tau[dst] = values",
        "the joint-torque topic's sign ignored",
        pytest(LOGIC + "test_wrench_frames_take_the_headers_axes_and_reject_unknown_frames"),
    ),
    Mutant(
        "python/sabre/ros/commands.py",
        "accel, jerk = [min(accel)] * n, [min(jerk)] * n",
        "accel, jerk = [max(accel)] * n, [max(jerk)] * n",
        "another arm's limits from the fastest Franka joint",
        pytest(LOGIC + "test_a_fixed_base_has_the_arms_stream_only_and_a_six_joint_arm_passes_its_own_reflexes"),
    ),
    Mutant(
        "python/sabre/ros/commands.py",
        'pick("base_jerk_limits", BASE_JERK, 3)',
        'pick("base_jerk_limits", BASE_ACCELERATION, 3)',
        "the base's default jerk is its acceleration",
        pytest(LOGIC + "test_default_limits_come_from_the_urdf_and_franka_kept_robust_to_two_missed_commands"),
    ),
    Mutant(
        "python/sabre/ros/reflexes.py",
        "[min(FRANKA_ACCELERATION)] * n, [min(FRANKA_JERK)] * n",
        "[max(FRANKA_ACCELERATION)] * n, [max(FRANKA_JERK)] * n",
        "another arm's reflexes from the fastest Franka joint",
        pytest(LOGIC + "test_a_fixed_base_has_the_arms_stream_only_and_a_six_joint_arm_passes_its_own_reflexes"),
    ),
    Mutant(
        "python/sabre/ros/direct.py",
        "if _major_minor(loaded[package]) != _major_minor(version):",
        "if loaded[package] != version:",
        "another patch release of rcl refused",
        pytest("tests/ros/test_direct.py"),
    ),
    Mutant(
        "python/sabre/ros/sim_robot.py",
        "else last - first + 1",
        "else last - first",
        "the answered window one state short",
        pytest(ROS + "test_the_sim_robot_matches_answers_by_stamp_and_stops_on_its_command_timeout"),
    ),
]

if __name__ == "__main__":
    root = pathlib.Path(sys.argv[1]).resolve()
    run(root, MUTANTS, timeout=900.0, log=pathlib.Path(sys.argv[2]) if len(sys.argv) > 2 else None)
