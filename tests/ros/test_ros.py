"""The ROS 2 bridge across real processes on real DDS (loopback only, a private domain per run):
joint-name mapping, rejection of malformed messages, both watchdogs, the command timeout, a
closed-loop approach, and the hand-pose object-state estimator against the plant."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

import sabre
from sabre.ros.conversions import JointMap, MessageError, base_to_world, tau_ext_from_wrench, world_to_base
from sabre.ros.estimator import ObjectStateEstimator
from sabre.ros.launch import Domain, start_node

DEADLINE = 120.0  # s: generous bound for conditions on a loaded machine; never asserted as a duration


# -- plain NumPy parts --------------------------------------------------------------------------
def test_joint_map_takes_any_order_ignores_extra_joints_and_rejects_missing_ones():
    wanted = ("a", "b", "c")
    m = JointMap(wanted)
    names = ["extra1", "c", "a", "extra2", "b"]
    assert np.array_equal(m.values(names, [9.0, 3.0, 1.0, 8.0, 2.0], "position"), [1.0, 2.0, 3.0])
    with pytest.raises(MessageError, match="lacks joints"):
        m.values(["a", "b", "x"], [1.0, 2.0, 3.0], "position")
    with pytest.raises(MessageError, match="2 values for 3 names"):
        m.values(["a", "b", "c"], [1.0, 2.0], "position")
    with pytest.raises(MessageError, match="non-finite"):
        m.values(["a", "b", "c"], [1.0, math.nan, 3.0], "position")


def test_base_twist_conversion_rotates_by_yaw_and_inverts():
    rng = np.random.default_rng(1)
    for _ in range(20):
        rates, yaw = rng.normal(size=3), rng.uniform(-math.pi, math.pi)
        base = world_to_base(rates, yaw)
        # the base-frame velocity rotated back by yaw is the world-frame velocity
        c, s = math.cos(yaw), math.sin(yaw)
        assert np.allclose([c * base[0] - s * base[1], s * base[0] + c * base[1], base[2]], rates)
        assert np.allclose(base_to_world(base, yaw), rates)
    assert np.allclose(world_to_base([1.0, 0.0, 0.2], math.pi / 2), [0.0, -1.0, 0.2])


def test_tau_ext_from_the_wrist_wrench_equals_the_plants_contact_torques():
    """Hooked on the shelf handle only the hand touches the object, so Jᵀw of the wrist sensor
    must equal the plant's τ_ext summed over the contact points."""
    scene = sabre.Scene.load(obj="shelf")
    plant = sabre.Plant(scene, tau_ext_cutoff=None)
    plant.reset(sabre.scenarios.hooked_state(scene))
    low = sabre.LowLevelController(scene)
    pull = np.zeros(scene.nu)
    pull[0] = -0.1
    compared = 0
    for _ in range(300):
        low.track(plant, pull, 1)
        if plant.contact and np.linalg.norm(plant.tau_ext) > 1.0:
            q = plant.state[: scene.nq]
            assert np.allclose(tau_ext_from_wrench(scene, q, plant.wrench), plant.tau_ext, rtol=1e-9, atol=1e-9)
            compared += 1
    assert compared > 10


@pytest.mark.parametrize("obj", ["shelf", "drawer"])
def test_estimator_tracks_the_plants_articulation_during_hook_and_pull(obj):
    scene = sabre.Scene.load(obj=obj)
    motion = sabre.hook_and_pull(scene)
    plant = sabre.Plant(scene)
    low = sabre.LowLevelController(scene)
    plant.reset(scene.default_state())
    nq = scene.nq
    estimator = ObjectStateEstimator(scene, scene.default_state()[2 * nq : 2 * nq + 1])
    per = int(round(motion.dt / plant.dt))
    rows = []
    for u in motion.U:
        low.track(plant, u, per)
        x = plant.state
        e = estimator.update(x[:nq], plant.time, float(np.linalg.norm(plant.wrench[:3])))
        rows.append((x[2 * nq], e.position[0], x[2 * nq + 1], e.velocity[0], e.hooked))
    true, est, rate, est_rate, hooked = (np.array(c, dtype=float) for c in zip(*rows))
    travel = scene.o_upper[0] - scene.o_lower[0]
    assert true[-1] > 0.5 * travel  # the scripted pull opened it
    assert hooked.mean() > 0.3
    assert np.max(np.abs(true - est)) < 0.01 * travel
    moving = hooked.astype(bool) & (np.abs(rate) > 0.2 * np.abs(rate).max())
    assert np.median(np.abs(rate - est_rate)[moving]) < 0.2 * np.abs(rate).max()


def test_using_the_bridge_without_ros_raises_a_sabre_error_naming_the_extra():
    code = (
        "import sys; sys.modules['rclpy'] = None\n"
        "import sabre, sabre.ros\n"
        "assert 'rclpy' not in [m for m in sys.modules if sys.modules[m] is not None]\n"
        "try:\n    sabre.ros.require_ros()\nexcept sabre.SabreError as e:\n    print('ERR', e)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "ERR" in out.stdout and "sabre-mpc[ros]" in out.stdout


# -- across processes ---------------------------------------------------------------------------
rclpy = pytest.importorskip("rclpy", reason="the ROS 2 extra sabre-mpc[ros] (make test installs it)")


class Probe:
    """A node in the test process on the run's private domain: publishes and records messages."""

    def __init__(self, domain: int) -> None:
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
        os.environ["ROS_DOMAIN_ID"] = str(domain)
        sabre.ros.require_ros()
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import WrenchStamped
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64MultiArray

        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("sabre_test_probe", context=self.context)
        self.lock = threading.Lock()
        self.messages: dict[str, list] = {"joint_states": [], "echo": [], "arm": [], "diagnostics": [], "sim_status": []}
        self.JointState, self.WrenchStamped = JointState, WrenchStamped
        for key, typ, topic in (
            ("joint_states", JointState, "/joint_states"),
            ("echo", JointState, "/sabre/command"),
            ("arm", Float64MultiArray, "/forward_velocity_controller/commands"),
            ("diagnostics", DiagnosticArray, "/diagnostics"),
            ("sim_status", DiagnosticArray, "/sabre/sim/status"),
        ):
            self.node.create_subscription(typ, topic, self._recorder(key), 50)
        self.js_pub = self.node.create_publisher(JointState, "/joint_states", 10)
        self.obj_pub = self.node.create_publisher(JointState, "/sabre/object/joint_states", 10)
        self.wrench_pub = self.node.create_publisher(WrenchStamped, "/wrist_wrench", 10)
        self.executor = rclpy.executors.SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _recorder(self, key):
        def record(msg):
            with self.lock:
                self.messages[key].append((time.monotonic(), msg))

        return record

    def _spin(self):
        while not self._stop.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def get(self, key):
        with self.lock:
            return list(self.messages[key])

    def wait_for(self, condition, what: str):
        deadline = time.monotonic() + DEADLINE
        while time.monotonic() < deadline:
            value = condition()
            if value:
                return value
            time.sleep(0.05)
        raise AssertionError(f"timed out waiting for {what}")

    def status(self, key: str, name: str) -> dict[str, str] | None:
        for _, msg in reversed(self.get(key)):
            for st in msg.status:
                if st.name == name:
                    return {kv.key: kv.value for kv in st.values}
        return None

    def close(self):
        self._stop.set()
        self._thread.join()
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


@pytest.fixture
def bridge():
    """A private domain, a probe node on it, and a list the test adds its node processes to
    (all killed on teardown)."""
    domain = Domain()
    probe = Probe(domain.id)
    processes = []
    try:
        yield domain, probe, processes
    finally:
        for p in processes:
            p.kill()
        probe.close()
        domain.release()
        for p in processes:
            os.unlink(p.log_path)


def stamp_of(t: float):
    from builtin_interfaces.msg import Time

    return Time(sec=int(t), nanosec=int(round((t % 1.0) * 1e9)) % 1_000_000_000)


def test_malformed_joint_states_get_a_logged_rejection_and_a_zero_command_and_fresh_state_resumes(bridge):
    """The probe plays the robot: valid states start the controller; a wrong length, a NaN and
    unknown names are each answered by a zero command (matched by their stamps) and a logged
    error; withholding states past state_timeout zeroes the command; valid states resume it."""
    domain, probe, processes = bridge
    ctrl = start_node("control", domain.id, ["--object", "shelf", "--variant", "IO"], {"state_timeout": 0.05})
    processes.append(ctrl)
    scene = sabre.Scene.load(obj="shelf")
    x = sabre.paper_start_state(scene)
    nq = scene.nq
    names = list(scene.joint_names)
    t0 = time.time()
    k = [0]

    def send(position, velocity, joint_names, stamp_t=None):
        k[0] += 1
        stamp_t = t0 + 0.001 * k[0] if stamp_t is None else stamp_t
        obj = probe.JointState(name=list(scene.object_joint_names), position=[0.0], velocity=[0.0])
        obj.header.stamp = stamp_of(stamp_t)
        probe.obj_pub.publish(obj)
        js = probe.JointState(name=joint_names, position=list(position), velocity=list(velocity))
        js.header.stamp = stamp_of(stamp_t)
        probe.js_pub.publish(js)
        return js.header.stamp

    def answers(stamp):
        return [m for _, m in probe.get("echo") if m.header.stamp.sec == stamp.sec and m.header.stamp.nanosec == stamp.nanosec]

    def run_valid(n):
        last = None
        for _ in range(n):
            last = send(x[:nq], x[nq : 2 * nq], names)
            time.sleep(0.002)
        return last

    # until the controller plans and answers valid states with its command
    probe.wait_for(
        lambda: run_valid(50) and any(np.any(np.asarray(m.velocity) != 0.0) for _, m in probe.get("echo")),
        "non-zero commands from the controller",
    )
    for label, position, velocity, joint_names in (
        ("wrong length", x[: nq - 1], x[nq : 2 * nq - 1], names[:-1] + ["unknown_joint"]),
        ("NaN", np.where(np.arange(nq) == 4, math.nan, x[:nq]), x[nq : 2 * nq], names),
        ("unknown names", x[:nq], x[nq : 2 * nq], [f"other_{n}" for n in names]),
        ("lengths differ", x[:nq], x[nq : 2 * nq - 2], names),
    ):
        stamp = send(position, velocity, joint_names)
        reply = probe.wait_for(lambda stamp=stamp: answers(stamp), f"the answer to the {label} state")
        assert np.all(np.asarray(reply[0].velocity) == 0.0), label
    assert ctrl.process.poll() is None
    assert ctrl.output().count("joint state rejected") >= 1

    # withholding the state: the watchdog zeroes the command; fresh states resume it
    probe.wait_for(
        lambda: (probe.status("diagnostics", "sabre/controller") or {}).get("state_stale") == "true",
        "the controller to flag the state stale",
    )
    status = probe.status("diagnostics", "sabre/controller")
    ages = json.loads(status["stale_zero_age_ms"])
    assert ages and ages[-1] >= 50.0  # never before state_timeout
    _, last_echo = probe.get("echo")[-1]
    assert np.all(np.asarray(last_echo.velocity) == 0.0)
    before = len(probe.get("echo"))
    probe.wait_for(
        lambda: run_valid(20) and any(np.any(np.asarray(m.velocity) != 0.0) for _, m in probe.get("echo")[before:]),
        "non-zero commands after fresh state",
    )
    ctrl.stop()
    assert ctrl.process.returncode == 0
    summary = ctrl.summary()
    print(summary)
    assert summary["rejected"] >= 4 and summary["stale_events"] >= 1
    # the shutdown's final command is zero
    _, final = probe.get("arm")[-1]
    assert np.all(np.asarray(final.data) == 0.0)


def grasp_to_handle(scene, msg, o: float) -> float:
    q = JointMap(scene.joint_names).values(msg.name, msg.position, "position")
    return float(np.linalg.norm(scene.fk(q, "grasp")[:3, 3] - scene.object_fk([o], "handle_frame")[:3, 3]))


def test_closed_loop_with_permuted_joint_order_moves_the_hand_toward_the_handle_then_the_sim_robot_stops_on_timeout(bridge):
    """The sim robot publishes the joints in reversed order with two extra joints; the controller
    maps them by name. Over the loop the grasp frame closes on the handle; with the controller
    killed, the robot stops (zero reference) at most command_timeout plus one tick after the last
    command, in the plant's schedule, and comes to rest."""
    domain, probe, processes = bridge
    scene = sabre.Scene.load(obj="shelf")
    order = list(reversed(scene.joint_names))
    sim = start_node(
        "sim-robot",
        domain.id,
        ["--object", "shelf"],
        {"publish_order": order, "extra_joints": ["gripper_left", "gripper_right"], "command_timeout": 0.05},
    )
    processes.append(sim)
    ctrl = start_node("control", domain.id, ["--object", "shelf", "--variant", "IO"])
    processes.append(ctrl)
    first = probe.wait_for(lambda: probe.get("joint_states"), "joint states from the sim robot")[0][1]
    assert list(first.name) == order + ["gripper_left", "gripper_right"]
    start = grasp_to_handle(scene, first, 0.0)
    probe.wait_for(
        lambda: grasp_to_handle(scene, probe.get("joint_states")[-1][1], 0.0) < start - 0.3,
        "the hand to close 0.3 m on the handle",
    )
    assert (probe.status("diagnostics", "sabre/controller") or {}).get("rejected") == "0"
    print(f"grasp to handle {start:.3f} m -> {grasp_to_handle(scene, probe.get('joint_states')[-1][1], 0.0):.3f} m")

    ctrl.kill()
    status = probe.wait_for(
        lambda: (lambda s: s if s and json.loads(s["stop_delays_ms"]) else None)(probe.status("sim_status", "sabre/sim_robot")),
        "the sim robot to stop",
    )
    delays = json.loads(status["stop_delays_ms"])
    print("stop delays (ms)", delays)
    assert delays[-1] <= 50.0 + 1.0 + 1e-6
    probe.wait_for(lambda: np.linalg.norm(probe.get("joint_states")[-1][1].velocity) < 0.02, "the robot to come to rest")


def test_controller_zeroes_its_commands_when_the_sim_robot_dies(bridge):
    domain, probe, processes = bridge
    sim = start_node("sim-robot", domain.id, ["--object", "drawer"])
    processes.append(sim)
    ctrl = start_node("control", domain.id, ["--object", "drawer", "--variant", "N"], {"state_timeout": 0.05})
    processes.append(ctrl)
    probe.wait_for(lambda: any(np.any(np.asarray(m.data) != 0.0) for _, m in probe.get("arm")), "non-zero arm commands")
    sim.kill()
    probe.wait_for(
        lambda: (probe.status("diagnostics", "sabre/controller") or {}).get("state_stale") == "true",
        "the controller to flag the state stale",
    )
    probe.wait_for(lambda: np.all(np.asarray(probe.get("arm")[-1][1].data) == 0.0), "a zero arm command")
    status = probe.status("diagnostics", "sabre/controller")
    assert json.loads(status["stale_zero_age_ms"])[-1] >= 50.0
    assert ctrl.process.poll() is None


def test_the_sim_robot_counts_an_answer_per_state_it_names_over_the_states_published_while_answers_came(bridge):
    """The probe answers every tenth joint state it receives (an echo with that state's stamp)
    for a while, and sends three echoes with stamps no state had. The sim robot matches each
    real echo to its state, counts the made-up ones apart, and divides by the states it
    published from the first answered to the last: a tenth, whatever it published before or after."""
    domain, probe, processes = bridge
    sim = start_node("sim-robot", domain.id, ["--object", "shelf"])
    processes.append(sim)
    echo_pub = probe.node.create_publisher(probe.JointState, "/sabre/command", 50)
    answered: list[float] = []
    received = [0]
    answering = threading.Event()

    def answer(msg):
        received[0] += 1
        if answering.is_set() and received[0] % 10 == 0:
            echo = probe.JointState(name=list(msg.name))
            echo.header.stamp = msg.header.stamp
            echo_pub.publish(echo)
            answered.append(msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec)

    probe.node.create_subscription(probe.JointState, "/joint_states", answer, 100)
    probe.wait_for(lambda: received[0] > 200, "joint states from the sim robot")
    answering.set()
    probe.wait_for(lambda: len(answered) >= 150, "150 answers")
    answering.clear()
    for k in range(3):
        made_up = probe.JointState()
        made_up.header.stamp = stamp_of(1.0 + 0.001 * k)
        echo_pub.publish(made_up)
    n = len(answered)
    status = probe.wait_for(
        lambda: (lambda s: s if s and int(s["echoes"]) == n and int(s["unmatched_echoes"]) == 3 else None)(
            probe.status("sim_status", "sabre/sim_robot")
        ),
        "the sim robot's count of the answers",
    )
    window = int(status["answered_window"])
    span_ticks = (answered[-1] - answered[0]) / 0.001 + 1  # the sim robot publishes a state per 1 ms tick
    print(f"{n} answers, window {window} states, span {span_ticks:.0f} ms, published {status['states_published']}")
    assert abs(window - span_ticks) <= 0.05 * span_ticks
    assert int(status["states_published"]) > window + 200  # states before the first answer are outside
    assert float(status["delivered_fraction"]) == pytest.approx(n / window)
    assert 0.07 < n / window < 0.13
