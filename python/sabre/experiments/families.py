"""The generated object families of the generality sweep and the hook experiment: objects written the
way other tools write them, in two families, each drawn from a random specification.

The box family (`random_spec`, `object_urdf`): a URDF per object with its own link and joint names, a
`world` root with a fixed joint and no `handle_frame`; handle height 0.6–1.1 m, door or drawer width
0.25–0.6 m, hinge left or right, vertical or horizontal bar, a box, cylinder or mesh (STL) bar, revolute
door or prismatic drawer, friction and damping ×0.5–×2, moving mass ×0.5–×2.

The mesh family (`random_mesh_spec`, `write_mesh_cabinet`): cabinets as robot-learning benchmarks ship
them, a ROS package each (package.xml, urdf/, meshes/ named by package:// URLs); every part a set of
convex mesh pieces (STL and multi-object OBJ files), no inertial anywhere; two doors hinged left and
right over or under two stacked drawers, so that handles stand 0.51–1.23 m high; handles as mesh bars
(one piece, two halves, or a 16-sided round bar) on standoffs; one of the four parts is the target.

Both stand 2–4 m from the robot, their front within ±60° of facing it (`pose()`), and `scene_of(spec, robot)`
loads either next to a mobile robot (the RoyalPanda or a mobile example robot). `python -m sabre
experiment hook` (:mod:`sabre.experiments.hook`) opens these objects.
"""

from __future__ import annotations

import tempfile
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .. import assets
from ..errors import AssumedInertialWarning, InvalidValueError
from ..robot_examples import EXAMPLE_ROBOTS, example_robot_urdf
from ..scene import Scene
from . import mesh_files


def robot_urdf(robot: str = "royalpanda") -> Path:
    """The URDF file of ``robot``: the built-in RoyalPanda or an example robot
    (:data:`sabre.robot_examples.EXAMPLE_ROBOTS`)."""
    if robot == "royalpanda":
        return assets.urdf_path(robot)
    if robot in EXAMPLE_ROBOTS:
        return example_robot_urdf(robot)
    raise InvalidValueError(f"unknown robot {robot!r}; royalpanda or one of {sorted(EXAMPLE_ROBOTS)}")


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
    bar_size: float = 0.01  # m: the bar's thickness and depth (a cylinder bar's diameter)
    standoff: float = 0.056  # m: from the bar's back face to the panel

    @property
    def handle_link(self) -> str:
        return f"grip_{self.index}"

    @property
    def handle_class(self) -> str:
        return handle_class(self.standoff)

    def pose(self) -> list[float]:
        """(x, y, z, roll, pitch, yaw): the front (−x of the object frame) faces the robot at the
        origin, turned by ``facing``."""
        x, y = self.distance * np.cos(self.bearing), self.distance * np.sin(self.bearing)
        return [float(x), float(y), 0.0, 0.0, 0.0, float(self.bearing + self.facing)]

    def describe(self) -> str:
        bar = "vertical" if self.vertical_bar else "horizontal"
        size = f"{1000 * self.bar_size:.0f} mm on {1000 * self.standoff:.0f} mm standoffs"
        return f"{self.kind}, w {self.width:.2f}, h {self.handle_height:.2f}, {bar} {self.bar_shape}, {size}"


#: Standoffs shorter than this (m) make a handle of the short-standoff class: bars of 10–20 mm on
#: standoffs of 20–40 mm, as benchmark cabinets and kitchen pulls have them.
SHORT_STANDOFF = 0.045


def handle_class(standoff: float) -> str:
    """The handle class the sweep reports on its own: "short standoff" or "standard"."""
    return "short standoff" if standoff < SHORT_STANDOFF else "standard"


def short_handle(rng: np.random.Generator) -> tuple[float, float]:
    """(bar size, standoff) in m: half the handles standard (a 10 mm bar on 56 mm standoffs), half of
    the short-standoff class (a 10–20 mm bar on 20–40 mm standoffs)."""
    if rng.random() < 0.5:
        return 0.01, 0.056
    return float(rng.uniform(0.01, 0.02)), float(rng.uniform(0.02, 0.04))


def _log_scale(rng: np.random.Generator) -> float:
    """A factor ×0.5–×2, uniform in log."""
    return float(np.exp(rng.uniform(np.log(0.5), np.log(2.0))))


def _placement(rng: np.random.Generator) -> dict[str, float]:
    """Where an object stands: 2–4 m away, within ±0.5 rad of straight ahead, its front within ±60°
    of facing the robot (drawn in this order)."""
    distance = float(rng.uniform(2.0, 4.0))
    bearing = float(rng.uniform(-0.5, 0.5))
    return {"distance": distance, "bearing": bearing, "facing": float(rng.uniform(-np.pi / 3, np.pi / 3))}


def random_spec(rng: np.random.Generator, index: int) -> ObjectSpec:
    kind = "door" if rng.random() < 0.6 else "drawer"
    spec = ObjectSpec(
        index=index,
        kind=kind,
        width=float(rng.uniform(0.25, 0.6)),
        handle_height=float(rng.uniform(0.6, 1.1)),
        hinge_left=bool(rng.random() < 0.5),
        vertical_bar=bool(rng.random() < (0.7 if kind == "door" else 0.3)),
        bar_shape=("box", "cylinder", "mesh")[min(2, int(3 * rng.random()))],
        damping_scale=_log_scale(rng),
        friction_scale=_log_scale(rng),
        mass_scale=_log_scale(rng),
        **_placement(rng),
    )
    bar_size, standoff = short_handle(rng)
    return replace(spec, bar_size=bar_size, standoff=standoff)


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
    length, b, post = 0.17, spec.bar_size, spec.standoff
    x = b / 2 + post / 2  # a standoff's centre: from the bar's back face to the panel
    if spec.vertical_bar:
        bar_size, standoffs, rpy = (b, b, length), [(x, 0.0, 0.08), (x, 0.0, -0.08)], "0 0 0"
    else:
        bar_size, standoffs, rpy = (b, length, b), [(x, 0.08, 0.0), (x, -0.08, 0.0)], "1.5707963 0 0"
    radius = 0.6 * b
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
            f'<collision name="bar"><origin xyz="0 0 0" rpy="{rpy}"/><geometry>'
            f'<cylinder radius="{radius:.4f}" length="{length}"/></geometry></collision>'
            f'<visual name="bar"><origin xyz="0 0 0" rpy="{rpy}"/><geometry>'
            f'<cylinder radius="{radius:.4f}" length="{length}"/></geometry></visual>'
        )
    grip = (
        _inertial(0.1, (0.013, 0.0, 0.0), (0.06, 0.02, 0.17))
        + bar
        + "".join(_box(f"standoff_{k}", xyz, (post, 0.01, 0.01)) for k, xyz in enumerate(standoffs))
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
    <origin xyz="{-(post + b / 2):.4f} {grip_y:.4f} 0"/></joint>
</robot>
"""


def scene_of(spec: ObjectSpec | MeshCabinetSpec, robot: str = "royalpanda") -> Scene:
    """The object of either family next to ``robot`` (see :func:`robot_urdf`), its target joint the one movable."""
    if isinstance(spec, MeshCabinetSpec):
        return mesh_scene_of(spec, robot=robot)
    return Scene.from_urdf(robot_urdf(robot), assets.urdf_file(object_urdf(spec), f"generated-{spec.index}"), spec.pose())


# -- the mesh family: cabinets as robot-learning benchmarks ship them ------------------------------------------------

#: The four moving parts of a mesh cabinet, by their index in link and joint names.
PARTS = ("left door", "right door", "low drawer", "high drawer")
BOARD = 0.018  # m: carcass boards and fronts
DEPTH = 0.45  # m: the carcass behind the fronts


@dataclass(frozen=True)
class MeshCabinetSpec:
    """One generated cabinet with two doors (hinged left and right, side by side) and two drawers
    (stacked), every part a set of convex mesh pieces, no inertial anywhere, handles as mesh bars
    on standoffs; ``target`` is the part the sweep opens."""

    index: int
    width: float
    plinth: float  # m: the height the lowest section starts at
    drawer_height: float
    door_height: float
    drawers_on_top: bool
    handle_inset: float  # m: a door handle's distance from the door's edge nearest the drawers
    handle_edge: float  # m: a door handle's distance from the door's free edge
    bar_length: float
    handle_style: str  # "pieces" (bar and standoffs, an STL each), "split" (bar in halves, one OBJ), "round" (16-gon bar)
    target: int  # index into PARTS
    damping_scale: float
    friction_scale: float
    distance: float
    bearing: float
    facing: float
    bar_size: float = 0.01  # m: the bar's thickness and depth (the round bar's diameter)
    standoff: float = 0.056  # m: from the bar's back face to the front it is mounted on

    @property
    def handle_link(self) -> str:
        return f"handle_{self.target}"

    @property
    def handle_class(self) -> str:
        return handle_class(self.standoff)

    @property
    def handle_mount(self) -> float:
        """x (m) of the handle's origin (the bar's centre) in its part's frame: in front of the front."""
        return -(self.standoff + self.bar_size / 2)

    @property
    def package(self) -> str:
        return f"mesh_cabinet_{self.index}"

    def pose(self) -> list[float]:
        x, y = self.distance * np.cos(self.bearing), self.distance * np.sin(self.bearing)
        return [float(x), float(y), 0.0, 0.0, 0.0, float(self.bearing + self.facing)]

    def sections(self) -> dict[str, tuple[float, float]]:
        """(bottom, height) of the door section and each drawer, bottom to top."""
        order = ["doors", "low drawer", "high drawer"] if self.drawers_on_top else ["low drawer", "high drawer", "doors"]
        out, z = {}, self.plinth
        for name in order:
            height = self.door_height if name == "doors" else self.drawer_height
            out[name] = (z, height)
            z += height
        return out

    def handle_height(self) -> float:
        """Height (m) of the target's handle above the floor."""
        bottom, height = self.sections()["doors" if self.target < 2 else PARTS[self.target]]
        if self.target >= 2:
            return bottom + height / 2
        return bottom + height - self.handle_inset if self.drawers_on_top else bottom + self.handle_inset

    def describe(self) -> str:
        size = f"{1000 * self.bar_size:.0f} mm on {1000 * self.standoff:.0f} mm standoffs"
        return f"{PARTS[self.target]}, w {self.width:.2f}, h {self.handle_height():.2f}, {self.handle_style} mesh handle, {size}"


def random_mesh_spec(rng: np.random.Generator, index: int) -> MeshCabinetSpec:
    drawers_on_top = bool(rng.random() < 0.5)
    spec = MeshCabinetSpec(
        index=index,
        width=float(rng.uniform(0.6, 0.9)),
        # drawers on top of low doors: door handles 0.51–0.77 m, drawers 0.75–1.23 m; drawers under
        # raised doors: drawers 0.58–0.93 m, door handles 0.96–1.19 m (drawer handles down to 0.48 m
        # were not hooked from the default start, docs/results.md)
        plinth=float(rng.uniform(0.2, 0.3) if drawers_on_top else rng.uniform(0.48, 0.55)),
        drawer_height=float(rng.uniform(0.2, 0.25)),
        door_height=float(rng.uniform(0.45, 0.55)),
        drawers_on_top=drawers_on_top,
        handle_inset=float(rng.uniform(0.08, 0.14)),
        handle_edge=float(rng.uniform(0.06, 0.1)),
        bar_length=float(rng.uniform(0.14, 0.22)),
        handle_style=("pieces", "split", "round")[int(rng.integers(3))],
        target=int(rng.integers(4)),
        damping_scale=_log_scale(rng),
        friction_scale=_log_scale(rng),
        **_placement(rng),
    )
    bar_size, standoff = short_handle(rng)
    return replace(spec, bar_size=bar_size, standoff=standoff)


def _carcass(spec: MeshCabinetSpec) -> list[tuple[str, mesh_files.Piece]]:
    """The fixed body's convex pieces in its frame: sides, top, back, a plinth block and a rail
    under and over each drawer."""
    w, x = spec.width, BOARD + 0.002 + DEPTH / 2
    top = sum(spec.sections()["doors"]) if not spec.drawers_on_top else sum(spec.sections()["high drawer"])
    pieces = [
        ("side_left", mesh_files.box((x, w / 2 - BOARD / 2, top / 2), (DEPTH, BOARD, top))),
        ("side_right", mesh_files.box((x, -w / 2 + BOARD / 2, top / 2), (DEPTH, BOARD, top))),
        ("top", mesh_files.box((x, 0.0, top + BOARD / 2), (DEPTH, w, BOARD))),
        ("back", mesh_files.box((x + DEPTH / 2 - BOARD / 2, 0.0, top / 2), (BOARD, w - 2 * BOARD, top))),
        ("plinth", mesh_files.box((x, 0.0, spec.plinth / 2 - BOARD / 2), (DEPTH, w - 2 * BOARD, spec.plinth - BOARD))),
    ]
    for name, (bottom, _) in spec.sections().items():
        if name != "doors":
            rail = (DEPTH - BOARD, w - 2 * BOARD, 0.008)
            pieces.append((f"rail_{name.replace(' ', '_')}", mesh_files.box((x - BOARD / 2, 0.0, bottom - 0.004), rail)))
    return pieces


def _handle_pieces(spec: MeshCabinetSpec, vertical: bool) -> list[tuple[str, mesh_files.Piece]]:
    """The handle's convex pieces in its link frame (origin at the bar's centre, +x into the front):
    the bar and two standoffs from its back face to the front (1 mm into the bar)."""
    length, axis, b = spec.bar_length, 2 if vertical else 1, spec.bar_size
    along = np.eye(3)[axis]
    post = spec.standoff + 0.001
    standoffs = [
        (
            f"standoff_{k}",
            mesh_files.box(
                np.array([b / 2 - 0.001 + post / 2, 0.0, 0.0]) + sign * (length / 2 - 0.012) * along, (post, 0.01, 0.01)
            ),
        )
        for k, sign in enumerate((-1.0, 1.0))
    ]
    if spec.handle_style == "round":
        return [("bar", mesh_files.prism((0.0, 0.0, 0.0), axis, 0.6 * b, length))] + standoffs
    size = np.full(3, b)
    size[axis] = length
    if spec.handle_style == "split":
        halves = []
        for k, sign in enumerate((-1.0, 1.0)):
            half = size.copy()
            half[axis] = length / 2
            halves.append((f"bar_{k}", mesh_files.box(sign * length / 4 * along, half)))
        return halves + standoffs
    return [("bar", mesh_files.box((0.0, 0.0, 0.0), size))] + standoffs


def _door(spec: MeshCabinetSpec, k: int) -> tuple[list[tuple[str, mesh_files.Piece]], list[float], str]:
    """Door k (0 left, 1 right): its leaf's pieces in the link frame (at the hinge), the joint's origin
    and axis, and the handle's origin in the leaf frame."""
    s = 1.0 if k == 0 else -1.0  # the hinge on the robot's left (+y) for the left door
    bottom, height = spec.sections()["doors"]
    leaf_w, leaf_h = spec.width / 2 - 0.004, height - 0.006
    half = [
        (f"leaf_{j}", mesh_files.box((BOARD / 2, -s * leaf_w / 2, sign * leaf_h / 4), (BOARD, leaf_w, leaf_h / 2)))
        for j, sign in enumerate((-1, 1))
    ]
    handle_z = (height / 2 - spec.handle_inset) if spec.drawers_on_top else (spec.handle_inset - height / 2)
    joint = [0.0, s * (spec.width / 2 - 0.002), bottom + height / 2]
    return half, joint, f"{spec.handle_mount:g} {-s * (leaf_w - spec.handle_edge):.4f} {handle_z:.4f}"


def _drawer(spec: MeshCabinetSpec, name: str) -> tuple[list[tuple[str, mesh_files.Piece]], list[float]]:
    """A drawer's pieces in its link frame (at the front's centre) and the joint's origin."""
    bottom, height = spec.sections()[name]
    inner = spec.width - 2 * BOARD - 0.014
    box_h, depth = height - 0.04, DEPTH - 0.06
    x = BOARD + 0.004 + depth / 2
    pieces = [
        ("front", mesh_files.box((BOARD / 2, 0.0, 0.0), (BOARD, spec.width - 0.004, height - 0.006))),
        ("floor", mesh_files.box((x, 0.0, -height / 2 + 0.025), (depth, inner, 0.012))),
        ("side_a", mesh_files.box((x, inner / 2 - 0.006, -height / 2 + 0.02 + box_h / 2), (depth, 0.012, box_h))),
        ("side_b", mesh_files.box((x, -inner / 2 + 0.006, -height / 2 + 0.02 + box_h / 2), (depth, 0.012, box_h))),
        ("back", mesh_files.box((x + depth / 2 - 0.006, 0.0, -height / 2 + 0.02 + box_h / 2), (0.012, inner - 0.024, box_h))),
    ]
    return pieces, [0.0, 0.0, bottom + height / 2]


def _mesh_link(name: str, files: list[str]) -> str:
    """A link whose collision and visual are the given mesh files (package:// URLs)."""
    geometries = [f'<geometry><mesh filename="{f}"/></geometry>' for f in files]
    body = "".join(f"<visual>{g}</visual><collision>{g}</collision>" for g in geometries)
    return f'  <link name="{name}">{body}</link>\n'


def _write_handle(spec: MeshCabinetSpec, part: int, meshes: Path, url: str) -> list[str]:
    """Writes part ``part``'s handle meshes; returns their package:// URLs."""
    pieces = _handle_pieces(spec, vertical=part < 2)
    if spec.handle_style == "pieces":
        for name, piece in pieces:
            mesh_files.write_stl(meshes / f"handle_{part}_{name}.stl", piece)
        return [f"{url}/handle_{part}_{name}.stl" for name, _ in pieces]
    mesh_files.write_obj(meshes / f"handle_{part}.obj", pieces)
    return [f"{url}/handle_{part}.obj"]


def _moving_parts(spec: MeshCabinetSpec, meshes: Path, url: str) -> str:
    """Writes every moving part's meshes; returns their links and joints as URDF text."""
    text = ""
    for part in range(4):
        if part < 2:
            pieces, origin, handle_origin = _door(spec, part)
            s = 1.0 if part == 0 else -1.0
            joint = (
                f'type="revolute"><axis xyz="0 0 {-s:.0f}"/><limit lower="0" upper="1.57" effort="50" velocity="2"/>'
                f'<dynamics damping="{2.0 * spec.damping_scale:.3f}" friction="{4.0 * spec.friction_scale:.3f}"/>'
            )
        else:
            pieces, origin = _drawer(spec, PARTS[part])
            handle_origin = f"{spec.handle_mount:g} 0 0"
            joint = (
                f'type="prismatic"><axis xyz="-1 0 0"/><limit lower="0" upper="0.35" effort="100" velocity="1"/>'
                f'<dynamics damping="{2.0 * spec.damping_scale:.3f}" friction="{0.5 * spec.friction_scale:.3f}"/>'
            )
        mesh_files.write_obj(meshes / f"link_{part}.obj", pieces)
        text += _mesh_link(f"link_{part}", [f"{url}/link_{part}.obj"])
        text += _mesh_link(f"handle_{part}", _write_handle(spec, part, meshes, url))
        text += (
            f'  <joint name="joint_{part}" {joint}<parent link="body"/><child link="link_{part}"/>'
            f'<origin xyz="{origin[0]:.4f} {origin[1]:.4f} {origin[2]:.4f}"/></joint>\n'
            f'  <joint name="handle_joint_{part}" type="fixed"><parent link="link_{part}"/><child link="handle_{part}"/>'
            f'<origin xyz="{handle_origin}"/></joint>\n'
        )
    return text


#: The cabinet shipped as assets/objects/examples/mesh_cabinet, written by
#: ``write_mesh_cabinet(MESH_CABINET_EXAMPLE, Path("assets/objects/examples"), "mesh_cabinet")``.
MESH_CABINET_EXAMPLE = MeshCabinetSpec(
    index=0,
    width=0.7,
    plinth=0.35,
    drawer_height=0.18,
    door_height=0.5,
    drawers_on_top=False,
    handle_inset=0.12,
    handle_edge=0.045,
    bar_length=0.17,
    handle_style="split",
    target=2,
    damping_scale=1.0,
    friction_scale=1.0,
    distance=2.0,
    bearing=0.0,
    facing=0.0,
)


def write_mesh_cabinet(spec: MeshCabinetSpec, root: Path, package: str | None = None) -> Path:
    """Writes the cabinet as a ROS package ``package`` (default ``spec.package``) under ``root``
    (package.xml, urdf/cabinet.urdf, meshes/; the URDF names its meshes by package:// URLs) and
    returns the URDF's path. An even index names the package's folder like the package, an odd one
    differently (found through its package.xml)."""
    package = package or spec.package
    folder = root / (package if spec.index % 2 == 0 else f"cabinet_{spec.index}_description")
    meshes, url = folder / "meshes", f"package://{package}/meshes"
    mesh_files.write_obj(meshes / "body.obj", _carcass(spec))
    urdf = (
        f'<?xml version="1.0"?>\n<robot name="{package}">\n  <link name="base"/>\n'
        f'  <joint name="base_joint" type="fixed"><parent link="base"/><child link="body"/></joint>\n'
        + _mesh_link("body", [f"{url}/body.obj"])
        + _moving_parts(spec, meshes, url)
        + "</robot>\n"
    )
    package_xml = (
        f'<?xml version="1.0"?>\n<package format="3">\n  <name>{package}</name>\n  <version>0.0.0</version>\n'
        f'  <description>A generated cabinet</description>\n  <maintainer email="sabre@example.com">sabre</maintainer>\n'
        f"  <license>Apache-2.0</license>\n</package>\n"
    )
    mesh_files.write_text(folder / "package.xml", package_xml)
    path = folder / "urdf" / "cabinet.urdf"
    mesh_files.write_text(path, urdf)
    return path


def mesh_scene_of(spec: MeshCabinetSpec, root: Path | None = None, robot: str = "royalpanda") -> Scene:
    """The cabinet written under ``root`` (default: the temp directory) and loaded from its file next to
    ``robot``, keeping the joint of the target's handle; no inertial warnings (there are none
    by design: sabre fills every moving part's in from its meshes)."""
    path = write_mesh_cabinet(spec, root or Path(tempfile.gettempdir()) / "sabre-generated" / "mesh-cabinets")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", AssumedInertialWarning)
        return Scene.from_urdf(robot_urdf(robot), path, spec.pose(), handle=spec.handle_link)
