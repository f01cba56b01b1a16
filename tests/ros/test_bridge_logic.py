"""The bridge's logic without ROS (plain Python and the core's rate limiter): message conversions,
joint states merged by name with a staleness per joint, odometry and wrench frames, QoS parameters,
command limits, the command gate's ramps on a fake clock, Franka's reflexes, the descriptions the
scene is built from, and obstacles by id."""

from __future__ import annotations

import math

import numpy as np
import pytest

import sabre
from sabre.ros import params, qos
from sabre.ros.commands import CommandGate, CommandShaper, Limits, command_limits, joint_accelerations
from sabre.ros.conversions import JointMap, MessageError, base_to_world, quaternion_of, rpy_of, world_to_base, yaw_of
from sabre.ros.descriptions import DescriptionSources, build_scene
from sabre.ros.inputs import JointStates, JointTorques, WrenchFrames, base_from_odometry
from sabre.ros.reflexes import FrankaReflexes
from sabre.ros.visualization import ObstacleRegistry, active_constraints


def test_joint_map_takes_any_order_ignores_extra_joints_and_rejects_missing_ones():
    m = JointMap(("a", "b", "c"))
    assert np.array_equal(m.values(["extra1", "c", "a", "extra2", "b"], [9.0, 3.0, 1.0, 8.0, 2.0], "position"), [1.0, 2.0, 3.0])
    with pytest.raises(MessageError, match="lacks joints"):
        m.values(["a", "b", "x"], [1.0, 2.0, 3.0], "position")
    with pytest.raises(MessageError, match="2 values for 3 names"):
        m.values(["a", "b", "c"], [1.0, 2.0], "position")
    with pytest.raises(MessageError, match="non-finite"):
        m.values(["a", "b", "c"], [1.0, math.nan, 3.0], "position")


def test_base_rates_rotate_by_yaw_and_quaternions_round_trip():
    rng = np.random.default_rng(1)
    for _ in range(20):
        rates, yaw = rng.normal(size=3), rng.uniform(-math.pi, math.pi)
        assert np.allclose(base_to_world(world_to_base(rates, yaw), yaw), rates)
        rpy = (rng.uniform(-3, 3), rng.uniform(-1.5, 1.5), rng.uniform(-3, 3))
        q = quaternion_of(*rpy)
        assert np.allclose(rpy_of(*q), rpy) and yaw_of(*q) == pytest.approx(rpy[2])
        assert np.allclose(rpy_of(*(2.0 * np.asarray(q))), rpy)  # normalised first
    assert np.allclose(world_to_base([1.0, 0.0, 0.2], math.pi / 2), [0.0, -1.0, 0.2])
    with pytest.raises(MessageError):
        rpy_of(0.0, 0.0, 0.0, 0.0)


def test_joint_states_merge_publishers_by_name_each_joint_with_its_own_staleness():
    """The arm's states tick, the fingers' and another driver's merge without ticking; each joint
    goes stale after its own timeout; a malformed message changes nothing."""
    names = ("base_x", "base_y", "base_yaw", "j1", "j2")
    states = JointStates(names, ("j1", "j2"), [0.1, 0.1, 0.1, 0.01, 0.01])
    assert not states.update(["finger", "base_x"], [0.04, 1.0], [], received=0.0)  # no velocity field: zeros
    assert states.update(["j2", "finger", "j1"], [2.0, 0.04, 1.0], [0.2, 0.0, 0.1], received=0.0)
    assert np.array_equal(states.position, [1.0, 0.0, 0.0, 1.0, 2.0]) and np.array_equal(states.velocity, [0, 0, 0, 0.1, 0.2])
    assert states.stale(0.005) == ["base_y", "base_yaw"]  # never received
    states.set(np.array([1, 2]), [0.5, 0.1], [0.0, 0.0], received=0.0)
    assert states.fresh(0.005) and states.stale(0.05) == ["j1", "j2"] and not states.stale(0.01)
    before = states.position.copy()
    for bad in (
        (["j1", "j2"], [1.0], [0.0, 0.0]),
        (["j1", "j2"], [1.0, math.nan], [0.0, 0.0]),
        (["j1", "j2"], [1.0, 2.0], [0.0]),
    ):
        with pytest.raises(MessageError):
            states.update(*bad, received=1.0)
    assert np.array_equal(states.position, before) and states.fresh(0.005)
    with pytest.raises(MessageError):
        JointStates(names, ("j9",), 0.1)


def test_odometry_twist_in_the_child_frame_is_rotated_into_world_rates():
    q, rates = base_from_odometry(1.0, 2.0, math.pi / 2, (1.0, 0.0, 0.3), twist_in_child_frame=True)
    assert q == (1.0, 2.0, math.pi / 2) and np.allclose(rates, [0.0, 1.0, 0.3])
    _, world = base_from_odometry(1.0, 2.0, math.pi / 2, (1.0, 0.0, 0.3), twist_in_child_frame=False)
    assert world == (1.0, 0.0, 0.3)
    with pytest.raises(MessageError):
        base_from_odometry(math.nan, 0.0, 0.0, (0.0, 0.0, 0.0), True)


def test_wrench_frames_take_the_headers_axes_and_reject_unknown_frames():
    scene = sabre.Scene.load(obj="shelf")
    frames = WrenchFrames(scene, "odom", "panda_link8")
    assert frames.resolve("") == ("panda_link8", "panda_link8")  # the sensor frame when the header names none
    assert frames.resolve("odom") == (None, "panda_link8") and frames.resolve("world") == (None, "panda_link8")
    assert frames.resolve("panda_link0") == ("panda_link0", "panda_link0")
    with pytest.raises(MessageError, match="neither"):
        frames.resolve("camera_link")
    q = sabre.paper.paper_start_state(scene)[: scene.nq]
    w = np.array([1.0, -2.0, 3.0, 0.1, 0.2, -0.3])
    r = scene.fk(q, "panda_link8")[:3, :3]
    local = np.concatenate([r.T @ w[:3], r.T @ w[3:]])
    # the same wrench in the sensor's axes (empty header) and in world axes: the same τ_ext, J(q)ᵀ w about the sensor
    expected = scene.jacobian(q, "panda_link8").T @ w
    assert np.allclose(frames.tau_ext(q, local, ""), expected, atol=1e-9)
    assert np.allclose(frames.tau_ext(q, w, "odom"), expected, atol=1e-9)
    with pytest.raises(MessageError, match="neither"):
        frames.tau_ext(q, w, "camera_link")
    with pytest.raises(MessageError):
        WrenchFrames(scene, "odom", "nowhere")
    torques = JointTorques(scene.joint_names, scene.nq, sign=-1.0)
    tau = torques.update(["panda_joint2", "other"], [3.0, 9.0])
    assert tau[4] == -3.0 and np.count_nonzero(tau) == 1


def test_qos_parameters_name_a_profile_and_a_depth():
    assert qos.parse("sensor") == (False, False, 10)
    assert qos.parse("reliable:1") == (True, False, 1)
    assert qos.parse("latched") == (True, True, 1)
    for bad in ("fast", "reliable:x", "sensor:0"):
        with pytest.raises(sabre.InvalidValueError):
            qos.parse(bad)
    # every endpoint's default: sensor inputs best effort, commands reliable, descriptions latched
    defaults = params.CONTROLLER_PARAMETERS
    assert all(defaults[k] == "sensor" for k in ("joint_state_qos", "odometry_qos", "wrench_qos", "tau_ext_qos"))
    assert defaults["arm_command_qos"] == defaults["cmd_vel_qos"] == "reliable"
    assert defaults["robot_description_qos"] == defaults["object_pose_qos"] == "latched"


def limits(**given):
    p = {"command_period": 0.001, "cmd_vel_rate": 50.0} | given
    return command_limits([2.175] * 4 + [2.61] * 3, [1.0, 1.0, 1.0], p)


def test_default_limits_come_from_the_urdf_and_franka_kept_robust_to_two_missed_commands():
    lim = limits()
    assert lim.arm.velocity == (2.175,) * 4 + (2.61,) * 3 and lim.base.velocity == (1.0, 1.0, 1.0)
    for a, j, a_max, j_max in zip(lim.arm.acceleration, lim.arm.jerk, params.FRANKA_ACCELERATION, params.FRANKA_JERK):
        assert a <= a_max and j == pytest.approx(0.9 * j_max)
        assert 3 * a / 0.001 <= 0.9 * j_max + 1e-9  # two missed cycles: the robot sees a jerk of 3a/dt
    assert lim.base_period == pytest.approx(0.02)
    assert (lim.base.acceleration, lim.base.jerk) == (params.BASE_ACCELERATION, params.BASE_JERK)
    assert limits(arm_velocity_limits=[1.0] * 7).arm.velocity == (1.0,) * 7
    with pytest.raises(sabre.InvalidValueError):
        limits(arm_jerk_limits=[1.0] * 6)


def check_stream(commands: np.ndarray, lim, dt: float) -> None:
    """Every step of a (T, n) command stream within the velocity, acceleration and jerk bounds."""
    a = np.diff(commands, axis=0) / dt
    jerk = np.diff(a, axis=0) / dt
    assert np.all(np.abs(commands) <= np.asarray(lim.velocity) + 1e-9)
    assert np.all(np.abs(a) <= np.asarray(lim.acceleration) * (1 + 1e-9) + 1e-6)
    assert np.all(np.abs(jerk) <= np.asarray(lim.jerk) * (1 + 1e-6) + 1e-3)


def test_gate_ramps_to_zero_on_a_fake_clock_once_states_stop_and_never_steps():
    """Ticks at 1 kHz follow a target; then no tick: nothing happens until state_timeout, the ramp's
    first step is due at most one period after it, steps come one period apart, and the streams come
    to rest within the limiter's bound with every step within the limits."""
    lim = limits()
    shaper = CommandShaper(lim)
    gate = CommandGate(shaper, state_timeout=0.05)
    assert gate.watchdog(10.0) == []  # nothing commanded yet: nothing to ramp
    target = np.array([1.0, -1.0, 0.5, 0.5, 1.0, 1.0, -1.0])
    stream = [np.zeros(7)]
    t = 0.0
    for _ in range(300):
        t += 0.001
        stream.append(gate.on_tick(t, target, np.array([0.3, 0.0, 0.1])).arm)
    last_tick = t
    bound = shaper.steps_to_rest
    assert gate.watchdog(last_tick + 0.05) == [] and gate.stale_events == 0
    looks = np.arange(last_tick + 0.0503, last_tick + 1.5, 0.0007)  # an irregular watchdog
    times = []
    for now in looks:
        steps = gate.watchdog(float(now))
        assert len(steps) <= 1  # one step per look: a late look slows the ramp, never steepens it
        for command in steps:
            times.append(gate.last_command)
            stream.append(command.arm)
    assert gate.stale_events == 1
    assert times[0] <= last_tick + 0.05 + 0.001 + 1e-9
    gaps = np.diff(times)
    assert np.all(gaps >= 0.001 - 1e-9) and np.all(gaps <= 0.001 + 0.0007 + 1e-9)
    assert shaper.at_rest and np.all(stream[-1] == 0.0)
    assert len(times) <= bound
    check_stream(np.array(stream), lim.arm, 0.001)
    ramp = np.array(stream[301:])
    assert np.all(ramp * np.sign(target) >= -1e-12)  # a stop never swings past zero
    # a tick resumes following, from rest
    assert np.abs(gate.on_tick(looks[-1] + 0.001, target, None).arm).max() <= max(lim.arm.acceleration) * 0.001 + 1e-12


def test_a_tick_without_targets_is_one_ramp_step_and_the_base_steps_at_its_own_rate():
    lim = limits()
    shaper = CommandShaper(lim)
    gate = CommandGate(shaper, state_timeout=0.05)
    target = np.full(7, 0.5)
    commands = [gate.on_tick(0.001 * k, target, np.array([0.5, 0.0, 0.0])) for k in range(200)]
    bases = [c.base for c in commands if c.base is not None]
    assert len(bases) == 10  # every 20th tick at 50 Hz
    check_stream(np.array([b for b in bases]), lim.base, lim.base_period)
    before = commands[-1].arm
    after = gate.on_tick(0.2, None, None).arm  # e-stop, rejected state, stale plan: one step toward zero
    assert np.all(np.abs(after - before) <= np.asarray(lim.arm.acceleration) * 0.001 + 1e-12)
    assert np.all(after <= before + 1e-12)


def test_franka_reflexes_trip_on_a_step_and_pass_the_robust_limiter_with_missed_cycles():
    reflexes = FrankaReflexes(0.001)
    assert reflexes.check(np.zeros(7)) is None
    assert "velocity_discontinuity" in reflexes.check(np.full(7, 0.1))  # 100 rad/s² in one cycle
    assert reflexes.aborted and reflexes.check(np.zeros(7)) is None and reflexes.aborts == 1
    reflexes.recover()
    lim = limits()
    shaper = CommandShaper(lim)
    rng = np.random.default_rng(3)
    target = np.zeros(7)
    for k in range(4000):
        if k % 150 == 0:
            target = rng.uniform(-2.0, 2.0, 7)
        command = shaper.step(target, None).arm
        if k % 97 in (5, 6):  # two cycles in a row the robot holds the previous command
            continue
        assert reflexes.check(command) is None, reflexes.aborted


@pytest.mark.parametrize("gap", [0.003, 0.005, 0.008])
def test_the_velocity_stream_keeps_its_promise_a_gap_up_to_tolerated_gap_passes_the_reflexes(gap):
    """The robot holds the last command through every gap of up to ``tolerated_gap`` (m missed
    cycles), wherever the gaps fall; the same stream with gaps twice as long trips a reflex."""
    misses = round(gap / 0.001) - 1

    def stream(hold: int) -> str | None:
        shaper = CommandShaper(limits(tolerated_gap=gap))
        reflexes = FrankaReflexes(0.001)
        rng = np.random.default_rng(5)
        target, in_effect = np.zeros(7), np.zeros(7)
        held = 0
        for k in range(6000):
            if k % 400 == 0:
                target = rng.uniform(-2.0, 2.0, 7)
            command = shaper.step(target, None).arm
            if held < hold and k % 23 >= 11:  # this cycle's command is late: the previous one holds
                held += 1
            else:
                held, in_effect = 0, command
            if (error := reflexes.check(in_effect)) is not None:
                return error
        return None

    assert stream(misses) is None
    assert stream(2 * misses + 2) is not None
    with pytest.raises(sabre.InvalidValueError, match="tolerated_gap"):
        limits(tolerated_gap=0.0005)


def test_a_fixed_base_has_the_arms_stream_only_and_a_six_joint_arm_passes_its_own_reflexes():
    """Without a base the shaper never emits a base twist and is at rest when the arm is; a UR-like
    six-joint arm's default limits (the slowest Franka joint's on every joint) shape a stream that
    its reflexes (the same rule, its own velocity limits) pass, also when the robot misses two
    commands in a row, while a step trips them."""
    velocity = [3.15, 3.15, 3.15, 3.2, 3.2, 3.2]
    lim = command_limits(velocity, None, {"command_period": 0.001, "cmd_vel_rate": 50.0})
    assert lim.base is None and len(lim.arm.acceleration) == 6
    shaper = CommandShaper(lim)
    gate = CommandGate(shaper, state_timeout=0.05)
    reflexes = FrankaReflexes.for_arm(0.001, velocity)
    target = np.array([1.0, -1.0, 0.5, 2.0, -2.0, 1.0])
    for k in range(6000):  # 2 s toward the target, then the ramp to rest (about 2 s at 1.125 rad/s²)
        command = gate.on_tick(0.001 * k, target if k < 2000 else None, None)
        assert command.base is None
        if k % 97 in (5, 6):  # two cycles in a row the robot holds the previous command
            continue
        assert reflexes.check(command.arm) is None, reflexes.aborted
    assert shaper.at_rest
    assert "velocity_discontinuity" in FrankaReflexes.for_arm(0.001, velocity).check(np.full(6, 0.1))
    # within the jerk of every Franka joint (3000 rad/s³ a cycle) up to 10 rad/s², which only the
    # slowest joint's acceleration (7.5 rad/s²) forbids: it trips the six-joint arm's reflexes
    accelerations = np.minimum(3.0 * np.arange(1, 40), 10.0)
    stream = np.cumsum(accelerations * 0.001)
    assert min(params.FRANKA_ACCELERATION) < 10.0 < max(params.FRANKA_ACCELERATION)
    assert np.abs(np.diff(accelerations, prepend=0.0)).max() / 0.001 <= min(params.FRANKA_JERK)
    six = FrankaReflexes.for_arm(0.001, velocity)
    tripped = [six.check(np.full(6, v)) for v in stream]
    assert any(e is not None and "velocity_discontinuity" in e for e in tripped), six.aborted


def test_descriptions_wait_for_the_robot_and_the_pose_and_reject_a_pose_in_another_frame(tmp_path):
    p = params.CONTROLLER_PARAMETERS | {"object_pose": [], "hold_joints": [], "hold_positions": [], "joint_names": []}
    sources = DescriptionSources(p)
    assert [m.split(" (")[0] for m in sources.missing()] == ["the robot description", "the object pose"]
    with pytest.raises(sabre.InvalidValueError, match="waiting for"):
        sources.descriptions()
    from sabre.assets import urdf_text

    sources.on_robot_description(urdf_text("royalpanda"))
    with pytest.raises(MessageError, match="world frame"):
        sources.on_object_pose("map", (1.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
    pose = sources.on_object_pose("odom", (1.3, 0.2, 0.0), quaternion_of(0.0, 0.0, 0.35))
    assert pose == pytest.approx((1.3, 0.2, 0.0, 0.0, 0.0, 0.35))
    scene = build_scene(sources.descriptions())
    assert np.allclose(scene.object_pose[:3, 3], [1.3, 0.2, 0.0])
    missing_file = p | {"robot_description_file": str(tmp_path / "none.urdf")}
    with pytest.raises(sabre.UrdfError):
        DescriptionSources(missing_file)
    with pytest.raises(sabre.InvalidValueError, match="6 finite"):
        DescriptionSources(p | {"object_pose": [1.0, 2.0]})


def test_obstacles_are_kept_by_id_moved_re_added_on_a_new_radius_and_cleared():
    calls = []
    ids = iter(range(100))
    registry = ObstacleRegistry(
        lambda c, r: calls.append(("add", tuple(c), r)) or next(ids),
        lambda i, c: calls.append(("move", i, tuple(c))),
        lambda i: calls.append(("remove", i)),
    )
    registry.apply(("a", 1), 0, (1.0, 0.0, 0.5), 0.1)
    registry.apply(("a", 2), 0, (2.0, 0.0, 0.5), 0.1)
    registry.apply(("a", 1), 0, (1.5, 0.0, 0.5), 0.1)  # same radius: moved
    registry.apply(("a", 2), 0, (2.0, 0.0, 0.5), 0.2)  # new radius: re-added
    registry.apply(("a", 1), 2, (0.0, 0.0, 0.0), 0.0)
    assert calls == [
        ("add", (1.0, 0.0, 0.5), 0.1),
        ("add", (2.0, 0.0, 0.5), 0.1),
        ("move", 0, (1.5, 0.0, 0.5)),
        ("remove", 1),
        ("add", (2.0, 0.0, 0.5), 0.2),
        ("remove", 0),
    ]
    registry.apply(("x", 0), 3, (0.0, 0.0, 0.0), 0.0)
    assert registry.obstacles == {} and calls[-1] == ("remove", 2)
    with pytest.raises(MessageError):
        registry.apply(("a", 3), 0, (math.nan, 0.0, 0.0), 0.1)
    assert active_constraints(["a", "b", "c"], np.array([0.01, math.nan, 1.0])) == ["a"]


def test_the_sim_robots_contact_record_gives_each_contact_ticks_wrist_force_magnitude():
    """The simulated robot's record of the hand's contact force, fed every tick of a plant pulling the
    shelf open by a scripted hook, holds exactly the ticks in contact with |f| of each tick's wrist
    force (computed here per tick with math.hypot), across the growth of its buffer; the episode's
    definition gives the same from the rows and their contact flags."""
    from sabre.episode import contact_force_stats, hand_contact_forces
    from sabre.ros.sim_robot import ContactRecord

    scene = sabre.Scene.load(obj="shelf")
    motion = sabre.hook_and_pull(scene)
    plant, low = sabre.Plant(scene), sabre.LowLevelController(scene)
    plant.reset(scene.default_state())
    record, wrenches, contacts, expected = ContactRecord(), [], [], []
    for u in motion.U:
        for _ in range(int(round(motion.dt / plant.dt))):
            low.track(plant, u, steps=1)
            w = plant.wrench
            wrenches.append(w)
            contacts.append(plant.contact)
            if plant.contact:
                record.record(plant.time, w)
                expected.append((plant.time, math.hypot(*w[:3])))
    times, forces = record.forces()
    assert len(expected) > 4096, "the pull outlasts the record's first buffer"
    np.testing.assert_array_equal(times, [t for t, _ in expected])
    np.testing.assert_allclose(forces, [f for _, f in expected], rtol=1e-12)
    np.testing.assert_allclose(hand_contact_forces(np.array(wrenches), np.array(contacts)), forces, rtol=1e-12)
    stats = contact_force_stats(forces)
    assert stats["steps"] == len(expected) and stats["max"] == pytest.approx(max(f for _, f in expected))


def test_the_planners_joint_accelerations_are_the_command_paths():
    """The arm's joints take their stream's (or segments') bounds; the base's world x and y the smaller
    of its frame's linear bounds: a world-frame acceleration of that size, at any heading, has base-frame
    components within both of the driver's bounds. A joint of neither stream has no bound to give."""
    base = (1.0, 0.5, 2.0)
    a = joint_accelerations(6, [3, 4, 5], [7.0, 8.0, 9.0], [0, 1, 2], Limits((1.0,) * 3, base, (10.0,) * 3))
    assert a == (0.5, 0.5, 2.0, 7.0, 8.0, 9.0)
    for yaw in np.linspace(-math.pi, math.pi, 37):
        for direction in np.linspace(0.0, 2 * math.pi, 36, endpoint=False):
            world = a[0] * np.array([math.cos(direction), math.sin(direction)])
            body = world_to_base(np.array([world[0], world[1], 0.0]), yaw)
            assert abs(body[0]) <= base[0] + 1e-12 and abs(body[1]) <= base[1] + 1e-12
    assert joint_accelerations(2, [0, 1], [3.0, 4.0], None, None) == (3.0, 4.0)
    with pytest.raises(sabre.SabreError, match="neither"):
        joint_accelerations(4, [3], [7.0], None, None)
