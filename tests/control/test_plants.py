"""The plant protocol (sabre.PlantInterface): a simulator wrapped in pure Python drives the same closed loop
as sabre.Plant's Rust fast path, to rounding; a velocity-interface plant with its own servo gets the filtered
command; an object that is not a plant is refused, naming what it lacks."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import sabre
from sabre.errors import InvalidValueError
from sabre.paper import scenarios
from sabre.plants import PLANT_MEMBERS, as_plant

SECONDS = 0.3


class WrappedSimulator:
    """A user's simulator behind the protocol, as a user would write the wrapper: here the simulator is a
    sabre.Plant, reached only through its public API, one call per member."""

    command_interface = "torque"

    def __init__(self, scene: sabre.Scene) -> None:
        self.scene = scene
        self._sim = sabre.Plant(scene)
        self.steps = 0

    @property
    def dt(self) -> float:
        return self._sim.dt

    @property
    def time(self) -> float:
        return self._sim.time

    @property
    def state(self) -> np.ndarray:
        return self._sim.state

    def step(self, command: np.ndarray) -> None:
        self.steps += 1
        self._sim.step(command)

    @property
    def measured_tau_ext(self) -> np.ndarray:
        return self._sim.measured_tau_ext

    @property
    def tau_ext(self) -> np.ndarray:
        return self._sim.tau_ext

    @property
    def wrench(self) -> np.ndarray:
        return self._sim.wrench

    @property
    def contact(self) -> bool:
        return self._sim.contact

    def contacts(self) -> list[sabre.ContactPoint]:
        return self._sim.contacts()

    def reset(self, x0=None) -> None:
        self._sim.reset(x0)

    def hold_object(self, flag: bool) -> None:
        self._sim.hold_object(flag)

    @property
    def object_held(self) -> bool:
        return self._sim.object_held


class VelocityRobot(WrappedSimulator):
    """A robot with a joint velocity interface: its own servo (here the low-level controller (53) at the
    plant's step) turns each velocity command into joint torques."""

    command_interface = "velocity"

    def __init__(self, scene: sabre.Scene) -> None:
        super().__init__(scene)
        self.servo = sabre.LowLevelController(scene, dt=self.dt)
        self.commands: list[np.ndarray] = []

    def reset(self, x0=None) -> None:
        super().reset(x0)
        self.servo.reset()
        self.commands.clear()

    def step(self, command: np.ndarray) -> None:
        self.commands.append(np.array(command))
        super().step(self.servo.torque(self.state, command))


@pytest.fixture(scope="module")
def hooked():
    """The shelf scene with the hook against the handle's bar (contact from the first step)."""
    scene = sabre.Scene.load()
    return scene, scenarios.hooked_state(scene)


def _pull_from_the_start(t, x, plant, controller):
    if t == 0.0:
        controller.set_phase("open", t)


def _episode(scene, x0, plant=None, **kw):
    """IO pulling on the hooked handle with the tank 0.3 J above its floor, so that the passivity row binds."""
    config = sabre.ControllerConfig(variant="IO", rollouts=16, seed=4, threads=1, tank_initial=2.3)
    controller = sabre.Controller(scene, sabre.tasks.OpenObject(), config)
    episode = sabre.run_episode(
        scene,
        controller,
        SECONDS,
        seed=4,
        x0=x0,
        plant=plant,
        record_every=1,
        stop_on_success=False,
        progress=False,
        on_replan=_pull_from_the_start,
        **kw,
    )
    return episode, controller.tank.refilled


def _assert_same_episode(a: sabre.Episode, b: sabre.Episode) -> None:
    np.testing.assert_allclose(a.time, b.time, rtol=0.0, atol=1e-9)
    np.testing.assert_allclose(a.state, b.state, rtol=0.0, atol=1e-9)
    np.testing.assert_allclose(a.tank_energy, b.tank_energy, rtol=0.0, atol=1e-9)
    np.testing.assert_allclose(a.command, b.command, rtol=0.0, atol=1e-9)
    np.testing.assert_allclose(a.tau_ext_measured, b.tau_ext_measured, rtol=0.0, atol=1e-9)
    np.testing.assert_allclose(a.wrench, b.wrench, rtol=0.0, atol=1e-9)
    np.testing.assert_array_equal(a.contact, b.contact)
    np.testing.assert_array_equal(a.phase, b.phase)


def test_sabre_plant_and_a_wrapped_simulator_are_plants_and_members_match_the_protocol(scene):
    assert PLANT_MEMBERS == tuple(n for n in vars(sabre.PlantInterface) if not n.startswith("_"))
    assert sabre.Plant.command_interface == "torque"
    for plant in (sabre.Plant(scene), WrappedSimulator(scene), VelocityRobot(scene)):
        assert isinstance(plant, sabre.PlantInterface)
        assert as_plant(plant, scene) is plant
    assert not isinstance(object(), sabre.PlantInterface)


@pytest.mark.parametrize("plan_delay", [0.0, 0.02], ids=["undelayed", "delayed"])
def test_an_episode_through_a_wrapped_simulator_is_the_fast_paths_episode(hooked, plan_delay):
    """The same seed through the wrapper (stepped from Python, one core tick per step) and through
    sabre.Plant (the Rust follow): the same states, tank, commands and readings to 1e-9, with contact, the
    passivity row and the refill at work."""
    scene, x0 = hooked
    fast, fast_refill = _episode(scene, x0, plan_delay=plan_delay)
    wrapper = WrappedSimulator(scene)
    wrapped, wrapped_refill = _episode(scene, x0, plant=wrapper, plan_delay=plan_delay)
    _assert_same_episode(fast, wrapped)
    assert abs(fast_refill - wrapped_refill) <= 1e-9
    assert wrapper.steps == len(fast.time) == round(SECONDS / wrapper.dt)
    # What the comparison covers: contact, a tank the exchange moved and refilled, a binding passivity row.
    assert fast.contact.mean() > 0.5
    assert np.ptp(fast.tank_energy) > 0.01 and fast_refill > 0.01
    assert np.abs(fast.command - fast.reference).max() > 1e-3


def test_a_velocity_robot_gets_the_filtered_command_and_its_servo_reproduces_the_torque_loop(hooked):
    """A velocity plant gets the tick's command (after the filter); its own servo with the low-level
    controller's gains then drives the very episode the torque loop drives."""
    scene, x0 = hooked
    robot = VelocityRobot(scene)
    by_velocity, _ = _episode(scene, x0, plant=robot)
    np.testing.assert_array_equal(np.array(robot.commands), by_velocity.command)
    assert np.abs(by_velocity.command - by_velocity.reference).max() > 1e-3  # the filter changed commands
    _assert_same_episode(_episode(scene, x0)[0], by_velocity)


def test_follow_and_track_record_the_same_trace_for_any_plant(hooked):
    """LowLevelController.follow on the wrapper, every third step recorded, with filter, tank and refill:
    every Trace field equal to the fast path's; track likewise."""
    scene, x0 = hooked
    motion = sabre.hook_and_pull(scene, scene.default_state())
    U = np.ascontiguousarray(motion.U[int(np.argmax(motion.phases == 3)) :])
    predicted = np.linspace(0.0, 2.0, len(U))
    traces = []
    for plant in (sabre.Plant(scene), WrappedSimulator(scene)):
        plant.reset(x0)
        low = sabre.LowLevelController(scene, dt=plant.dt)
        tank = sabre.EnergyTank(2.5, 2.0, refill=sabre.TankRefill())
        safety = sabre.SafetyFilter(scene)
        traces.append(low.follow(plant, U, 0.0, motion.dt, 200, 3, safety=safety, tank=tank, predicted_dissipation=predicted))
        low.track(plant, U[0], steps=20)
        traces.append(plant.state)
    fast, fast_after, wrapped, wrapped_after = traces
    assert len(fast.time) == 67 and fast.filter_status == wrapped.filter_status
    for field in ("time", "state", "reference", "filtered", "tank_energy", "wrench", "tau_ext", "tau_ext_measured"):
        np.testing.assert_allclose(getattr(wrapped, field), getattr(fast, field), rtol=0.0, atol=1e-9, err_msg=field)
    np.testing.assert_array_equal(wrapped.contact, fast.contact)
    assert wrapped.contact.dtype == bool and wrapped.state.shape == (67, scene.nx)
    np.testing.assert_allclose(wrapped_after, fast_after, rtol=0.0, atol=1e-9)


def test_track_hands_a_velocity_robot_the_reference(scene):
    robot = VelocityRobot(scene)
    robot.reset()
    u = np.full(scene.nq, 0.1)
    sabre.LowLevelController(scene).track(robot, u, steps=3)
    assert len(robot.commands) == 3 and all(np.array_equal(c, u) for c in robot.commands)


class _HalfAPlant:
    command_interface = "torque"

    def __init__(self, scene):
        self.scene, self.dt, self.time = scene, 0.001, 0.0

    def step(self, command):
        pass


def test_an_object_that_is_not_a_plant_is_refused_naming_what_it_lacks(scene):
    half = _HalfAPlant(scene)
    assert not isinstance(half, sabre.PlantInterface)
    lacking = "state, measured_tau_ext, tau_ext, wrench, contact, contacts, reset, hold_object, object_held"
    controller = sabre.Controller(scene, sabre.tasks.OpenObject(), sabre.ControllerConfig(rollouts=8, seed=0))
    low = sabre.LowLevelController(scene)
    for call in (
        lambda: sabre.run_episode(scene, controller, 0.1, plant=half, progress=False),
        lambda: low.follow(half, np.zeros((3, scene.nq)), 0.0, 0.02, 5),
        lambda: low.track(half, np.zeros(scene.nq)),
    ):
        with pytest.raises(TypeError, match=f"_HalfAPlant is not a sabre.PlantInterface; it lacks {lacking}$"):
            call()


def test_a_plant_with_an_unknown_interface_or_another_robot_is_refused(scene):
    odd = WrappedSimulator(scene)
    odd.command_interface = "position"
    with pytest.raises(InvalidValueError, match="command_interface"):
        as_plant(odd, scene)
    other = WrappedSimulator(scene)
    other.scene = SimpleNamespace(nq=scene.nq, nx=scene.nx + 2)  # an object with two joints
    with pytest.raises(InvalidValueError, match=f"nx = {scene.nx + 2}"):
        as_plant(other, scene)
    with pytest.raises(InvalidValueError):
        sabre.LowLevelController(scene).follow(other, np.zeros((3, scene.nq)), 0.0, 0.02, 5)


def test_the_experiments_run_on_any_plant():
    """The scenarios take a plant factory and the runner names one ("module:factory"), keeping those runs
    apart in the cache; the wrapped simulator gives the Rapier plant's episode."""
    from sabre.experiments import runner

    name = "test_plants:WrappedSimulator"
    runs = runner.specs("fig8", 1, True, plant=name)
    plain = runner.specs("fig8", 1, True)
    assert [r.options for r in runs] == [{**r.options, "plant": name} for r in plain]
    assert {r.key for r in runs}.isdisjoint(r.key for r in plain)
    assert runner.specs("fig3", 1, True, plant=name) == runner.specs("fig3", 1, True)  # no plant in fig3
    assert all(r.options["plant"] == name for r in runner.acceptance_specs([0], duration=1.0, plant=name))
    with pytest.raises(InvalidValueError, match="module:attribute"):
        runner.specs("fig8", 1, True, plant="no_such_module:Plant")
    wrapped = scenarios.object_manipulation("IO", seed=0, duration=0.1, plant=WrappedSimulator)
    fast = scenarios.object_manipulation("IO", seed=0, duration=0.1)
    np.testing.assert_allclose(wrapped.episode.state, fast.episode.state, rtol=0.0, atol=1e-9)
    np.testing.assert_allclose(wrapped.episode.tank_energy, fast.episode.tank_energy, rtol=0.0, atol=1e-9)
