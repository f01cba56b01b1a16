"""Objects written the way other tools write them: a URDF per random specification, with its own link and
joint names, a `world` root with a fixed joint and no `handle_frame`.

`random_spec(rng, index)` draws one object: handle height 0.6–1.1 m, door or drawer width 0.25–0.6 m,
hinge left or right, vertical or horizontal bar, a box, cylinder or mesh (STL) bar, revolute door or
prismatic drawer, friction and damping ×0.5–×2, moving mass ×0.5–×2, and where it stands: 2–4 m from
the robot, its front within ±60° of facing it. `object_urdf(spec)` writes it and `scene_of(spec)` loads
it next to the RoyalPanda. The generality sweep (experiments/generality_sweep.py) opens these objects
and tests/scenarios/test_generality.py checks the handle frame inferred from each.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import sabre

ROBOT_URDF = Path(__file__).resolve().parents[1] / "assets" / "robots" / "royalpanda.urdf"


@dataclass(frozen=True)
class ObjectSpec:
    """One generated object: its parameters and where it stands."""

    index: int
    kind: str  # "door" (revolute) or "drawer" (prismatic)
    width: float
    handle_height: float
    hinge_left: bool
    vertical_bar: bool
    bar_shape: str  # "box", "cylinder" or "mesh" (an STL of the box bar)
    damping_scale: float
    friction_scale: float
    mass_scale: float
    distance: float
    bearing: float  # rad: direction of the object from the robot
    facing: float  # rad: how far its front turns away from facing the robot

    @property
    def handle_link(self) -> str:
        return f"grip_{self.index}"

    def pose(self) -> list[float]:
        """(x, y, z, roll, pitch, yaw): the front (−x of the object frame) faces the robot at the
        origin, turned by ``facing``."""
        x, y = self.distance * np.cos(self.bearing), self.distance * np.sin(self.bearing)
        return [float(x), float(y), 0.0, 0.0, 0.0, float(self.bearing + self.facing)]


def random_spec(rng: np.random.Generator, index: int) -> ObjectSpec:
    def scale() -> float:  # ×0.5–×2, uniform in log
        return float(np.exp(rng.uniform(np.log(0.5), np.log(2.0))))

    kind = "door" if rng.random() < 0.6 else "drawer"
    return ObjectSpec(
        index=index,
        kind=kind,
        width=float(rng.uniform(0.25, 0.6)),
        handle_height=float(rng.uniform(0.6, 1.1)),
        hinge_left=bool(rng.random() < 0.5),
        vertical_bar=bool(rng.random() < (0.7 if kind == "door" else 0.3)),
        bar_shape=("box", "cylinder", "mesh")[min(2, int(3 * rng.random()))],
        damping_scale=scale(),
        friction_scale=scale(),
        mass_scale=scale(),
        distance=float(rng.uniform(2.0, 4.0)),
        bearing=float(rng.uniform(-0.5, 0.5)),
        facing=float(rng.uniform(-np.pi / 3, np.pi / 3)),
    )


def _box(name: str, xyz: tuple[float, float, float], size: tuple[float, float, float]) -> str:
    return (
        f'<collision name="{name}"><origin xyz="{xyz[0]:.4f} {xyz[1]:.4f} {xyz[2]:.4f}"/>'
        f'<geometry><box size="{size[0]:.4f} {size[1]:.4f} {size[2]:.4f}"/></geometry></collision>'
        f'<visual name="{name}"><origin xyz="{xyz[0]:.4f} {xyz[1]:.4f} {xyz[2]:.4f}"/>'
        f'<geometry><box size="{size[0]:.4f} {size[1]:.4f} {size[2]:.4f}"/></geometry></visual>'
    )


def _inertial(mass: float, xyz: tuple[float, float, float], size: tuple[float, float, float]) -> str:
    a, b, c = size
    ixx, iyy, izz = mass / 12 * (b * b + c * c), mass / 12 * (a * a + c * c), mass / 12 * (a * a + b * b)
    return (
        f'<inertial><origin xyz="{xyz[0]:.4f} {xyz[1]:.4f} {xyz[2]:.4f}"/><mass value="{mass:.4f}"/>'
        f'<inertia ixx="{ixx:.6g}" ixy="0" ixz="0" iyy="{iyy:.6g}" iyz="0" izz="{izz:.6g}"/></inertial>'
    )


def _bar_stl(size: tuple[float, float, float]) -> str:
    """An STL file of a box bar (written once per size into the temp directory), as CAD exports ship."""
    import trimesh

    path = Path(tempfile.gettempdir()) / "sabre-generated" / f"bar_{size[0]:.3f}_{size[1]:.3f}_{size[2]:.3f}.stl"
    if not path.is_file():
        path.parent.mkdir(parents=True, exist_ok=True)
        trimesh.creation.box(extents=size).export(path)
    return str(path)


def object_urdf(spec: ObjectSpec) -> str:
    """The object as a URDF in another tool's style (names suffixed with the index, a world root)."""
    i, w, h = spec.index, spec.width, spec.handle_height
    door = spec.kind == "door"
    panel_h = 0.6 if door else 0.22
    bottom = h - panel_h / 2
    carcass = [
        _box("side_a", (0.218, w / 2 - 0.009, bottom + panel_h / 2), (0.4, 0.018, panel_h)),
        _box("side_b", (0.218, -(w / 2 - 0.009), bottom + panel_h / 2), (0.4, 0.018, panel_h)),
        _box("plinth", (0.218, 0.0, bottom / 2), (0.4, w, bottom)),
        _box("back", (0.41, 0.0, bottom + panel_h / 2), (0.018, w, panel_h)),
    ]
    s = 1.0 if spec.hinge_left else -1.0
    if door:
        mass = 5.8 * spec.mass_scale
        panel_xyz = (0.008, -s * w / 2, 0.0)
        moving = _inertial(mass, panel_xyz, (0.016, w, panel_h)) + _box("panel", panel_xyz, (0.016, w, panel_h))
        joint = (
            f'<joint name="hinge_{i}" type="revolute"><parent link="body_{i}"/><child link="leaf_{i}"/>'
            f'<origin xyz="0 {s * w / 2:.4f} {h:.4f}"/><axis xyz="0 0 {-s:.0f}"/>'
            f'<limit lower="0" upper="1.57" effort="50" velocity="2"/>'
            f'<dynamics damping="{2.0 * spec.damping_scale:.3f}" friction="{4.0 * spec.friction_scale:.3f}"/></joint>'
        )
        grip_y = -s * (w - 0.04)
    else:
        mass = 3.0 * spec.mass_scale
        front, tray = (0.008, 0.0, 0.0), (0.19, 0.0, -panel_h / 2 + 0.02)
        moving = (
            _inertial(mass, (0.1, 0.0, -0.05), (0.35, w - 0.04, panel_h))
            + _box("front", front, (0.016, w, panel_h))
            + _box("tray", tray, (0.35, w - 0.04, 0.01))
        )
        joint = (
            f'<joint name="slide_{i}" type="prismatic"><parent link="body_{i}"/><child link="leaf_{i}"/>'
            f'<origin xyz="0 0 {h:.4f}"/><axis xyz="-1 0 0"/>'
            f'<limit lower="0" upper="0.35" effort="100" velocity="1"/>'
            f'<dynamics damping="{2.0 * spec.damping_scale:.3f}" friction="{0.5 * spec.friction_scale:.3f}"/></joint>'
        )
        grip_y = 0.0
    length = 0.17
    if spec.vertical_bar:
        bar_size, standoffs, rpy = (0.01, 0.01, length), [(0.033, 0.0, 0.08), (0.033, 0.0, -0.08)], "0 0 0"
    else:
        bar_size, standoffs, rpy = (0.01, length, 0.01), [(0.033, 0.08, 0.0), (0.033, -0.08, 0.0)], "1.5707963 0 0"
    if spec.bar_shape == "box":
        bar = _box("bar", (0.0, 0.0, 0.0), bar_size)
    elif spec.bar_shape == "mesh":
        path = _bar_stl(bar_size)
        bar = (
            f'<collision name="bar"><geometry><mesh filename="{path}"/></geometry></collision>'
            f'<visual name="bar"><geometry><mesh filename="{path}"/></geometry></visual>'
        )
    else:
        bar = (
            f'<collision name="bar"><origin xyz="0 0 0" rpy="{rpy}"/><geometry><cylinder radius="0.006" length="{length}"/>'
            f'</geometry></collision><visual name="bar"><origin xyz="0 0 0" rpy="{rpy}"/><geometry>'
            f'<cylinder radius="0.006" length="{length}"/></geometry></visual>'
        )
    grip = (
        _inertial(0.1, (0.013, 0.0, 0.0), (0.06, 0.02, 0.17))
        + bar
        + "".join(_box(f"standoff_{k}", xyz, (0.056, 0.01, 0.01)) for k, xyz in enumerate(standoffs))
    )
    return f"""<?xml version="1.0"?>
<robot name="generated_{spec.kind}_{i}">
  <link name="world"/>
  <joint name="mount_{i}" type="fixed"><parent link="world"/><child link="body_{i}"/></joint>
  <link name="body_{i}">{_inertial(25.0, (0.2, 0.0, 0.4), (0.4, w, 0.8))}{"".join(carcass)}</link>
  <link name="leaf_{i}">{moving}</link>
  {joint}
  <link name="grip_{i}">{grip}</link>
  <joint name="grip_mount_{i}" type="fixed"><parent link="leaf_{i}"/><child link="grip_{i}"/>
    <origin xyz="-0.061 {grip_y:.4f} 0"/></joint>
</robot>
"""


def scene_of(spec: ObjectSpec) -> sabre.Scene:
    return sabre.Scene.from_urdf_strings(ROBOT_URDF.read_text(), object_urdf(spec), spec.pose())
