"""The open-object task's phase switch on the shelf: the grasp placed by an independent IK at each
phase's offset, the hook recognised only behind the bar, a finger stopped short or backing out, one
already dragging the handle, and the recovery from a slip."""

from __future__ import annotations

import itertools
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from se3_reference import se3_log

import sabre
from sabre import costs

ASSETS = Path(__file__).resolve().parents[2] / "assets"


@pytest.fixture(scope="module")
def scene():
    return sabre.Scene.load(obj="shelf")


def _place_grasp(scene, x, target, iterations=200):
    """Damped least-squares IK on the arm only (base fixed): grasp frame onto `target`."""
    x = x.copy()
    for _ in range(iterations):
        q = x[: scene.nq]
        pose = scene.fk(q, "grasp")
        xi = se3_log(np.linalg.solve(pose, target))
        err = np.r_[pose[:3, :3] @ xi[:3], pose[:3, :3] @ xi[3:]]
        j = scene.jacobian(q, "grasp")[:, 3:]
        x[3 : scene.nq] += j.T @ np.linalg.solve(j @ j.T + 1e-6 * np.eye(6), err)
    assert np.linalg.norm(np.linalg.solve(scene.fk(x[: scene.nq], "grasp"), target)[:3, 3]) < 1e-4
    return x


def test_open_object_walks_through_its_phases_and_recovers_from_a_slip(scene):
    task = sabre.tasks.OpenObject()
    x = scene.default_state()
    x[0] = 0.939 - 0.75  # base in front of the handle
    handle = scene.object_fk(np.zeros(1), "handle_frame")
    expected = {"approach": "insert", "insert": "hook", "hook": "open"}
    for phase, following in expected.items():
        at = _place_grasp(scene, x, handle @ task.grasp_offset(scene, phase))
        assert task.next_phase(scene, at, 0.0, phase) == following
        assert task.noise_scale(scene, at, phase) == pytest.approx(task.noise.floor)
    hooked = _place_grasp(scene, x, handle @ task.grasp_offset(scene, "open"))
    assert task.next_phase(scene, hooked, 0.0, "open") == "open"
    assert task.noise_scale(scene, hooked, "open") == task.noise.open
    slipped = _place_grasp(scene, x, handle @ task.grasp_offset(scene, "open") @ _translation(0.0, -0.015, 0.0))
    assert task.lateral_error(scene, slipped) == pytest.approx(-0.015, abs=1e-4)
    assert task.next_phase(scene, slipped, 0.0, "open") == "approach"
    # Far away, Σ is used as configured; the schedule shrinks it quadratically with the distance.
    assert task.noise_scale(scene, scene.default_state(), "approach") == pytest.approx(
        min(1.0, (task.approach_error(scene, scene.default_state(), "approach").distance / task.noise.distance) ** 2)
    )


def _urdf_box_corners(urdf, link, collision, frame_joint):
    """Corners (8, 4) of a link's collision box in the frame that `frame_joint` attaches to the
    same parent as the link, read straight from the URDF (fixed joints, no rotations)."""
    root = ET.parse(urdf).getroot()
    joints = {j.find("child").get("link"): j for j in root.findall("joint")}
    link_origin = np.array(joints[link].find("origin").get("xyz").split(), float)
    frame_origin = np.array(root.find(f"joint[@name='{frame_joint}']/origin").get("xyz").split(), float)
    box = root.find(f"link[@name='{link}']/collision[@name='{collision}']")
    centre = np.array(box.find("origin").get("xyz").split(), float) + link_origin - frame_origin
    half = 0.5 * np.array(box.find("geometry/box").get("size").split(), float)
    signs = np.array(list(itertools.product((-1.0, 1.0), repeat=3)))
    return np.hstack([centre + half * signs, np.ones((8, 1))])


def _at_insert_depth(scene, task, dz):
    """A state at rest with the grasp frame dz (m) along the handle frame's z from the insert
    target (the shelf closed, the base in front of it), and the depth in the handle frame of the
    hook tip's nearest corner (a box on the hook finger, read from the URDF)."""
    tip = _urdf_box_corners(ASSETS / "robots" / "royalpanda.urdf", "hook_finger", "tip", "grasp_joint")
    x = scene.default_state()
    x[0] = 0.939 - 0.75
    handle = scene.object_fk(np.zeros(1), "handle_frame")
    target = handle @ task.grasp_offset(scene, "insert")
    target[:3, 3] += dz * handle[:3, 2]
    placed = _place_grasp(scene, x, target)
    corners = np.linalg.solve(handle, scene.fk(placed[: scene.nq], "grasp") @ tip.T).T
    return placed, float(corners[:, 2].min())


def test_inserting_ends_only_once_the_hook_tip_is_behind_the_bar(scene):
    """The hook phase slides the finger sideways; its tip (a box on the hook finger) must already be
    behind the bar (a 1 cm box at the handle frame's origin). Checked against the URDF's boxes: at
    every depth the insert test accepts, the tip's nearest corner clears the bar's back face; a
    finger 12 mm short, which the across-the-bar distance alone lets through, has its tip level with
    the bar and keeps inserting."""
    bar_back = 0.005  # half the bar's 1 cm depth (assets/objects/shelf.urdf, collision "bar")
    task = sabre.tasks.OpenObject()

    def at_depth(dz):
        return _at_insert_depth(scene, task, dz)

    for dz in (-0.9 * task.hook.insert_depth_tolerance, 0.0, 0.9 * task.hook.insert_depth_tolerance):
        placed, nearest = at_depth(dz)
        assert task.depth_error(scene, placed, "insert") == pytest.approx(dz, abs=1e-4)
        assert task.next_phase(scene, placed, 0.0, "insert") == "hook"
        assert nearest > bar_back + 0.003
    short, nearest = at_depth(-0.012)
    assert task.pocket_error(scene, short, "insert").across < task.approach.switch_position
    assert nearest < bar_back
    assert task.next_phase(scene, short, 0.0, "insert") == "insert"
    assert (
        sabre.tasks.OpenObject(hook=sabre.tasks.HookConfig(insert_depth_tolerance=None)).next_phase(scene, short, 0.0, "insert")
        == "hook"
    )


def test_only_inserting_and_holding_leave_the_object_cost_out(scene):
    """While inserting, the object cost would reward dragging the closed door by the finger's tip
    beside the bar, and while holding, pulling along the path the object does not follow; every
    other phase carries it (a door resting on the hand is seen to open)."""
    task = sabre.tasks.OpenObject()
    carries = {phase: any(isinstance(t, costs.ObjectState) for t in task.cost(scene, phase).terms) for phase in task.phases}
    assert carries == {"approach": True, "insert": False, "hook": True, "open": True, "release": True, "hold": False}


def test_a_finger_stopped_a_few_millimetres_short_of_the_insert_depth_hooks(scene):
    """A hand held a few millimetres short of the insert target's depth by something in front of it
    (the planner cannot push it further) ends inserting once it has stopped, within
    ``hook.blocked_depth``, where the tip's nearest corner still clears the bar's back face
    (URDF boxes); the same finger still moving toward the target (grasp frame at 2 cm/s, from
    joint rates through a least-squares inverse of the Jacobian) keeps inserting, and one stopped
    12 mm short, tip level with the bar, keeps inserting too."""
    bar_back = 0.005  # half the bar's 1 cm depth (assets/objects/shelf.urdf, collision "bar")
    task = sabre.tasks.OpenObject()
    blocked = task.hook.blocked_depth
    assert blocked > task.hook.insert_depth_tolerance
    handle = scene.object_fk(np.zeros(1), "handle_frame")
    stopped, nearest = _at_insert_depth(scene, task, -0.95 * blocked)
    assert task.depth_error(scene, stopped, "insert") == pytest.approx(-0.95 * blocked, abs=1e-4)
    assert nearest > bar_back
    assert task.next_phase(scene, stopped, 0.0, "insert") == "hook"
    moving = stopped.copy()
    j = scene.jacobian(stopped[: scene.nq], "grasp")[:3, 3 : scene.nq]
    toward = 0.02 * handle[:3, 2]
    moving[scene.nq + 3 : 2 * scene.nq] = j.T @ np.linalg.solve(j @ j.T, toward)
    hand_velocity = scene.jacobian(moving[: scene.nq], "grasp")[:3] @ moving[scene.nq : 2 * scene.nq]
    assert np.linalg.norm(hand_velocity) == pytest.approx(0.02)
    assert task.next_phase(scene, moving, 0.0, "insert") == "insert"
    far, _ = _at_insert_depth(scene, task, -0.012)
    assert task.next_phase(scene, far, 0.0, "insert") == "insert"
    never = sabre.tasks.OpenObject(hook=sabre.tasks.HookConfig(blocked_depth=None))
    assert never.next_phase(scene, stopped, 0.0, "insert") == "insert"


def test_a_finger_that_backs_out_in_front_of_a_held_bar_while_hooking_starts_over(scene):
    """Hooking a door already opened 0.2 rad that does not move, a hand that drifts back until the
    tip's nearest corner no longer clears the bar's back face (checked against the URDF's boxes)
    starts over from the approach; one a few millimetres short, whose tip is still behind the bar,
    keeps hooking, and so does one that drags the handle open, or one at a closed door (where a
    tip's catch is how the drag starts)."""
    tip = _urdf_box_corners(ASSETS / "robots" / "royalpanda.urdf", "hook_finger", "tip", "grasp_joint")
    bar_back = 0.005  # half the bar's 1 cm depth (assets/objects/shelf.urdf, collision "bar")
    task = sabre.tasks.OpenObject()
    nq, no = scene.nq, scene.no

    def backed_out(dz, opening=0.2):
        x = scene.default_state()
        x[0] = 0.939 - 0.75
        x[2 * nq] = opening
        handle = scene.object_fk(np.array([opening]), "handle_frame")
        # Where hooking starts: beside the bar (the insert target), then pulled back by dz.
        shifted = handle @ task.grasp_offset(scene, "insert")
        shifted[:3, 3] += dz * handle[:3, 2]
        placed = _place_grasp(scene, x, shifted)
        corners = np.linalg.solve(handle, scene.fk(placed[:nq], "grasp") @ tip.T).T
        return placed, float(corners[:, 2].min())

    assert task.handle_from_closed(scene, backed_out(0.0)[0]) > task.hook.drag_distance
    for dz in (-0.5 * task.hook.backout, -0.9 * task.hook.backout):
        placed, nearest = backed_out(dz)
        assert task.depth_error(scene, placed, "hook") == pytest.approx(dz, abs=1e-4)
        assert nearest > bar_back - 0.001
        assert task.next_phase(scene, placed, 0.0, "hook") == "hook"
    for dz in (-1.2 * task.hook.backout, -0.03):
        placed, nearest = backed_out(dz)
        assert nearest < bar_back
        assert task.next_phase(scene, placed, 0.0, "hook") == "approach"
        assert sabre.tasks.OpenObject(hook=sabre.tasks.HookConfig(backout=None)).next_phase(scene, placed, 0.0, "hook") == "hook"
        # A tip that catches the bar and drags the handle open keeps hooking: on a free door the bar
        # then slides into the pocket.
        dragging = placed.copy()
        dragging[2 * nq + no] = 2.0 * task.hook.drag_speed / task.handle_travel(scene, 0.2)
        assert task.next_phase(scene, dragging, 0.0, "hook") == "hook"
        dragging[2 * nq + no] *= 0.4
        assert task.next_phase(scene, dragging, 0.0, "hook") == "approach"
        closed, nearest = backed_out(dz, opening=0.0)
        assert nearest < bar_back
        assert task.next_phase(scene, closed, 0.0, "hook") == "hook"


def test_a_finger_that_already_drags_the_handle_open_switches_to_opening(scene):
    """While hooking, the bar may sit in the pocket 1 cm off the hook target (outside
    hook_tolerance) and still be pulled open: that is the open phase, whatever the hook test says.
    Not when the handle stands still or closes, nor when the hand is beyond the slip distance, nor
    before the handle is drag_distance from closed."""
    task = sabre.tasks.OpenObject()
    nq, no = scene.nq, scene.no
    x, handle = _opened(scene, 0.2)
    off_target = _place_grasp(scene, x, handle @ task.grasp_offset(scene, "hook") @ _translation(0.0, 0.0, -0.01))
    across = task.pocket_error(scene, off_target, "hook").across
    assert task.hook.tolerance < across < task.open.slip_distance
    rate = 2.0 * task.hook.drag_speed / task.handle_travel(scene, 0.2)  # handle at twice drag_speed
    moving = off_target.copy()
    moving[2 * nq + no] = rate
    assert task.next_phase(scene, off_target, 0.0, "hook") == "hook"
    assert task.next_phase(scene, moving, 0.0, "hook") == "open"
    assert task.next_phase(scene, moving, 0.0, "insert") == "open"
    closing = off_target.copy()
    closing[2 * nq + no] = -rate
    assert task.next_phase(scene, closing, 0.0, "hook") == "hook"
    slow = off_target.copy()
    slow[2 * nq + no] = 0.5 * task.hook.drag_speed / task.handle_travel(scene, 0.2)
    assert task.next_phase(scene, slow, 0.0, "hook") == "hook"
    far = _place_grasp(scene, x, handle @ task.grasp_offset(scene, "hook") @ _translation(0.0, 0.0, -0.08))
    far[2 * nq + no] = rate
    assert task.next_phase(scene, far, 0.0, "hook") == "hook"
    assert sabre.tasks.OpenObject(hook=sabre.tasks.HookConfig(drag_speed=0.0)).next_phase(scene, moving, 0.0, "hook") == "hook"
    # the same pull 2 cm from closed (shelf handle about 0.27 m from the hinge): not yet
    near = 0.02 / task.handle_travel(scene, 0.0)
    handle = scene.object_fk(np.array([near]), "handle_frame")
    x[2 * nq] = near
    early = _place_grasp(scene, x, handle @ task.grasp_offset(scene, "hook") @ _translation(0.0, 0.0, -0.01))
    early[2 * nq + no] = rate
    assert task.next_phase(scene, early, 0.0, "hook") == "hook"


def test_an_opened_object_that_stops_following_the_pull_is_held_until_it_moves(scene):
    """Opened 0.2 rad with the bar in the pocket and the handle still: hold. The handle faster than
    twice hold_speed either way: open again (between once and twice: each phase stays). The bar out of the
    pocket: start over. Closed, or hold_speed 0: never held. The hold target lies hold_pull out
    from the open target along the handle's normal."""
    task = sabre.tasks.OpenObject()
    nq, no = scene.nq, scene.no
    x, handle = _opened(scene, 0.2)
    hooked = _place_grasp(scene, x, handle @ task.grasp_offset(scene, "open"))
    assert task.next_phase(scene, hooked, 0.0, "open") == "hold"
    assert task.next_phase(scene, hooked, 0.0, "hold") == "hold"
    assert task.noise_scale(scene, hooked, "hold") == task.noise.open
    per_speed = 1.0 / task.handle_travel(scene, 0.2)  # opening rate per m/s at the handle
    for factor, from_open, from_hold in ((3.0, "open", "open"), (1.5, "open", "hold"), (-3.0, "open", "open")):
        moving = hooked.copy()
        moving[2 * nq + no] = factor * task.open.hold_speed * per_speed
        assert task.next_phase(scene, moving, 0.0, "open") == from_open, factor
        assert task.next_phase(scene, moving, 0.0, "hold") == from_hold, factor
    slipped = _place_grasp(scene, x, handle @ task.grasp_offset(scene, "open") @ _translation(0.0, -0.015, 0.0))
    assert task.next_phase(scene, slipped, 0.0, "hold") == "approach"
    never = sabre.tasks.OpenObject(open=sabre.tasks.OpenConfig(hold_speed=0.0))
    assert never.next_phase(scene, hooked, 0.0, "open") == "open"
    x[2 * nq] = 0.0
    closed = _place_grasp(scene, x, scene.object_fk(np.zeros(1), "handle_frame") @ task.grasp_offset(scene, "open"))
    assert task.next_phase(scene, closed, 0.0, "open") == "open"
    pull = np.linalg.solve(task.grasp_offset(scene, "open"), task.grasp_offset(scene, "hold"))
    normal = task.grasp_offset(scene, "open")[:3, :3].T @ np.array([0.0, 0.0, -task.open.hold_pull])
    np.testing.assert_allclose(pull[:3, 3], normal, atol=1e-12)
    np.testing.assert_allclose(pull[:3, :3], np.eye(3), atol=1e-12)


def _opened(scene, opening):
    """The default state with the base in front of the handle and the shelf open `opening` rad,
    and the handle frame's world pose there."""
    x = scene.default_state()
    x[0] = 0.939 - 0.75
    x[2 * scene.nq] = opening
    return x, scene.object_fk(np.array([opening]), "handle_frame")


def _translation(x, y, z):
    t = np.eye(4)
    t[:3, 3] = [x, y, z]
    return t
