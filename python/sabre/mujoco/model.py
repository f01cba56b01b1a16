"""The MuJoCo model of a scene, imported by MuJoCo's own URDF importer: meshes resolved as sabre resolves
them, the object attached at the scene's pose, where sabre's quantities sit in it (:class:`Layout`), and the
check that it is the scene's."""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InvalidValueError, UrdfError
from ..scene import Scene

__all__ = ["OBJECT_PREFIX", "Layout", "compile_model", "layout", "check_against_scene", "builtin_path"]

#: Prefix of the object's bodies and joints in the MuJoCo model (the robot's keep their URDF names).
OBJECT_PREFIX = "object/"

# Geom collision bits: robot geoms touch object geoms only, as in sabre's plant (no robot self-contact,
# no contact between the object's own parts).
_ROBOT_CONTYPE, _ROBOT_CONAFFINITY = 1, 2
_OBJECT_CONTYPE, _OBJECT_CONAFFINITY = 2, 1


# -- importing the URDFs ---------------------------------------------------------------------------
def _search_dirs(variable: str) -> list[Path]:
    return [Path(p) for p in os.environ.get(variable, "").split(os.pathsep) if p]


def _resolve_mesh(filename: str, urdf_dir: Path) -> Path:
    """A URDF mesh filename as a file, found as sabre finds it (docs/objects.md): an absolute path;
    ``package://pkg/rest`` under ``SABRE_PACKAGE_PATH``, ``ROS_PACKAGE_PATH`` and ``AMENT_PREFIX_PATH``/share;
    a relative path next to the URDF, on ``SABRE_MESH_PATH``, then in the working directory."""
    name = filename.removeprefix("file://")
    if name.startswith("package://"):
        package, _, rest = name.removeprefix("package://").partition("/")
        roots = _search_dirs("SABRE_PACKAGE_PATH") + _search_dirs("ROS_PACKAGE_PATH")
        candidates = [r / package / rest for r in roots]
        candidates += [p / "share" / package / rest for p in _search_dirs("AMENT_PREFIX_PATH")]
    elif Path(name).is_absolute():
        candidates = [Path(name)]
    else:
        candidates = [urdf_dir / name] + [d / name for d in _search_dirs("SABRE_MESH_PATH")] + [Path.cwd() / name]
    for candidate in candidates:
        if candidate.is_file():
            return candidate.resolve()
    raise UrdfError(f"mesh {filename!r} not found (looked in {', '.join(str(c) for c in candidates) or 'no directory'})")


def _prepared_urdf(path: Path) -> str:
    """The URDF at ``path`` as MuJoCo's importer is given it: visual elements dropped (MuJoCo discards them
    anyway, and their meshes need not exist), collision names dropped and every mesh's filename made absolute."""
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as exc:
        raise UrdfError(f"URDF {path}: {exc}") from exc
    for link in root.iter("link"):
        for visual in link.findall("visual"):
            link.remove(visual)
        for collision in link.findall("collision"):
            collision.attrib.pop("name", None)  # names repeat across links, which MuJoCo warns about
    for mesh in root.iter("mesh"):
        mesh.set("filename", str(_resolve_mesh(mesh.get("filename", ""), path.parent)))
    return ET.tostring(root, encoding="unicode")


def builtin_path(name: str, table: tuple[str, ...], kind: str) -> Path:
    """The file of the built-in ``kind`` ("robot" or "object") ``name`` (:func:`sabre.assets.urdf_path`);
    a name not in ``table`` raises :class:`InvalidValueError` asking for the file."""
    if name not in table:
        raise InvalidValueError(
            f"the scene's {kind} {name!r} is not built in; pass its URDF file as MujocoPlant(..., {kind}_urdf=path)"
        )
    from .. import assets

    return assets.urdf_path(name)


def _quaternion(mujoco: Any, rotation: np.ndarray) -> np.ndarray:
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(rotation, dtype=np.float64).reshape(9))
    return quat


def compile_model(mujoco: Any, robot_path: Path, object_path: Path, object_pose: np.ndarray, dt: float, friction: float) -> Any:
    """Robot and object imported from their URDFs by MuJoCo, the object's root bodies attached to the robot's
    world at ``object_pose``; links joined by fixed joints stay bodies of their own (``fusestatic`` off) so that
    every URDF frame is a MuJoCo body."""
    robot = mujoco.MjSpec.from_string(_prepared_urdf(robot_path))
    obj = mujoco.MjSpec.from_string(_prepared_urdf(object_path))
    for spec in (robot, obj):
        spec.compiler.fusestatic = False
    for geom in robot.geoms:
        geom.contype, geom.conaffinity = _ROBOT_CONTYPE, _ROBOT_CONAFFINITY
    for geom in obj.geoms:
        geom.contype, geom.conaffinity = _OBJECT_CONTYPE, _OBJECT_CONAFFINITY
    for geom in list(robot.geoms) + list(obj.geoms):
        geom.friction = [friction, geom.friction[1], geom.friction[2]]
    frame = robot.worldbody.add_frame(pos=object_pose[:3, 3], quat=_quaternion(mujoco, object_pose[:3, :3]))
    for body in list(obj.worldbody.bodies):
        frame.attach_body(body, OBJECT_PREFIX, "")
    robot.option.timestep = dt
    robot.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    robot.option.gravity = [0.0, 0.0, -9.81]
    try:
        return robot.compile()
    except ValueError as exc:
        raise UrdfError(f"MuJoCo could not compile {robot_path.name} with {object_path.name}: {exc}") from exc


@dataclass(frozen=True)
class Layout:
    """Where sabre's quantities sit in the MuJoCo model."""

    robot_qpos: np.ndarray
    robot_dofs: np.ndarray
    object_qpos: np.ndarray
    object_dofs: np.ndarray
    object_joints: np.ndarray
    is_robot_body: np.ndarray
    """(nbody,) bool: the body belongs to the robot."""
    is_sensor_body: np.ndarray
    """(nbody,) bool: the wrist sensor measures the forces on this body (at or beyond it)."""
    sensor_body: int
    link_names: tuple[str, ...]
    """The URDF link of every body ("world" for the world body)."""


def _joint_ids(mujoco: Any, model: Any, names: Sequence[str], prefix: str) -> np.ndarray:
    ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, prefix + n) for n in names]
    missing = [n for n, i in zip(names, ids) if i < 0]
    if missing:
        raise InvalidValueError(f"MuJoCo's model lacks the scene's joints {missing}")
    return np.asarray(ids, dtype=int)


def layout(mujoco: Any, model: Any, scene: Scene) -> Layout:
    robot_joints = _joint_ids(mujoco, model, scene.joint_names, "")
    object_joints = _joint_ids(mujoco, model, scene.object_joint_names, OBJECT_PREFIX)
    if model.njnt != scene.nq + scene.no or model.nv != scene.nq + scene.no:
        found = [model.joint(j).name for j in range(model.njnt)]
        raise InvalidValueError(
            f"MuJoCo's model has the joints {found}, the scene only {list(scene.joint_names) + list(scene.object_joint_names)}: "
            "MujocoPlant takes objects whose every movable joint is the scene's"
        )
    names = tuple(model.body(b).name.removeprefix(OBJECT_PREFIX) for b in range(model.nbody))
    is_object = np.array([model.body(b).name.startswith(OBJECT_PREFIX) for b in range(model.nbody)])
    is_robot = ~is_object
    is_robot[0] = False
    # the scene's wrist-sensor link, or the body MuJoCo's importer merged it into (that of the last joint)
    wrist = scene.wrist_sensor_link
    sensor = names.index(wrist) if wrist in names else int(model.jnt_bodyid[robot_joints[-1]])
    beyond = np.zeros(model.nbody, dtype=bool)
    for b in range(model.nbody):
        walk = b
        while walk > 0 and walk != sensor:
            walk = int(model.body_parentid[walk])
        beyond[b] = walk == sensor
    return Layout(
        robot_qpos=model.jnt_qposadr[robot_joints].copy(),
        robot_dofs=model.jnt_dofadr[robot_joints].copy(),
        object_qpos=model.jnt_qposadr[object_joints].copy(),
        object_dofs=model.jnt_dofadr[object_joints].copy(),
        object_joints=object_joints,
        is_robot_body=is_robot,
        is_sensor_body=beyond,
        sensor_body=sensor,
        link_names=("world",) + names[1:],
    )


def check_against_scene(mujoco: Any, model: Any, where: Layout, scene: Scene) -> None:
    """Refuses a MuJoCo model that is not the scene's: other joint limits, object damping or friction, or
    frames elsewhere at the scene's default state (a scene of the built-in names from other files)."""
    checks = {
        "robot lower limits": (model.jnt_range[_joint_ids(mujoco, model, scene.joint_names, ""), 0], scene.q_lower),
        "robot upper limits": (model.jnt_range[_joint_ids(mujoco, model, scene.joint_names, ""), 1], scene.q_upper),
        "object limits": (
            model.jnt_range[where.object_joints].ravel(),
            np.ravel(np.column_stack([scene.o_lower, scene.o_upper])),
        ),
        "object damping": (model.dof_damping[where.object_dofs], scene.object_damping),
        "object friction": (model.dof_frictionloss[where.object_dofs], scene.object_friction),
    }
    data = mujoco.MjData(model)
    q, _, o, _ = scene.split_state(scene.default_state())
    data.qpos[where.robot_qpos], data.qpos[where.object_qpos] = q, o
    mujoco.mj_kinematics(model, data)
    frames = [(f, f, True) for f in scene.frame_names] + [(f, OBJECT_PREFIX + f, False) for f in scene.object_frame_names]
    for frame, body_name, on_robot in frames:
        body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, body_name)
        if body > 0:
            pose = scene.fk(q, frame) if on_robot else scene.object_fk(o, frame)
            checks[f"frame {frame}"] = (
                np.concatenate([data.xpos[body], data.xmat[body]]),
                np.concatenate([pose[:3, 3], pose[:3, :3].ravel()]),
            )
    wrong = [name for name, (mine, theirs) in checks.items() if not np.allclose(mine, theirs, rtol=0.0, atol=1e-9)]
    if wrong:
        raise InvalidValueError(
            f"the URDF files MuJoCo read differ from the scene's ({', '.join(wrong)}); "
            "pass the files the scene was built from as robot_urdf= and object_urdf="
        )
