"""A MuJoCo scene equivalent to sabre's reduced-order rollout model, built from the same URDF files,
and sabre's states and commands carried into it (`mujoco_state`, `mujoco_controls`, `mujoco_step_through`).

`build_mujoco_model(scene_name)` parses ``assets/robots/royalpanda.urdf`` and
``assets/objects/<scene_name>.urdf`` with ``xml.etree`` (the robot's custom ``<sabre>`` block is
skipped; the rollout contact links, the object placement and the home mass matrix are taken from
``sabre.Scene``), writes MJCF text and compiles it. What is the same as in sabre's RolloutModel:

* Kinematic tree: base slide x, slide y, hinge yaw, the 7 Panda hinges (in this order, so
  ``qpos[:10]`` = sabre's q and ``qpos[10]`` = sabre's o), with URDF joint origins, axes and
  position limits. Links attached by fixed joints become joint-less child bodies that the
  compiler fuses into their parent (``fusestatic``), as MuJoCo's own URDF import does.
* Masses and inertias: the URDF ``<inertial>`` of every link (``fullinertia``, rotated into the
  link frame when the inertial origin has an rpy); the compiler combines fused links.
* Collision geometry: only the links in ``scene.rollout_contact_links`` (panda_link5, panda_link6,
  panda_link7, panda_hand, hook_finger) get collision geoms (URDF box / capsule / cylinder / sphere,
  a cylinder closed by spheres on its caps as one capsule, as sabre reads it;
  URDF cylinders and capsules run along local z as in MuJoCo; URDF capsule ``length`` is the
  cylinder part, i.e. MuJoCo half-length = length / 2). Other robot links have no geoms at all,
  and no visual geoms are generated anywhere.
* The object: its root ``cabinet`` is welded to the world at ``scene.object_pose``; door / drawer and
  handle boxes as in the URDF; the single ``articulation`` joint with the URDF range, ``damping``
  and ``frictionloss`` (= URDF ``<dynamics friction>``); the object feels gravity.
* Contacts: robot geoms have contype=1/conaffinity=2 and object geoms contype=2/conaffinity=1, so
  only robot-vs-object pairs are generated (no robot self-contact, no object-object contact, as in
  sabre's collision groups), condim 3, friction 0.2 (sabre's ``contact_friction``).
* Options: timestep 0.015 s, integrator ``implicitfast``, gravity -9.81 z.
* Robot drive: one ``<velocity>`` actuator per robot joint, kv = 40 * M_ii(q_home) (sabre's servo
  bandwidth 40/s scaled by the diagonal of the joint-space mass matrix at the home configuration),
  ctrlrange = +-dq_limit (sabre also clips the command to the velocity limits) and
  forcerange = +-effort_limit (also the joints' ``actuatorfrcrange``); ``gravcomp="1"`` on every
  robot body (sabre's servo compensates gravity).

Where the two models DIFFER (so the comparison is "same scene, same task", not bit-equivalence):

1. Servo structure. sabre integrates the closed loop q̈ = Λ (u - q̇) + Λ_I ∫(u - q̇) + M(q)⁻¹ τ_ext
   per joint (decoupled, Λ = 40/s exactly at every configuration, Coriolis terms compensated,
   integral action Λ_I = 400/s² with a ±0.1 clamp and anti-windup). MuJoCo's velocity actuator is a
   pure P velocity loop τ = kv (u - q̇) acting on the coupled rigid-body dynamics: the bandwidth is
   only ≈ 40/s (kv uses the diagonal of M at the home configuration, so off-diagonal inertia and
   configuration changes alter it), Coriolis/centrifugal forces act, there is NO integral action,
   and in contact the steady-state pushing force is kv·(velocity error) instead of growing with
   the integrated error. sabre limits each joint's acceleration change to effort / M_ii(home) per
   step; MuJoCo clamps the actuator force to the effort limit.
2. Robot-object contact. In sabre the robot is not a multibody: each contact link is a free "proxy"
   rigid body carrying the robot's smallest effective mass at that link (computed at the
   default configuration), placed at its forward-kinematics pose every step; the contact impulses
   feed back to the joints one step later through τ_ext. In MuJoCo the contact forces act on the
   full articulated robot within the same step.
3. Contact and constraint solvers. sabre uses Rapier (soft constraints at 60 Hz natural frequency,
   damping ratio 1, 2 solver iterations, no contact recycling); MuJoCo uses its own soft-constraint
   model with default solref/solimp (a 0.02 s time constant, which MuJoCo raises to 2·timestep =
   0.03 s at dt = 0.015), the Newton solver and a pyramidal friction cone. The object joint's dry
   friction is a frictionloss constraint in MuJoCo and a Rapier multibody joint friction in sabre;
   joint limits are soft constraints in MuJoCo, whereas sabre clamps robot joint positions.
4. Position limits of the robot joints: sabre clamps q to the URDF limits inside the servo; MuJoCo
   enforces them as (soft) limit constraints.
5. Contact detection: sabre re-places its proxies every step and disables Rapier's contact
   recycling; MuJoCo detects contacts from the positions at the start of each step with zero margin.

Optional integral action (``servo_integral=True``, NOT the default and not what the brief's
benchmark times as "MuJoCo"): adds one ``<intvelocity>`` actuator per robot joint with
kp = Λ_I · M_ii(q_home) (Λ_I = 400/s², sabre's ``servo_integral_gain``), whose activation integrates
the same velocity command, so the joint force becomes kv (u - q̇) + kp (∫u - (q - q0)) - the
structure of sabre's PI servo, but without its ±0.1 clamp on the integrated error and its
anti-windup (the activation is only clamped to the joint range). Each joint's total actuator force
is bounded by its effort limit (``actuatorfrcrange``). The model then has nu = 2·nq controls:
the command must be given twice, ``ctrl = [u, u]``, and ``act`` must be initialised to the joint
positions of the initial state. Without it MuJoCo's P-only servo yields to sustained loads (the
door's friction and damping), the arm drifts from the commanded path and the hook can slip off
the handle during long pulls; with it the scripted pulls of the shelf, microwave and drawer end
within about 0.01 rad / 2 mm of sabre's (the dishwasher, whose door falls open under gravity
once pulled past its balance point, is more sensitive and differs more).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np

import sabre

__all__ = [
    "ASSETS",
    "STATE_SPEC",
    "TIMESTEP",
    "build_mujoco_model",
    "mjcf_text",
    "mujoco_controls",
    "mujoco_state",
    "mujoco_step_through",
    "qpos_slice",
]

ASSETS = Path(__file__).resolve().parents[1] / "assets"

SERVO_BANDWIDTH = 40.0  # 1/s, sabre.RolloutModel default
SERVO_INTEGRAL_GAIN = 400.0  # 1/s^2, sabre.RolloutModel default (only with servo_integral=True)
CONTACT_FRICTION = 0.2  # sabre.RolloutModel default
TIMESTEP = 0.015
STATE_SPEC = mujoco.mjtState.mjSTATE_FULLPHYSICS  # the state vector mujoco.rollout reads and writes

ROBOT_CONTYPE, ROBOT_CONAFFINITY = 1, 2
OBJECT_CONTYPE, OBJECT_CONAFFINITY = 2, 1


# --------------------------------------------------------------------------------------------
# URDF parsing
# --------------------------------------------------------------------------------------------


def _floats(text: str | None, default: tuple[float, ...]) -> np.ndarray:
    if text is None:
        return np.array(default, dtype=float)
    return np.array([float(v) for v in text.split()], dtype=float)


def _origin(elem: ET.Element | None) -> tuple[np.ndarray, np.ndarray]:
    """(xyz, rpy) of an optional <origin> child."""
    o = None if elem is None else elem.find("origin")
    if o is None:
        return np.zeros(3), np.zeros(3)
    return _floats(o.get("xyz"), (0, 0, 0)), _floats(o.get("rpy"), (0, 0, 0))


def _rpy_matrix(rpy: np.ndarray) -> np.ndarray:
    """URDF rpy: fixed-axis roll about x, then pitch about y, then yaw about z (R = Rz Ry Rx)."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def _mat_quat(r: np.ndarray) -> np.ndarray:
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(r, dtype=float).reshape(9))
    return q


def _fmt(v) -> str:
    return " ".join(f"{float(x):.12g}" for x in np.atleast_1d(v))


def _pose_attrs(xyz: np.ndarray, rot: np.ndarray) -> str:
    out = f'pos="{_fmt(xyz)}"'
    if not np.allclose(rot, np.eye(3), atol=1e-15):
        out += f' quat="{_fmt(_mat_quat(rot))}"'
    return out


class _Urdf:
    """Links and joints of a URDF; everything else (materials, the <sabre> block) is ignored."""

    def __init__(self, path: Path) -> None:
        root = ET.parse(path).getroot()
        self.name = root.get("name", path.stem)
        # Only direct <link>/<joint> children of <robot>: this skips the custom <sabre> block.
        self.links = {link.get("name"): link for link in root.findall("link")}
        self.joints = [j for j in root.findall("joint")]
        self.children: dict[str, list[ET.Element]] = {name: [] for name in self.links}
        child_links = set()
        for j in self.joints:
            self.children[j.find("parent").get("link")].append(j)
            child_links.add(j.find("child").get("link"))
        roots = [name for name in self.links if name not in child_links]
        if len(roots) != 1:
            raise ValueError(f"{path}: expected one root link, found {roots}")
        self.root = roots[0]


def _inertial_xml(link: ET.Element, indent: str) -> str:
    inertial = link.find("inertial")
    if inertial is None:
        return ""
    xyz, rpy = _origin(inertial)
    mass = float(inertial.find("mass").get("value"))
    i = inertial.find("inertia")

    def g(k: str) -> float:
        return float(i.get(k, "0"))

    full = np.array([[g("ixx"), g("ixy"), g("ixz")], [g("ixy"), g("iyy"), g("iyz")], [g("ixz"), g("iyz"), g("izz")]])
    rot = _rpy_matrix(rpy)
    full = rot @ full @ rot.T  # tensor expressed in the link frame
    six = [full[0, 0], full[1, 1], full[2, 2], full[0, 1], full[0, 2], full[1, 2]]
    return f'{indent}<inertial pos="{_fmt(xyz)}" mass="{mass:.12g}" fullinertia="{_fmt(six)}"/>\n'


def _capsule_caps(collisions: list[ET.Element]) -> dict[int, set[int]]:
    """For each cylinder closed by two spheres of its radius on its end caps (standard URDF's way of
    writing a capsule, read back as one capsule by sabre too), the indices of those spheres."""
    fused: dict[int, set[int]] = {}
    for i, col in enumerate(collisions):
        shape = col.find("geometry")[0]
        if shape.tag != "cylinder":
            continue
        xyz, rpy = _origin(col)
        radius, half = float(shape.get("radius")), float(shape.get("length")) / 2.0
        axis = _rpy_matrix(rpy)[:, 2]
        caps = set()
        for cap in (np.asarray(xyz) + half * axis, np.asarray(xyz) - half * axis):
            for k, other in enumerate(collisions):
                s = other.find("geometry")[0]
                if (
                    s.tag == "sphere"
                    and abs(float(s.get("radius")) - radius) <= 1e-9
                    and np.linalg.norm(np.asarray(_origin(other)[0]) - cap) <= 1e-6
                ):
                    caps.add(k)
                    break
        if len(caps) == 2:
            fused[i] = caps
    return fused


def _collision_geoms_xml(link: ET.Element, indent: str, contype: int, conaffinity: int) -> str:
    out = []
    collisions = link.findall("collision")
    capsules = _capsule_caps(collisions)
    caps = set().union(*capsules.values())
    for k, col in enumerate(collisions):
        if k in caps:
            continue
        xyz, rpy = _origin(col)
        geom = col.find("geometry")
        shape = geom[0]
        if k in capsules:
            gtype, size = "capsule", [float(shape.get("radius")), float(shape.get("length")) / 2.0]
        elif shape.tag == "box":
            gtype, size = "box", _floats(shape.get("size"), ()) / 2.0
        elif shape.tag == "sphere":
            gtype, size = "sphere", [float(shape.get("radius"))]
        elif shape.tag == "cylinder":
            gtype, size = "cylinder", [float(shape.get("radius")), float(shape.get("length")) / 2.0]
        elif shape.tag == "capsule":
            # URDF capsule length = cylinder part; MuJoCo size = (radius, half-length of that part).
            gtype, size = "capsule", [float(shape.get("radius")), float(shape.get("length")) / 2.0]
        else:
            raise ValueError(f"link {link.get('name')}: unsupported collision shape <{shape.tag}>")
        name = f"{link.get('name')}/{col.get('name') or k}"
        out.append(
            f'{indent}<geom name="{name}" type="{gtype}" size="{_fmt(size)}" {_pose_attrs(xyz, _rpy_matrix(rpy))} '
            f'contype="{contype}" conaffinity="{conaffinity}" condim="3" '
            f'friction="{CONTACT_FRICTION} 0.005 0.0001"/>\n'
        )
    return "".join(out)


def _joint_xml(joint: ET.Element, indent: str, robot: bool) -> str:
    """A URDF joint as an MJCF joint; robot joints bound their total actuator force by the effort limit."""
    kind = joint.get("type")
    if kind == "fixed":
        return ""
    if kind not in ("revolute", "prismatic", "continuous"):
        raise ValueError(f"joint {joint.get('name')}: unsupported type {kind}")
    axis = _floats(joint.find("axis").get("xyz") if joint.find("axis") is not None else None, (1, 0, 0))
    mj_type = "slide" if kind == "prismatic" else "hinge"
    attrs = [f'name="{joint.get("name")}"', f'type="{mj_type}"', f'axis="{_fmt(axis)}"']
    limit = joint.find("limit")
    if kind != "continuous" and limit is not None and limit.get("lower") is not None:
        attrs.append(f'range="{float(limit.get("lower")):.12g} {float(limit.get("upper")):.12g}"')
    dyn = joint.find("dynamics")
    damping = float(dyn.get("damping", "0")) if dyn is not None else 0.0
    friction = float(dyn.get("friction", "0")) if dyn is not None else 0.0
    if damping:
        attrs.append(f'damping="{damping:.12g}"')
    if friction:
        attrs.append(f'frictionloss="{friction:.12g}"')
    if robot and limit is not None and limit.get("effort") is not None:
        effort = float(limit.get("effort"))
        attrs.append(f'actuatorfrcrange="{-effort:.12g} {effort:.12g}"')
    return f"{indent}<joint {' '.join(attrs)}/>\n"


def _body_tree_xml(
    urdf: _Urdf,
    link_name: str,
    depth: int,
    *,
    collision_links: set[str] | None,
    contype: int,
    conaffinity: int,
    robot: bool,
) -> str:
    """Children of `link_name` as nested MJCF bodies (the link itself is emitted by the caller).

    Robot bodies get gravity compensation and their joints an actuator force range."""
    out = []
    for joint in urdf.children[link_name]:
        child = joint.find("child").get("link")
        xyz, rpy = _origin(joint)
        ind = "  " * depth
        gc = ' gravcomp="1"' if robot else ""
        out.append(f'{ind}<body name="{child}" {_pose_attrs(xyz, _rpy_matrix(rpy))}{gc}>\n')
        out.append(_joint_xml(joint, ind + "  ", robot=robot))
        out.append(_inertial_xml(urdf.links[child], ind + "  "))
        if collision_links is None or child in collision_links:
            out.append(_collision_geoms_xml(urdf.links[child], ind + "  ", contype, conaffinity))
        out.append(
            _body_tree_xml(
                urdf,
                child,
                depth + 1,
                collision_links=collision_links,
                contype=contype,
                conaffinity=conaffinity,
                robot=robot,
            )
        )
        out.append(f"{ind}</body>\n")
    return "".join(out)


# --------------------------------------------------------------------------------------------
# Scene
# --------------------------------------------------------------------------------------------


def mjcf_text(
    scene_name: str, scene: sabre.Scene | None = None, robot: str = "royalpanda", *, servo_integral: bool = False
) -> str:
    """MJCF of the robot + object scene `scene_name` (see the module docstring)."""
    if scene is None:
        scene = sabre.Scene.load(robot=robot, obj=scene_name)
    robot_urdf = _Urdf(ASSETS / "robots" / f"{robot}.urdf")
    obj_urdf = _Urdf(ASSETS / "objects" / f"{scene_name}.urdf")

    contact_links = set(scene.rollout_contact_links)
    # The robot URDF's root is the world link: its children hang directly from <worldbody>.
    world_link = robot_urdf.links[robot_urdf.root]
    if world_link.find("collision") is not None or world_link.find("inertial") is not None:
        raise ValueError("robot root link must be an empty 'world' link")
    robot_xml = _body_tree_xml(
        robot_urdf,
        robot_urdf.root,
        2,
        collision_links=contact_links,
        contype=ROBOT_CONTYPE,
        conaffinity=ROBOT_CONAFFINITY,
        robot=True,
    )

    pose = np.asarray(scene.object_pose, dtype=float)
    root = obj_urdf.root
    obj_xml = (
        f'    <body name="{root}" {_pose_attrs(pose[:3, 3], pose[:3, :3])}>\n'
        + _inertial_xml(obj_urdf.links[root], "      ")
        + _collision_geoms_xml(obj_urdf.links[root], "      ", OBJECT_CONTYPE, OBJECT_CONAFFINITY)
        + _body_tree_xml(
            obj_urdf, root, 3, collision_links=None, contype=OBJECT_CONTYPE, conaffinity=OBJECT_CONAFFINITY, robot=False
        )
        + "    </body>\n"
    )

    # Velocity servos: kv = bandwidth * M_ii(q_home), limits from the scene.
    mass_diag = np.diag(np.asarray(scene.mass_matrix(scene.home_configuration())[0]))
    acts = []
    for i, name in enumerate(scene.joint_names):
        kv = SERVO_BANDWIDTH * mass_diag[i]
        v, f = float(scene.dq_limit[i]), float(scene.effort_limit[i])
        acts.append(
            f'    <velocity name="{name}_servo" joint="{name}" kv="{kv:.12g}" '
            f'ctrlrange="{-v:.12g} {v:.12g}" forcerange="{-f:.12g} {f:.12g}"/>\n'
        )
    if servo_integral:
        for i, name in enumerate(scene.joint_names):
            kp = SERVO_INTEGRAL_GAIN * mass_diag[i]
            v, f = float(scene.dq_limit[i]), float(scene.effort_limit[i])
            lo, hi = float(scene.q_lower[i]), float(scene.q_upper[i])
            acts.append(
                f'    <intvelocity name="{name}_integral" joint="{name}" kp="{kp:.12g}" '
                f'ctrlrange="{-v:.12g} {v:.12g}" actrange="{lo:.12g} {hi:.12g}" forcerange="{-f:.12g} {f:.12g}"/>\n'
            )

    return (
        f'<mujoco model="sabre_{robot}_{scene_name}">\n'
        '  <compiler angle="radian" autolimits="true" fusestatic="true" inertiafromgeom="false"/>\n'
        f'  <option timestep="{TIMESTEP}" integrator="implicitfast" gravity="0 0 -9.81"/>\n'
        "  <worldbody>\n"
        f"{robot_xml}"
        f"{obj_xml}"
        "  </worldbody>\n"
        "  <actuator>\n"
        f"{''.join(acts)}"
        "  </actuator>\n"
        "</mujoco>\n"
    )


def build_mujoco_model(scene_name: str, scene: sabre.Scene | None = None, *, servo_integral: bool = False) -> mujoco.MjModel:
    """Compiles the MuJoCo equivalent of ``sabre.Scene.load("royalpanda", scene_name)`` with the
    rollout model's physics (see the module docstring for what is equal and what differs).

    Joint order: qpos[:scene.nq] are the robot joints in ``scene.joint_names`` order and
    qpos[scene.nq:] the object joint(s), so sabre's x = [q, q̇, o, ȯ] maps to
    qpos = [q, o], qvel = [q̇, ȯ]. ``servo_integral=True`` adds the optional integral actuators
    (module docstring): nu doubles and ``act`` holds the integrated commands.
    """
    if scene is None:
        scene = sabre.Scene.load(robot="royalpanda", obj=scene_name)
    model = mujoco.MjModel.from_xml_string(mjcf_text(scene_name, scene, servo_integral=servo_integral))
    names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) for j in range(model.njnt)]
    expected = list(scene.joint_names) + list(scene.object_joint_names)
    if names != expected or model.nq != scene.nq + scene.no or model.nv != scene.nq + scene.no:
        raise RuntimeError(f"MuJoCo joint order {names} does not match sabre's {expected}")
    return model


# --------------------------------------------------------------------------------------------
# sabre's states and commands in the MuJoCo model
# --------------------------------------------------------------------------------------------


def mujoco_state(model: mujoco.MjModel, data: mujoco.MjData, scene: sabre.Scene, x: np.ndarray) -> np.ndarray:
    """MuJoCo's full physics state for sabre's x = [q, q̇, o, ȯ]: qpos = [q, o], qvel = [q̇, ȯ], and
    (integral servo variant only) each integrator actuator's activation = its joint's position."""
    nq, no = scene.nq, scene.no
    mujoco.mj_resetData(model, data)
    data.qpos[:nq] = x[:nq]
    data.qpos[nq:] = x[2 * nq : 2 * nq + no]
    data.qvel[:nq] = x[nq : 2 * nq]
    data.qvel[nq:] = x[2 * nq + no :]
    for a in range(model.nu):
        if model.actuator_actadr[a] >= 0:
            data.act[model.actuator_actadr[a]] = data.qpos[model.jnt_qposadr[model.actuator_trnid[a, 0]]]
    mujoco.mj_forward(model, data)
    state = np.empty(mujoco.mj_stateSize(model, STATE_SPEC))
    mujoco.mj_getState(model, data, state, STATE_SPEC)
    return state


def mujoco_controls(model: mujoco.MjModel, U: np.ndarray) -> np.ndarray:
    """Joint velocity commands as MuJoCo controls: the variant with integral actuators takes u twice."""
    reps = model.nu // U.shape[-1]
    return np.ascontiguousarray(np.concatenate([U] * reps, axis=-1))


def qpos_slice(model: mujoco.MjModel) -> slice:
    """Where qpos sits in a full-physics state vector (right after the time)."""
    start = mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_TIME)
    return slice(start, start + model.nq)


def mujoco_step_through(
    model: mujoco.MjModel, data: mujoco.MjData, state0: np.ndarray, U: np.ndarray, object_qpos: int
) -> tuple[np.ndarray, np.ndarray]:
    """Steps U (K, nq) with mj_step; returns (object opening after each step, contact flag per step).

    A step counts as "in contact" when a contact carries a positive normal force; every contact
    pair of the model is robot-object by construction (contype/conaffinity).
    """
    mujoco.mj_resetData(model, data)  # no warm start left over from earlier runs, as in rollout
    mujoco.mj_setState(model, data, state0, STATE_SPEC)
    ctrl = mujoco_controls(model, U)
    opening = np.empty(len(U))
    contact = np.zeros(len(U), dtype=bool)
    force = np.zeros(6)
    for k in range(len(U)):
        data.ctrl[:] = ctrl[k]
        mujoco.mj_step(model, data)
        for c in range(data.ncon):
            mujoco.mj_contactForce(model, data, c, force)
            if force[0] > 1e-9:
                contact[k] = True
                break
        opening[k] = data.qpos[object_qpos]
    return opening, contact


if __name__ == "__main__":  # print the MJCF for inspection
    import sys

    print(mjcf_text(sys.argv[1] if len(sys.argv) > 1 else "shelf"))
