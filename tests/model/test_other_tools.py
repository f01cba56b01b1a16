"""The shipped URDFs in other tools: urdfdom's check_urdf and Pinocchio load them without an error, and
Pinocchio, a second rigid-body engine, agrees with sabre's kinematics and dynamics on them."""

from __future__ import annotations

import importlib.util
import json
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

import sabre

ASSETS = Path(__file__).resolve().parents[2] / "assets"
SHIPPED = sorted([*ASSETS.glob("robots/*.urdf"), *ASSETS.glob("objects/*.urdf"), *ASSETS.glob("objects/examples/*.urdf")])

# Pinocchio runs in a child interpreter: its urdfdom reports problems on stderr, which the tests read, and
# its shared libraries never meet the ones the ROS 2 wheels load into the test process.
PINOCCHIO = r"""
import json, sys
import numpy as np
import pinocchio as pin

request = json.load(sys.stdin)
model = pin.buildModelFromUrdf(request["path"])
geometry = pin.buildGeomFromUrdf(model, request["path"], pin.GeometryType.COLLISION)
data = model.createData()
out = {"joints": [model.names[i] for i in range(1, model.njoints)], "geometries": geometry.ngeoms, "cases": []}
frame = model.getFrameId(request["frame"])
for q in request["q"]:
    q = np.array(q)
    pin.forwardKinematics(model, data, q)
    pin.updateFramePlacements(model, data)
    jacobian = pin.computeFrameJacobian(model, data, q, frame, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
    mass = pin.crba(model, data, q)
    mass = np.triu(mass) + np.triu(mass, 1).T
    out["cases"].append({
        "pose": data.oMf[frame].homogeneous.tolist(),
        "jacobian": jacobian.tolist(),
        "mass": mass.tolist(),
        "gravity": pin.computeGeneralizedGravity(model, data, q).tolist(),
    })
json.dump(out, sys.stdout)
"""


def pinocchio(path: Path, frame: str, q: np.ndarray) -> tuple[dict, str]:
    if importlib.util.find_spec("pinocchio") is None:
        pytest.fail("Pinocchio (pip: pin) is a test dependency: make test installs it")
    run = subprocess.run(
        [sys.executable, "-c", PINOCCHIO],
        input=json.dumps({"path": str(path), "frame": frame, "q": q.tolist()}),
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert run.returncode == 0, run.stderr
    return json.loads(run.stdout), run.stderr


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.name)
def test_urdfdom_check_urdf_reports_no_error(path: Path) -> None:
    check_urdf = shutil.which("check_urdf")
    if check_urdf is None:
        pytest.fail("urdfdom's check_urdf is not installed: make test-setup installs liburdfdom-tools")
    run = subprocess.run([check_urdf, str(path)], capture_output=True, text=True, timeout=60, check=False)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "error" not in (run.stdout + run.stderr).lower(), run.stdout + run.stderr
    assert "Successfully Parsed XML" in run.stdout


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.name)
def test_pinocchio_loads_every_shipped_urdf_with_its_collision_geometry(path: Path) -> None:
    robot = path.parent.name == "robots"
    scene = (
        sabre.Scene.from_urdf(path, ASSETS / "objects" / "shelf.urdf")
        if robot
        else sabre.Scene.from_urdf(ASSETS / "robots" / "royalpanda.urdf", path)
    )
    names = scene.joint_names if robot else scene.object_joint_names
    root = root_link(path)
    out, stderr = pinocchio(path, root, np.zeros((1, len(names))))
    assert "error" not in stderr.lower(), stderr
    assert tuple(out["joints"]) == names
    assert out["geometries"] > 0


def root_link(path: Path) -> str:
    root = ET.parse(path).getroot()
    children = {j.find("child").get("link") for j in root.findall("joint")}
    return next(link.get("name") for link in root.findall("link") if link.get("name") not in children)


def random_configurations(scene: sabre.Scene, count: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    lower = np.maximum(scene.q_lower, -3.0)
    upper = np.minimum(scene.q_upper, 3.0)
    return rng.uniform(lower, upper, size=(count, scene.nq))


def test_pinocchio_agrees_with_sabre_on_the_robot_kinematics_and_dynamics() -> None:
    scene = sabre.Scene.load()
    qs = random_configurations(scene, 12, seed=3)
    out, _ = pinocchio(ASSETS / "robots" / "royalpanda.urdf", "grasp", qs)
    for q, case in zip(qs, out["cases"]):
        np.testing.assert_allclose(scene.fk(q, "grasp"), case["pose"], atol=1e-12)
        np.testing.assert_allclose(scene.jacobian(q, "grasp"), case["jacobian"], atol=1e-12)
        mass, gravity = scene.mass_matrix(q)
        np.testing.assert_allclose(mass, case["mass"], rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(gravity, case["gravity"], rtol=1e-10, atol=1e-9)


@pytest.mark.parametrize("name", sabre.OBJECTS)
def test_pinocchio_places_the_handle_where_sabre_does(name: str) -> None:
    scene = sabre.Scene.load(obj=name)
    os_ = np.linspace(scene.o_lower, scene.o_upper, 5)
    out, _ = pinocchio(ASSETS / "objects" / f"{name}.urdf", "handle_frame", os_)
    for o, case in zip(os_, out["cases"]):
        np.testing.assert_allclose(scene.object_fk(o, "handle_frame"), scene.object_pose @ np.array(case["pose"]), atol=1e-12)
