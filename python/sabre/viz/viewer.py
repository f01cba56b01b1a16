"""Browser 3D viewer on viser: replays a recorded :class:`~sabre.Episode` on a timeline, or shows a run live.

viser (the library judo uses) serves a three.js scene over a websocket, so any browser is the
client, and ships GUI controls (timeline slider, play checkbox) in the same page; rerun needs its
own viewer application and meshcat has no GUI controls. The robot and the object are drawn from
the visuals of their URDFs (primitives and meshes), posed by sabre's own kinematics (:meth:`Scene.fk_many`).
Needs the ``viewer`` extra: ``pip install 'sabre-mpc[viewer]'``.
"""

from __future__ import annotations

import os
import threading
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .. import _core
from ..episode import Episode, RecordedPlan
from ..errors import SabreError, UnknownAssetError, UrdfError, require_extra
from ..safety import SafetyConfig, SafetyFilter
from ..scene import Scene, Visual

__all__ = ["Viewer", "VisualShape", "urdf_visuals", "asset_path", "replay"]

_ASSETS = Path(__file__).resolve().parents[3] / "assets"
_DEFAULT_RGBA = (0.7, 0.7, 0.72, 1.0)
_PATH_COLOR = (40, 180, 60)
_CONTACT_COLOR = (230, 30, 30)
_LIGHT = np.array([70.0, 110.0, 230.0])  # sampled rollout of negligible weight
_HEAVY = np.array([255.0, 150.0, 0.0])  # the heaviest sampled rollout
_FORCE_SCALE = 0.01  # m of arrow per N of contact force


def _viser():
    viser, trimesh = require_extra("viewer", "the viewer", "viser", "trimesh")
    return viser, trimesh


def asset_path(kind: str, name: str) -> Path:
    """Path of a built-in URDF (``kind`` "robots" or "objects") in the source tree's ``assets/``."""
    path = _ASSETS / kind / f"{name}.urdf"
    if not path.is_file():
        raise UnknownAssetError(f"no URDF for {kind[:-1]} {name!r} at {path}")
    return path


@dataclass(frozen=True)
class VisualShape:
    """One ``<visual>`` primitive of a URDF link: kind "box" (size = extents), "cylinder" or
    "capsule" (size = radius, length) or "sphere" (size = radius), its (4, 4) pose in the link frame
    and its RGBA colour in [0, 1]."""

    link: str
    kind: str
    size: tuple[float, ...]
    origin: np.ndarray
    rgba: tuple[float, float, float, float]


def _attribute(element: ET.Element, name: str) -> str:
    """An attribute the URDF must have; a missing one is a :class:`UrdfError` naming the element."""
    value = element.get(name)
    if value is None:
        raise UrdfError(f"<{element.tag}> needs the attribute '{name}'")
    return value


def _origin(element: ET.Element | None) -> np.ndarray:
    pose = np.eye(4)
    if element is None:
        return pose
    xyz = [float(v) for v in element.get("xyz", "0 0 0").split()]
    roll, pitch, yaw = (float(v) for v in element.get("rpy", "0 0 0").split())
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    pose[:3, :3] = [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]
    pose[:3, 3] = xyz
    return pose


def urdf_visuals(path: str | Path) -> list[VisualShape]:
    """The primitive visuals of every link of a URDF (meshes are skipped)."""
    root = ET.parse(path).getroot()
    named = {m.get("name"): m.find("color") for m in root.findall("material")}
    shapes = []
    for link in root.findall("link"):
        for visual in link.findall("visual"):
            geometry = visual.find("geometry")
            if geometry is None or len(geometry) == 0:
                continue
            g = geometry[0]
            size: tuple[float, ...]
            if g.tag == "box":
                size = tuple(float(v) for v in _attribute(g, "size").split())
            elif g.tag in ("cylinder", "capsule"):
                size = (float(_attribute(g, "radius")), float(_attribute(g, "length")))
            elif g.tag == "sphere":
                size = (float(_attribute(g, "radius")),)
            else:
                continue
            rgba = _DEFAULT_RGBA
            material = visual.find("material")
            if material is not None:
                color = material.find("color")
                color = color if color is not None else named.get(material.get("name"))
                if color is not None:
                    r, g_, b, a = (float(v) for v in _attribute(color, "rgba").split())
                    rgba = (r, g_, b, a)
            shapes.append(VisualShape(_attribute(link, "name"), g.tag, size, _origin(visual.find("origin")), rgba))
    return shapes


def _mesh(trimesh: Any, shape: VisualShape | Visual) -> Any:
    """The triangle mesh of a visual in its link's frame; None for a mesh file that cannot be read."""
    if isinstance(shape, Visual) and shape.kind == "mesh":
        if shape.mesh is None:
            return None
        try:
            vertices, faces = _core.mesh_triangles(shape.mesh, list(shape.scale))
        except SabreError:
            return None
        mesh = trimesh.Trimesh(np.asarray(vertices).reshape(-1, 3), np.asarray(faces).reshape(-1, 3), process=False)
        mesh.apply_transform(shape.pose)
        return mesh
    if shape.kind == "box":
        mesh = trimesh.creation.box(extents=shape.size)
    elif shape.kind == "cylinder":
        mesh = trimesh.creation.cylinder(radius=shape.size[0], height=shape.size[1], sections=24)
    elif shape.kind == "capsule":
        mesh = trimesh.creation.capsule(height=shape.size[1], radius=shape.size[0], count=[16, 16])
    else:
        mesh = trimesh.creation.icosphere(subdivisions=2, radius=shape.size[0])
    mesh.apply_transform(shape.pose if isinstance(shape, Visual) else shape.origin)
    return mesh


def _wxyz(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a rotation matrix."""
    r = rotation
    w = np.sqrt(max(0.0, 1.0 + r[0, 0] + r[1, 1] + r[2, 2])) / 2.0
    x = np.copysign(np.sqrt(max(0.0, 1.0 + r[0, 0] - r[1, 1] - r[2, 2])) / 2.0, r[2, 1] - r[1, 2])
    y = np.copysign(np.sqrt(max(0.0, 1.0 - r[0, 0] + r[1, 1] - r[2, 2])) / 2.0, r[0, 2] - r[2, 0])
    z = np.copysign(np.sqrt(max(0.0, 1.0 - r[0, 0] - r[1, 1] + r[2, 2])) / 2.0, r[1, 0] - r[0, 1])
    q = np.array([w, x, y, z])
    return q / np.linalg.norm(q)


class Viewer:
    """A viser server drawing one scene: robot and object links, the nominal plan's hand path,
    contact points with their forces, and the tank energy and phase in the side panel.

    Open ``http://<host>:<port>`` in a browser. :meth:`replay` adds a timeline; ``run_episode(...,
    viewer=Viewer(scene))`` shows a run live. Every link is drawn from its URDF visuals
    (:attr:`Scene.robot_visuals`, :attr:`Scene.object_visuals`): primitives, and meshes (STL, OBJ,
    COLLADA) read by sabre's core; a mesh file that was not found is left out.
    """

    def __init__(self, scene: Scene, *, host: str = "127.0.0.1", port: int = 8080) -> None:
        viser, trimesh = _viser()
        self.scene = scene
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.port = self.server.get_port()
        self._robot_links = self._add_links(trimesh, "robot", scene.robot_visuals)
        self._object_links = self._add_links(trimesh, "object", scene.object_visuals)
        self.server.scene.add_grid("/ground", width=12.0, height=12.0, cell_size=0.5)
        gui = self.server.gui
        self._time = gui.add_number("time (s)", 0.0, step=0.001, disabled=True)
        self._phase = gui.add_text("phase", "", disabled=True)
        self._tank = gui.add_number("tank energy (J)", 0.0, step=0.001, disabled=True)
        self._opening = gui.add_number("opening", 0.0, step=0.0001, disabled=True)
        self._active = gui.add_text(
            "near constraints", "", disabled=True, hint="safety rows within 5 cm (or 0.05 rad, m²) of their bound at this state"
        )
        self.safety: SafetyFilter | None = None
        self._shown_obstacles = 0
        self._lock = threading.Lock()

    def _add_links(self, trimesh: Any, prefix: str, visuals: tuple[Visual, ...]) -> dict[str, Any]:
        handles = {}
        for i, shape in enumerate(visuals):
            mesh = _mesh(trimesh, shape)
            if mesh is None:
                continue
            if shape.link not in handles:
                handles[shape.link] = self.server.scene.add_frame(f"/{prefix}/{shape.link}", show_axes=False)
            rgb = tuple(int(255 * c) for c in shape.rgba[:3])
            self.server.scene.add_mesh_simple(
                f"/{prefix}/{shape.link}/visual{i}",
                mesh.vertices,
                mesh.faces,
                color=rgb,
                opacity=None if shape.rgba[3] >= 1.0 else shape.rgba[3],
            )
        return handles

    def look_at(self, target: np.ndarray, distance: float = 4.0) -> None:
        """Places the initial camera of new clients at ``distance`` from ``target`` (3,), from the side."""
        target = np.asarray(target, dtype=np.float64)
        self.server.initial_camera.look_at = target
        self.server.initial_camera.position = target + distance * np.array([-0.55, -0.75, 0.5])

    @property
    def robot_links(self) -> tuple[str, ...]:
        """The robot links drawn, by frame name."""
        return tuple(self._robot_links)

    @property
    def object_links(self) -> tuple[str, ...]:
        """The object links drawn, by frame name."""
        return tuple(self._object_links)

    def show_state(self, x: np.ndarray) -> None:
        """Poses robot and object at state x (nx,)."""
        q, _, o, _ = self.scene.split_state(np.asarray(x, dtype=np.float64))
        robot = {name: self.scene.fk(q, name) for name in self._robot_links}
        obj = {name: self.scene.object_fk(o, name) for name in self._object_links}
        self.pose_links(robot, obj)

    def pose_links(self, robot: dict[str, np.ndarray], obj: dict[str, np.ndarray]) -> None:
        """Poses the drawn links: world poses (4, 4) by name of robot links (:attr:`robot_links`) and object
        links (:attr:`object_links`); links left out keep their pose."""
        with self.server.atomic():
            for handles, poses in ((self._robot_links, robot), (self._object_links, obj)):
                for name, pose in poses.items():
                    handles[name].position = pose[:3, 3]
                    handles[name].wxyz = _wxyz(pose[:3, :3])

    def show_plan(
        self,
        hand_path: np.ndarray | None,
        points: np.ndarray | None = None,
        forces: np.ndarray | None = None,
        samples: np.ndarray | None = None,
        weights: np.ndarray | None = None,
    ) -> None:
        """The nominal plan's hand path (K, 3) as a polyline, the sampled rollouts' hand paths
        (S, K, 3) coloured by their weights (S,) from blue (light) to orange (heavy), contact points
        (C, 3) and their forces on the robot (C, 3, N) as arrows; NaN rows are ignored."""
        scene = self.server.scene
        if samples is not None and weights is not None and len(samples):
            share = np.asarray(weights) / max(float(np.max(weights)), 1e-300)
            colours = np.outer(1.0 - share, _LIGHT) + np.outer(share, _HEAVY)
            segments = np.concatenate([np.stack([p[:-1], p[1:]], axis=1) for p in samples])
            per_segment = np.repeat(colours, samples.shape[1] - 1, axis=0)
            scene.add_line_segments(
                "/plan/samples", segments, np.repeat(per_segment[:, None], 2, axis=1).astype(np.uint8), thickness=0.004
            )
        if hand_path is not None and len(hand_path) > 1:
            segments = np.stack([hand_path[:-1], hand_path[1:]], axis=1)
            scene.add_line_segments("/plan/nominal", segments, _PATH_COLOR, thickness=0.012)
        if points is not None:
            keep = np.isfinite(points).all(axis=1)
            pts = points[keep] if keep.any() else np.zeros((1, 3))
            scene.add_point_cloud("/contact/points", pts, _CONTACT_COLOR, point_size=0.03, visible=bool(keep.any()))
            if forces is not None and keep.any():
                tips = pts + _FORCE_SCALE * forces[keep]
                scene.add_line_segments("/contact/forces", np.stack([pts, tips], axis=1), _CONTACT_COLOR, thickness=0.01)

    def show_safety(self, x: np.ndarray, config: SafetyConfig | None = None, obstacles: np.ndarray | None = None) -> None:
        """The base box of ``config`` (default: the paper's) on the ground, sphere obstacles (O, 4:
        centre, radius; NaN rows ignored), and the names of the safety rows near their bound at x."""
        if self.safety is None or config is not None:
            self.safety = SafetyFilter(self.scene, config)
            box = (config or SafetyConfig()).base_box
            if box is not None:
                x0, x1, y0, y1 = box
                corners = np.array([[x0, y0, 0.01], [x1, y0, 0.01], [x1, y1, 0.01], [x0, y1, 0.01]])
                self.server.scene.add_line_segments(
                    "/safety/base_box", np.stack([corners, np.roll(corners, -1, 0)], 1), (200, 120, 0), thickness=0.02
                )
        h = np.asarray(self.safety.constraint_rows(x).h)
        near = [n for n, v in zip(self.safety.row_names, h) if np.isfinite(v) and v < 0.05]
        self._active.value = ", ".join(near[:6]) + (f" (+{len(near) - 6})" if len(near) > 6 else "")
        if obstacles is not None:
            keep = [o for o in obstacles if np.isfinite(o).all()]
            for i in range(self._shown_obstacles):
                self.server.scene.remove_by_name(f"/safety/obstacle{i}")
            for i, o in enumerate(keep):
                self.server.scene.add_icosphere(
                    f"/safety/obstacle{i}", radius=float(o[3]), color=(150, 150, 150), opacity=0.5, position=o[:3]
                )
            self._shown_obstacles = len(keep)

    def show_panel(self, t: float, phase: str, tank: float | None, opening: float) -> None:
        self._time.value = round(float(t), 3)
        self._phase.value = phase
        self._tank.value = round(float(tank), 3) if tank is not None else 0.0
        self._opening.value = round(float(opening), 4)

    def show_recorded_plan(self, plan: RecordedPlan) -> None:
        """A recorded plan's hand paths and contacts (:meth:`show_plan`)."""
        self.show_plan(plan.hand_path, plan.contact_points, plan.contact_forces, plan.sample_hand_paths, plan.sample_weights)

    def show_live(
        self, x: np.ndarray, t: float, plan: RecordedPlan, *, phase: str, tank_energy: float, safety: SafetyConfig
    ) -> None:
        """One frame of a running episode (``run_episode(..., viewer=...)`` calls it after every re-plan): the
        plant's state x (nx,) at time t (s), the latest ``plan``, the task ``phase``, the tank's energy (J), and
        the filters' settings ``safety`` (read the first time, for the constraint rows and the base box)."""
        self.show_state(x)
        self.show_recorded_plan(plan)
        opening = self.scene.split_state(x).o[0]
        self.show_panel(t, phase, tank_energy, opening)
        self.show_safety(x, safety if self.safety is None else None, plan.obstacles)

    # -- replay ---------------------------------------------------------------------------------
    def load_episode(self, episode: Episode) -> Replay:
        """Adds a timeline (slider and play checkbox) for ``episode`` and shows its first frame."""
        return Replay(self, episode)

    def close(self) -> None:
        self.server.stop()


class Replay:
    """The timeline of one episode in a :class:`Viewer`; :meth:`seek` shows the frame at a time."""

    def __init__(self, viewer: Viewer, episode: Episode) -> None:
        self.viewer = viewer
        self.episode = episode
        scene = viewer.scene
        q, _, o, _ = scene.split_state(episode.state)
        # every link's pose at every recorded step, once: the slider then only moves frames
        self._robot = {n: scene.fk_many(q, n) for n in viewer.robot_links}
        self._object = {n: scene.object_fk_many(o, n) for n in viewer.object_links}
        gui = viewer.server.gui
        duration = float(episode.time[-1]) if len(episode.time) else 0.0
        self.slider = gui.add_slider("timeline (s)", 0.0, max(duration, 1e-3), 0.01, 0.0)
        self.playing = gui.add_checkbox("play", False)
        self.slider.on_update(lambda _event: self._show(self.slider.value))
        base = scene.fk_many(q, scene.base_link)[:, :2, 3]
        # nearer the object than the base: the door and the hand are what the viewer is for
        target = 0.4 * np.r_[base.mean(axis=0), 0.6] + 0.6 * np.r_[scene.object_pose[:2, 3], 0.6]
        extent = np.linalg.norm(np.ptp(np.vstack([base, scene.object_pose[None, :2, 3]]), axis=0))
        viewer.look_at(target, distance=max(2.4, 1.1 * extent))
        self.seek(0.0)

    def index(self, t: float) -> int:
        return int(np.clip(np.searchsorted(self.episode.time, t), 0, len(self.episode.time) - 1))

    def seek(self, t: float) -> None:
        """Moves the timeline to time t (s) and shows the recorded step nearest after it."""
        self.slider.value = float(np.clip(t, self.slider.min, self.slider.max))
        self._show(t)

    def _show(self, t: float) -> None:
        ep, viewer = self.episode, self.viewer
        i = self.index(t)
        viewer.pose_links({n: p[i] for n, p in self._robot.items()}, {n: p[i] for n, p in self._object.items()})
        plan = ep.plan_at(float(ep.time[i]))
        if plan is not None:
            viewer.show_recorded_plan(plan)
        viewer.show_safety(ep.state[i], obstacles=None if plan is None else plan.obstacles)
        tank = None if ep.tank_energy is None else ep.tank_energy[i]
        viewer.show_panel(ep.time[i], ep.phases[int(ep.phase[i])], tank, ep.opening[i])

    def play(self, speed: float = 1.0, fps: float = 30.0) -> None:
        """Blocks: advances the slider while "play" is ticked, looping at the end."""
        duration = float(self.slider.max)
        while True:
            time.sleep(1.0 / fps)
            if self.playing.value:
                t = self.slider.value + speed / fps
                self.seek(t if t <= duration else 0.0)


def replay(episode: Episode | str | os.PathLike[str], *, host: str = "127.0.0.1", port: int = 8080, speed: float = 1.0) -> None:
    """Serves ``episode`` (an Episode or an ``.npz`` path) with a timeline until interrupted."""
    if not isinstance(episode, Episode):
        episode = Episode.load(episode)
    viewer = Viewer(episode.scene, host=host, port=port)
    timeline = viewer.load_episode(episode)
    print(f"sabre viewer: http://{host}:{viewer.port}  ({episode.scene.object_name}, {episode.duration:.1f} s)")
    try:
        timeline.play(speed=speed)
    except KeyboardInterrupt:
        pass
    finally:
        viewer.close()
