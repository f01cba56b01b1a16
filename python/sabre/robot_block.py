"""What sabre makes of a robot, for people: a report of its roles and safety geometry, and the same written
as a ``<sabre>`` block that, put in the robot's URDF, reloads to the same scene (``python -m sabre robot-check``).
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from collections.abc import Iterable

import numpy as np

from .scene import Scene

__all__ = ["sabre_block", "with_sabre_block", "describe"]


def _number(value: float) -> str:
    """The shortest text that reads back as the same float."""
    return repr(float(value))


def _values(values: Iterable[float]) -> str:
    return " ".join(_number(v) for v in values)


def _role_elements(scene: Scene) -> list[ET.Element]:
    """<tool>, <tool_frame>, <hold>, <base>, <home>, <start>, <work>, <wrist_sensor> of the scene."""
    out = []
    tool = scene.tool
    if tool is not None:
        kind, value = tool.source()
        attributes = {"parent": tool.parent, ("builtin" if kind == "builtin" else "file"): value}
        if kind == "text":
            raise ValueError("a tool given as URDF text cannot be written into a <sabre> block; give it as a file")
        attributes |= {"xyz": _values(tool.xyz), "rpy": _values(tool.rpy)}
        if tool.frame is not None:
            attributes["frame"] = tool.frame
        out.append(ET.Element("tool", attributes))
    if scene.tool_frame is not None:
        out.append(ET.Element("tool_frame", {"link": scene.tool_frame}))
    for joint, held in scene.held_joints.items():
        out.append(ET.Element("hold", {"joint": joint, "value": _number(held)}))
    if scene.base_joints is None:
        out.append(ET.Element("base", {"type": "fixed", "link": scene.base_link}))
    else:
        out.append(ET.Element("base", {"type": "planar", "joints": " ".join(scene.base_joints), "link": scene.base_link}))
    for tag, posture in (("home", scene.home_configuration()), ("start", scene.start_configuration())):
        out += [ET.Element(tag, {"joint": j, "value": _number(v)}) for j, v in zip(scene.joint_names, posture)]
    work = scene.work_configuration()
    out += [
        ET.Element("work", {"joint": j, "value": _number(v)})
        for j, v, h in zip(scene.joint_names, work, scene.home_configuration())
        if v != h
    ]
    out.append(ET.Element("wrist_sensor", {"link": scene.wrist_sensor_link}))
    return out


def _geometry_elements(scene: Scene) -> list[ET.Element]:
    """<rollout_contact>, <sphere>, <pair>, <arm_reach> of the scene."""
    out = [ET.Element("rollout_contact", {"links": " ".join(scene.rollout_contact_links)})]
    for name, link, centre, radius, obstacles in scene._core.spheres():
        attributes = {"name": name, "link": link, "xyz": _values(centre), "radius": _number(radius)}
        if not obstacles:
            attributes["obstacles"] = "false"
        out.append(ET.Element("sphere", attributes))
    out += [ET.Element("pair", {"a": a, "b": b}) for a, b in scene.self_collision_pairs]
    if scene.arm_reach is not None:
        base, frame, reach = scene.arm_reach
        out.append(ET.Element("arm_reach", {"base": base, "frame": frame, "max": _number(reach)}))
    return out


def sabre_block(scene: Scene) -> str:
    """The ``<sabre>`` block that declares everything sabre uses of the scene's robot: its roles (tool,
    tool frame, held joints, base, postures, wrist sensor) and its safety geometry (rollout contact
    links, spheres, self-collision pairs, reach). The robot's URDF with this block loads to the same
    robot whatever sabre would detect or generate."""
    block = ET.Element("sabre")
    block.extend(_role_elements(scene) + _geometry_elements(scene))
    ET.indent(block, space="  ", level=1)
    return "  " + ET.tostring(block, encoding="unicode")


_BLOCK = re.compile(r"\s*<sabre>.*?</sabre>|\s*<sabre\s*/>", re.DOTALL)


def with_sabre_block(urdf: str, block: str) -> str:
    """The URDF text ``urdf`` with its ``<sabre>`` block (if any) replaced by ``block``, placed before ``</robot>``."""
    stripped = _BLOCK.sub("", urdf)
    end = stripped.rindex("</robot>")
    return stripped[:end].rstrip() + "\n" + block + "\n" + stripped[end:]


def describe(scene: Scene) -> str:
    """A plain-text report of what sabre uses of the scene's robot, and where each part came from."""
    how = scene.role_origins
    lines = [f"robot {scene.robot_name!r}: {scene.nq} planned joints"]
    for i, name in enumerate(scene.joint_names):
        lines.append(
            f"  {name:24s} [{scene.q_lower[i]: .4g}, {scene.q_upper[i]: .4g}]  velocity {scene.dq_limit[i]:.4g}  "
            f"effort {scene.effort_limit[i]:.4g}  home {scene.home_configuration()[i]: .4g}"
        )
    for joint, value in scene.held_joints.items():
        lines.append(f"  held {joint} at {value:.4g} ({how.get('hold:' + joint, '?')})")
    lines.append(f"tool frame: {scene.tool_frame} ({how['tool_frame']})" + (f", tool {scene.tool}" if scene.tool else ""))
    base = "fixed" if scene.base_joints is None else "holonomic, joints (x, y, yaw) " + ", ".join(scene.base_joints)
    lines.append(f"base: {base}, link {scene.base_link} ({how['base']})")
    lines.append(f"wrist sensor: {scene.wrist_sensor_link} ({how['wrist_sensor']})")
    lines.append(f"safety geometry ({how['geometry']}):")
    lines.append(f"  rollout contact links: {', '.join(scene.rollout_contact_links)}")
    spheres = scene._core.spheres()
    lines.append(f"  {len(spheres)} spheres:")
    for name, link, centre, radius, obstacles in spheres:
        note = "" if obstacles else " (self-collision only)"
        lines.append(f"    {name:24s} on {link:20s} at ({_values(np.round(centre, 4))}) radius {radius:.4f}{note}")
    lines.append(f"  {len(scene.self_collision_pairs)} self-collision pairs:")
    lines += [f"    {a} - {b}" for a, b in scene.self_collision_pairs]
    reach = scene.arm_reach
    lines.append("  arm reach: none" if reach is None else f"  arm reach: {reach[1]} within {reach[2]:.4f} m of {reach[0]}")
    return "\n".join(lines)
