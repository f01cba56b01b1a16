"""The estimates a controller on a real robot needs (sabre.estimation): τ_ext of a wrist wrench in
world or sensor axes against the plant's contact torques, and the hand-pose object-state estimator
while hooked, after release, on a force drop-out, on a held door, on bad input and as the core
object a Rust loop takes over."""

from __future__ import annotations

import math

import numpy as np
import pytest

import sabre
from sabre.estimation import SENSOR_FRAME, LowPass, tau_ext_from_wrench


def hooked_plant(obj: str = "shelf"):
    scene = sabre.Scene.load(obj=obj)
    plant = sabre.Plant(scene, tau_ext_cutoff=None)
    plant.reset(sabre.paper.scenarios.hooked_state(scene))
    return scene, plant, sabre.LowLevelController(scene)


def test_tau_ext_from_the_wrist_wrench_equals_the_plants_contact_torques_in_world_and_sensor_axes():
    """Hooked on the shelf handle only the hand touches the object, so Jᵀw of the wrist sensor
    equals the plant's τ_ext; the same wrench in the sensor frame's own axes gives the same τ_ext."""
    scene, plant, low = hooked_plant()
    pull = np.zeros(scene.nu)
    pull[0] = -0.1
    compared = 0
    for _ in range(300):
        low.track(plant, pull, 1)
        if plant.contact and np.linalg.norm(plant.tau_ext) > 1.0:
            q, w = plant.state[: scene.nq], plant.wrench
            assert np.allclose(tau_ext_from_wrench(scene, q, w), plant.tau_ext, rtol=1e-9, atol=1e-9)
            r = scene.fk(q, SENSOR_FRAME)[:3, :3]
            local = np.concatenate([r.T @ w[:3], r.T @ w[3:]])
            assert np.allclose(tau_ext_from_wrench(scene, q, local, axes=SENSOR_FRAME), plant.tau_ext, atol=1e-9)
            compared += 1
    assert compared > 10


def test_low_pass_follows_a_step_with_its_time_constant_and_passes_through_without_a_cutoff():
    f = LowPass(10.0)
    f.update(np.zeros(2), 0.001)
    tau = 1.0 / (2 * math.pi * 10.0)
    y = f.update(np.ones(2), tau)
    assert np.allclose(y, 1 - math.exp(-1))
    assert np.array_equal(LowPass(None).update(np.array([3.0]), 0.1), [3.0])


@pytest.mark.parametrize("obj", ["shelf", "drawer"])
def test_estimator_tracks_the_plants_articulation_during_hook_and_pull(obj):
    scene = sabre.Scene.load(obj=obj)
    motion = sabre.hook_and_pull(scene)
    plant = sabre.Plant(scene)
    low = sabre.LowLevelController(scene)
    plant.reset(scene.default_state())
    nq = scene.nq
    estimator = sabre.ObjectStateEstimator(scene, scene.default_state()[2 * nq : 2 * nq + 1])
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


def hooked_estimator(scene, **options):
    """An estimator hooked on the handle at the closed object (the hand put right at the handle)."""
    estimator = sabre.ObjectStateEstimator(scene, **options)
    q = sabre.paper.scenarios.hooked_state(scene)[: scene.nq]
    e = estimator.update(q, 0.0, 10.0)
    assert e.hooked, "the hooked state is within hook_distance of the handle"
    return estimator, q


def test_estimator_hooks_only_when_allowed_and_the_hand_is_at_the_handle_in_contact():
    """At the hooked state in contact the estimator hooks unless told it may not (the task's hook
    not seated yet), and never without force."""
    scene = sabre.Scene.load(obj="shelf")
    q = sabre.paper.scenarios.hooked_state(scene)[: scene.nq]
    estimator = sabre.ObjectStateEstimator(scene)
    for k in range(20):
        assert not estimator.update(q, 0.01 * k, 10.0, may_hook=False).hooked
    assert not estimator.update(q, 0.2, 0.0).hooked  # no contact force
    assert estimator.update(q, 0.21, 10.0).hooked


def test_estimator_releases_when_the_hand_leaves_the_handle_and_holds_the_last_state_at_rest():
    scene = sabre.Scene.load(obj="shelf")
    estimator, q = hooked_estimator(scene)
    before = estimator.update(q, 0.01, 10.0)
    away = q.copy()
    away[0] -= 0.3  # the base backs off: the hand is 0.3 m from the handle
    e = estimator.update(away, 0.02, 10.0)
    assert not e.hooked and e.velocity[0] == 0.0
    assert e.position[0] == pytest.approx(before.position[0])
    # and it stays released and at rest while the hand is away
    for k in range(5):
        e = estimator.update(away, 0.03 + 0.01 * k, 10.0)
        assert not e.hooked and e.velocity[0] == 0.0 and e.position[0] == pytest.approx(before.position[0])


def moved_hand(scene, q, frame, delta):
    """q with the hand frame's origin moved by ``delta`` (3,) in the world: resolved-rate steps on
    the position rows of the frame's Jacobian."""
    q = q.copy()
    target = scene.fk(q, frame)[:3, 3] + np.asarray(delta)
    for _ in range(100):
        error = target - scene.fk(q, frame)[:3, 3]
        if np.linalg.norm(error) < 1e-7:
            break
        q += np.linalg.lstsq(scene.jacobian(q, frame)[:3], error, rcond=None)[0]
    assert np.linalg.norm(target - scene.fk(q, frame)[:3, 3]) < 1e-6
    return q


def test_a_hook_sliding_along_the_bar_holds_until_it_slides_off_and_leaving_across_releases():
    """The shelf's bar is the handle frame's x (vertical): sliding along it within slide_distance
    keeps the hook and the closed door's estimate; past it, or as far across, releases."""
    scene = sabre.Scene.load(obj="shelf")
    handle = scene.object_fk(np.array([0.0]), "handle_frame")
    bar, across = handle[:3, 0], handle[:3, 2]  # along the bar; the handle frame's z, off the bar
    for delta, hooked in ((0.06 * bar, True), (-0.08 * bar, True), (0.15 * bar, False), (0.06 * across, False)):
        estimator, q0 = hooked_estimator(scene, slide_distance=0.1, release_distance=0.04)
        e = estimator.update(moved_hand(scene, q0, estimator.hand_frame, delta), 0.01, 10.0)
        assert e.hooked == hooked, delta
        if hooked:
            assert abs(e.position[0]) < 1e-3 and e.residual < 1e-3


def turned_about_the_hinge(scene, q, angle):
    """q with the holonomic base carried around the shelf's vertical hinge as the door turns by
    ``angle`` (rad of o), so that the hand keeps its place on the handle. The hinge is found from
    the handle's poses at two openings, independently of the estimator."""
    if angle == 0.0:
        return q.copy()
    h0, h1 = (scene.object_fk(np.array([o]), "handle_frame") for o in (0.0, angle))
    turn = math.atan2(h1[1, 2], h1[0, 2]) - math.atan2(h0[1, 2], h0[0, 2])  # of the handle's horizontal normal
    c, s = math.cos(turn), math.sin(turn)
    rotation = np.array([[c, -s], [s, c]])
    hinge = np.linalg.solve(np.eye(2) - rotation, h1[:2, 3] - rotation @ h0[:2, 3])
    out = q.copy()
    out[:2] = hinge + rotation @ (q[:2] - hinge)
    out[2] += turn
    return out


def hand_in_handle(scene, q, o):
    handle = scene.object_fk(np.array([o]), "handle_frame")
    return handle[:3, :3].T @ (scene.fk(q, "grasp")[:3, 3] - handle[:3, 3])


def test_a_lost_hook_holds_the_estimate_and_a_new_one_finds_the_object_where_the_hand_is():
    """The task loses its hook (may_hook False): the estimate releases and holds, whatever the hand
    does; the door swings on to 0.5 rad unheld, and the hand that hooks it there re-acquires 0.5."""
    scene = sabre.Scene.load(obj="shelf")
    estimator, q = hooked_estimator(scene)
    assert estimator.update(q, 0.01, 10.0).hooked
    for k, angle in enumerate((0.0, 0.2, 0.4)):  # the hand goes round with a door that is not there
        e = estimator.update(turned_about_the_hinge(scene, q, angle), 0.02 + 0.01 * k, 10.0, may_hook=False)
        assert not e.hooked and e.position[0] == pytest.approx(0.0, abs=1e-9) and e.velocity[0] == 0.0
    there = turned_about_the_hinge(scene, q, 0.5)
    assert np.allclose(hand_in_handle(scene, there, 0.5), hand_in_handle(scene, q, 0.0), atol=1e-9)
    e = estimator.update(there, 0.1, 10.0)
    # found again up to the hand's offset from the handle frame over the handle's radius about the
    # hinge (the estimator takes the handle nearest the hand: it knows no other offset then)
    h0, h1 = (scene.object_fk(np.array([o]), "handle_frame")[:3, 3] for o in (0.0, 0.5))
    radius = np.linalg.norm(h1 - h0) / (2.0 * math.sin(0.25))
    assert e.hooked and abs(e.position[0] - 0.5) <= np.linalg.norm(hand_in_handle(scene, q, 0.0)) / radius + 1e-3


def test_estimator_releases_after_the_force_stays_away_longer_than_release_time_only():
    scene = sabre.Scene.load(obj="shelf")
    estimator, q = hooked_estimator(scene, release_time=0.5, contact_force=1.0)
    t = 0.0
    for _ in range(40):  # 0.4 s without force: a drop-out shorter than release_time
        t += 0.01
        assert estimator.update(q, t, 0.0).hooked
    assert estimator.update(q, t + 0.01, 5.0).hooked  # force back: the timer restarts
    for _ in range(49):
        t += 0.01
        assert estimator.update(q, t + 0.01, 0.0).hooked
    assert not estimator.update(q, t + 0.2, 0.0).hooked  # past release_time without force


def test_estimator_on_a_held_door_stays_near_its_opening_and_holds_once_the_hook_slips_off():
    """The door held fixed while the hooked hand pulls: while the hook holds, the estimate stays
    within the hand's compliance of the true opening; the pull then drags the hook off the bar
    (the force collapses; the slip itself reads as opening, bounded by release_time), and once
    released the estimate holds, however far the hand goes."""
    scene, plant, low = hooked_plant()
    plant.hold_object(True)
    nq = scene.nq
    held_at = float(plant.state[2 * nq])
    estimator = sabre.ObjectStateEstimator(scene, plant.state[2 * nq : 2 * nq + 1])
    pull = np.zeros(scene.nu)
    pull[0] = -0.05
    rows = []
    for _ in range(3000):
        low.track(plant, pull, 1)
        x = plant.state
        e = estimator.update(x[:nq], plant.time, float(np.linalg.norm(plant.wrench[:3])))
        rows.append((e.position[0], e.velocity[0], e.hooked, scene.fk(x[:nq], "grasp")[0, 3]))
        assert abs(plant.state[2 * nq] - held_at) < 1e-3  # held
    position, rate, hooked, hand_x = (np.array(c, dtype=float) for c in zip(*rows))
    holding = slice(0, 800)  # 0.8 s of pull: the hook still on the bar
    assert np.all(np.abs(position[holding] - held_at) < 0.01) and np.all(np.abs(rate[holding]) < 0.05)
    released = int(np.argmin(hooked))
    assert not hooked[released] and not hooked[released:].any()
    assert hand_x[released] - hand_x[-1] > 0.05  # the hand went on backing away …
    assert np.all(position[released:] == position[released]) and np.all(rate[released:] == 0.0)  # … the estimate held
    assert position[released] - held_at < 0.25  # the slip before the release, at most


def test_estimator_rejects_bad_input_and_keeps_its_estimate():
    scene = sabre.Scene.load(obj="shelf")
    estimator, q = hooked_estimator(scene)
    good = estimator.update(q, 0.01, 10.0)
    for args, error in (
        ((np.where(np.arange(scene.nq) == 4, math.nan, q), 0.02, 1.0), sabre.InvalidValueError),
        ((q[:-1], 0.02, 1.0), sabre.ShapeError),
        ((q, math.nan, 1.0), sabre.InvalidValueError),
        ((q, 0.02, -1.0), sabre.InvalidValueError),
        ((q, 0.02, math.nan), sabre.InvalidValueError),
    ):
        with pytest.raises(error):
            estimator.update(*args)
    after = estimator.update(q, 0.02, 10.0)
    assert after.hooked and after.position[0] == pytest.approx(good.position[0], abs=1e-9)
    # a stamp going backwards counts as no time passed: no rate from it
    back = estimator.update(q, 0.0, 10.0)
    assert back.hooked and math.isfinite(back.velocity[0])
    with pytest.raises(sabre.InvalidValueError):
        sabre.ObjectStateEstimator(scene, hand_frame="nowhere")
    with pytest.raises(sabre.UnknownFrameError):
        sabre.ObjectStateEstimator(scene, handle="nowhere")


def test_the_ros_modules_re_export_the_core_estimates():
    from sabre.ros import conversions, estimator

    assert conversions.LowPass is LowPass and conversions.tau_ext_from_wrench is tau_ext_from_wrench
    assert estimator.ObjectStateEstimator is sabre.ObjectStateEstimator


def test_the_core_estimator_is_the_wrappers_state_and_a_copy_of_it_runs_on_alone():
    """``core`` is the estimator the wrapper runs (its estimate is the wrapper's); a copy taken while
    hooked continues from the same state, and what it is fed later leaves the original untouched."""
    import copy

    scene = sabre.Scene.load(obj="shelf")
    estimator, q = hooked_estimator(scene)
    core = estimator.core
    assert core.hooked and core.hand_frame == estimator.hand_frame == "grasp"
    assert core.hook_point is not None and np.linalg.norm(core.hook_point) <= estimator.hook_distance
    twin = copy.copy(core)
    lifted = q.copy()
    lifted[4] += 0.4  # the shoulder lifts the hand off the handle
    e = estimator.update(q, 0.01, 10.0)
    assert (core.position, core.velocity, core.hooked) == (e.position[0], e.velocity[0], e.hooked)
    assert twin.update(q, 0.01, 10.0, True) == (e.position[0], e.velocity[0], e.hooked, e.residual)
    assert not twin.update(lifted, 0.02, 10.0, True)[2]
    assert estimator.hooked and estimator.update(q, 0.02, 10.0).hooked
