"""Moving object links without an inertial (or with part of one) get mass, centre of mass and inertia
from their collision geometry at the scene's density: closed forms for a box and a cylinder mesh,
a warning naming each link, the scene's report, and the plant and the rollout model moving the
object exactly as if the file had declared those values."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

import sabre
from sabre.experiments import mesh_files

ROBOT = Path(__file__).resolve().parents[2] / "assets" / "robots" / "royalpanda.urdf"


def drawer(tray: str, inertial: str = "", extra: str = "") -> str:
    """A drawer (prismatic, damped, no friction) whose moving link carries ``tray`` collisions."""
    return f"""<robot name="drawer">
  <link name="body"><collision><origin xyz="0.3 0 0.2"/><geometry><box size="0.5 0.5 0.4"/></geometry></collision></link>
  <link name="tray">{inertial}{tray}</link>
  <joint name="slide" type="prismatic"><parent link="body"/><child link="tray"/><origin xyz="0 0 0.7"/>
    <axis xyz="-1 0 0"/><limit lower="0" upper="0.4" effort="10" velocity="1"/><dynamics damping="3"/></joint>
  {extra}
</robot>"""


def mesh(name: str) -> str:
    return f'<collision><geometry><mesh filename="{name}"/></geometry></collision>'


def load(directory: Path, urdf: str, **options) -> sabre.Scene:
    path = directory / "drawer.urdf"
    path.write_text(urdf)
    return sabre.Scene.from_urdf(ROBOT, path, **options)


def test_a_box_mesh_has_the_box_mass_and_inertia(tmp_path):
    a, b, c, centre = 0.3, 0.4, 0.02, (0.15, 0.01, -0.02)
    mesh_files.write_stl(tmp_path / "tray.stl", mesh_files.box(centre, (a, b, c)))
    with pytest.warns(sabre.AssumedInertialWarning, match="'tray'"):
        scene = load(tmp_path, drawer(mesh("tray.stl")))
    (tray,) = scene.assumed_inertials
    m = 600.0 * a * b * c
    # STL stores single-precision floats: the box's corners are good to a few parts in 10⁸
    assert tray.link == "tray" and tray.mass == pytest.approx(m, rel=1e-6)
    np.testing.assert_allclose(tray.com, centre, atol=1e-7)
    np.testing.assert_allclose(
        tray.inertia, np.diag([b * b + c * c, a * a + c * c, a * a + b * b]) * m / 12, rtol=1e-6, atol=1e-12
    )
    assert tray.source == "collision geometry at 600 kg/m³" and scene.density == 600.0


def test_a_cylinder_mesh_has_the_cylinder_mass_and_inertia(tmp_path):
    r, h, n = 0.05, 0.3, 256
    mesh_files.write_obj(tmp_path / "rod.obj", [("rod", mesh_files.prism((0.0, 0.0, 0.0), 2, r, h, sides=n))])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sabre.AssumedInertialWarning)
        (rod,) = load(tmp_path, drawer(mesh("rod.obj")), density=1000.0).assumed_inertials
    # the regular n-sided prism exactly: area ½ n r² sin(2π/n), polar moment per unit mass (r²/6)(1 + 2 cos²(π/n))
    area = 0.5 * n * r * r * np.sin(2 * np.pi / n)
    m = 1000.0 * area * h
    polar = m * r * r / 6 * (1 + 2 * np.cos(np.pi / n) ** 2)
    # (OBJ vertices are read in single precision)
    assert rod.mass == pytest.approx(m, rel=1e-6)
    np.testing.assert_allclose(rod.inertia, np.diag([polar / 2 + m * h * h / 12] * 2 + [polar]), rtol=1e-6, atol=1e-12)
    # and the cylinder it stands for, within the polygon's 0.01 % shortfall of the circle
    cylinder = 1000.0 * np.pi * r * r * h
    assert rod.mass == pytest.approx(cylinder, rel=2e-4)
    across = cylinder * (3 * r * r + h * h) / 12
    np.testing.assert_allclose(rod.inertia, np.diag([across, across, cylinder * r * r / 2]), rtol=5e-4, atol=1e-15)


def test_a_declared_mass_is_kept_and_the_density_scales_the_rest(tmp_path):
    mesh_files.write_stl(tmp_path / "tray.stl", mesh_files.box((0.0, 0.0, 0.0), (0.3, 0.4, 0.02)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sabre.AssumedInertialWarning)
        # a mass without an inertia tensor: the file reads, the mass stays, the inertia is the box's at that mass
        (partial,) = load(tmp_path, drawer(mesh("tray.stl"), '<inertial><mass value="2.5"/></inertial>')).assumed_inertials
        light, heavy = (load(tmp_path, drawer(mesh("tray.stl")), density=d).assumed_inertials[0] for d in (300.0, 900.0))
    assert partial.mass == 2.5 and "declared mass" in partial.source
    np.testing.assert_allclose(
        partial.inertia, np.diag([0.4**2 + 0.02**2, 0.3**2 + 0.02**2, 0.3**2 + 0.4**2]) * 2.5 / 12, rtol=1e-6, atol=1e-12
    )
    assert heavy.mass == pytest.approx(3 * light.mass) and "900 kg/m³" in heavy.source
    np.testing.assert_allclose(heavy.inertia, 3 * light.inertia, rtol=1e-12)
    with pytest.raises(sabre.InvalidValueError, match="density"):
        load(tmp_path, drawer(mesh("tray.stl")), density=0.0)


def test_complete_fixed_and_held_links_are_left_alone(tmp_path):
    mesh_files.write_stl(tmp_path / "tray.stl", mesh_files.box((0.0, 0.0, 0.0), (0.3, 0.4, 0.02)))
    full = '<inertial><mass value="1"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>'
    lid = """<link name="lid"><collision><geometry><box size="0.3 0.4 0.01"/></geometry></collision></link>
  <joint name="lid_hinge" type="revolute"><parent link="body"/><child link="lid"/><origin xyz="0.3 0 0.41"/>
    <axis xyz="0 1 0"/><limit lower="0" upper="1" effort="1" velocity="1"/></joint>"""
    with warnings.catch_warnings():
        warnings.simplefilter("error", sabre.AssumedInertialWarning)
        declared = load(tmp_path, drawer(mesh("tray.stl"), full))  # the body has none, but it does not move
        held = load(tmp_path, drawer(mesh("tray.stl"), full, extra=lid), joint="slide")  # the lid is held shut
    assert declared.assumed_inertials == () and held.assumed_inertials == ()
    with pytest.warns(sabre.AssumedInertialWarning, match="'lid'"):
        both = load(tmp_path, drawer(mesh("tray.stl"), full, extra=lid))
    assert [a.link for a in both.assumed_inertials] == ["lid"]


def test_the_plant_and_the_rollout_model_move_the_object_as_with_the_values_declared(tmp_path):
    mesh_files.write_stl(tmp_path / "tray.stl", mesh_files.box((0.15, 0.0, 0.0), (0.3, 0.4, 0.02)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sabre.AssumedInertialWarning)
        assumed = load(tmp_path, drawer(mesh("tray.stl")))
    (tray,) = assumed.assumed_inertials
    i = tray.inertia

    def declared_as(mass: float) -> sabre.Scene:
        moments = {"ixx": i[0, 0], "ixy": i[0, 1], "ixz": i[0, 2], "iyy": i[1, 1], "iyz": i[1, 2], "izz": i[2, 2]}
        inertia = " ".join(f'{name}="{float(value)!r}"' for name, value in moments.items())
        com = " ".join(repr(float(v)) for v in tray.com)
        inertial = f'<inertial><origin xyz="{com}"/><mass value="{mass!r}"/><inertia {inertia}/></inertial>'
        return load(tmp_path, drawer(mesh("tray.stl"), inertial))

    def opening(scene: sabre.Scene) -> tuple[np.ndarray, np.ndarray]:
        x0 = scene.default_state()
        scene.split_state(x0).o_dot[:] = 0.3  # the drawer slides out and the damping brakes it
        plant = sabre.Plant(scene)
        plant.reset(x0)
        gravity = scene.mass_matrix(x0[: scene.nq])[1]
        slid = []
        for _ in range(300):
            plant.step(gravity)
            slid.append(scene.split_state(plant.state).o[0])
        rolled = sabre.RolloutModel(scene).rollout(x0, np.zeros((1, 40, scene.nu)), threads=1).states[0]
        return np.array(slid), scene.split_state(rolled).o[:, 0]

    reference, same, other = opening(assumed), opening(declared_as(tray.mass)), opening(declared_as(2 * tray.mass))
    for k in range(2):
        np.testing.assert_allclose(reference[k], same[k], atol=1e-12)
        assert np.max(np.abs(reference[k] - other[k])) > 1e-3  # the mass shows in how far it slides
