"""The robots built from example-robot-data against Pinocchio, a second rigid-body engine: the wrapped robots'
kinematics (poses and Jacobians of their frames, held joints at their values), and the bare Panda's dynamics."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import sabre
from sabre.robot_examples import example_robot_data, example_robot_urdf, example_scene

# Pinocchio runs in a child interpreter, as in tests/model/test_other_tools.py: its shared libraries never
# meet the ones other tests load.
PINOCCHIO = r"""
import json, sys
import numpy as np
import pinocchio as pin

request = json.load(sys.stdin)
model = pin.buildModelFromUrdf(request["path"])
data = model.createData()
names = [model.names[i] for i in range(1, model.njoints)]
out = {"joints": names, "nq": model.nq, "cases": []}
for values in request["q"]:
    q = pin.neutral(model)
    for name, value in values.items():
        q[model.joints[model.getJointId(name)].idx_q] = value
    pin.forwardKinematics(model, data, q)
    pin.updateFramePlacements(model, data)
    case = {"poses": {}, "jacobians": {}, "columns": {}}
    for frame in request["frames"]:
        fid = model.getFrameId(frame)
        case["poses"][frame] = data.oMf[fid].homogeneous.tolist()
        case["jacobians"][frame] = pin.computeFrameJacobian(model, data, q, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED).tolist()
    case["columns"] = {name: model.joints[model.getJointId(name)].idx_v for name in names}
    mass = pin.crba(model, data, q)
    case["mass"] = (np.triu(mass) + np.triu(mass, 1).T).tolist()
    case["gravity"] = pin.computeGeneralizedGravity(model, data, q).tolist()
    out["cases"].append(case)
json.dump(out, sys.stdout)
"""


def pinocchio(path: Path, frames: list[str], configurations: list[dict[str, float]]) -> dict:
    if importlib.util.find_spec("pinocchio") is None:
        pytest.fail("Pinocchio (pip: pin) is a test dependency: make test installs it")
    run = subprocess.run(
        [sys.executable, "-c", PINOCCHIO],
        input=json.dumps({"path": str(path), "frames": frames, "q": configurations}),
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert run.returncode == 0, run.stderr
    return json.loads(run.stdout)


def configurations(scene: sabre.Scene, count: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(np.maximum(scene.q_lower, -3.0), np.minimum(scene.q_upper, 3.0), size=(count, scene.nq))


@pytest.mark.parametrize(
    ("name", "frames"),
    [
        ("panda_pedestal", ["panda_link3", "panda_hand", "panda_leftfinger", "panda_hand_tcp"]),
        ("ur5_mobile", ["mobile_base", "forearm_link", "tool0", "ee_link"]),
    ],
)
def test_wrapped_robots_place_their_frames_where_pinocchio_does(tmp_path, name, frames):
    scene = example_scene(name, "shelf")
    path = example_robot_urdf(name, tmp_path)
    qs = configurations(scene, 6, seed=5)
    values = [{**dict(zip(scene.joint_names, q.tolist())), **scene.held_joints} for q in qs]
    out = pinocchio(path, frames, values)
    for q, case in zip(qs, out["cases"]):
        columns = [case["columns"][joint] for joint in scene.joint_names]
        for frame in frames:
            np.testing.assert_allclose(scene.fk(q, frame), case["poses"][frame], atol=1e-12)
            np.testing.assert_allclose(scene.jacobian(q, frame), np.asarray(case["jacobians"][frame])[:, columns], atol=1e-12)


def test_the_bare_panda_dynamics_agree_with_pinocchio_with_the_fingers_held(tmp_path):
    share = example_robot_data()
    text = (share / "robots/panda_description/urdf/panda.urdf").read_text()
    path = tmp_path / "panda.urdf"
    path.write_text(text.replace("package://example-robot-data/", f"{share}/"))
    fingers = {"panda_finger_joint1": 0.04, "panda_finger_joint2": 0.04}
    scene = sabre.Scene.from_urdf(path, "shelf", robot_hold=fingers)
    assert scene.nq == 7
    qs = configurations(scene, 6, seed=7)
    out = pinocchio(path, ["panda_hand_tcp"], [{**dict(zip(scene.joint_names, q.tolist())), **fingers} for q in qs])
    for q, case in zip(qs, out["cases"]):
        arm = [case["columns"][joint] for joint in scene.joint_names]
        mass, gravity = scene.mass_matrix(q)
        # a held finger rides on the hand as a fixed body would: the arm's block is the same
        np.testing.assert_allclose(mass, np.asarray(case["mass"])[np.ix_(arm, arm)], rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(gravity, np.asarray(case["gravity"])[arm], rtol=1e-10, atol=1e-9)
        np.testing.assert_allclose(scene.fk(q, "panda_hand_tcp"), case["poses"]["panda_hand_tcp"], atol=1e-12)
