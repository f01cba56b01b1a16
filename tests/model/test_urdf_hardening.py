"""URDF input the loader must refuse with a UrdfError instead of crashing or loading nonsense."""

from __future__ import annotations

from pathlib import Path

import pytest

import sabre

ASSETS = Path(__file__).resolve().parents[2] / "assets"
ROBOT = (ASSETS / "robots" / "royalpanda.urdf").read_text()
SHELF = (ASSETS / "objects" / "shelf.urdf").read_text()


def test_deeply_nested_xml_raises_urdf_error_instead_of_overflowing_the_stack():
    deep = '<robot name="r">' + "<a>" * 20000 + "</a>" * 20000 + "</robot>"
    with pytest.raises(sabre.UrdfError, match="nested deeper"):
        sabre.Scene.from_urdf_strings(deep, deep)
    with pytest.raises(sabre.UrdfError, match="nested deeper"):
        sabre.Scene.from_urdf_strings(ROBOT, deep)


@pytest.mark.parametrize(
    "old, new, message",
    [
        ('<origin xyz="0.231338 0 0.382559"', '<origin xyz="0.231338 inf 0.382559"', "inertial origin"),
        ('ixx="3.29312"', 'ixx="-3.29312"', "non-physical inertia"),
        ('ixx="3.29312"', 'ixx="30"', "non-physical inertia"),
        ('damping="2"', 'damping="inf"', "damping inf"),
    ],
    ids=["inf inertial origin", "negative inertia", "inertia violating the triangle inequality", "infinite damping"],
)
def test_non_physical_object_values_are_refused_at_load(old, new, message):
    assert old in SHELF
    with pytest.raises(sabre.UrdfError, match=message):
        sabre.Scene.from_urdf_strings(ROBOT, SHELF.replace(old, new, 1))


def test_a_negative_effort_limit_is_refused_not_read_as_unlimited():
    old = 'effort="87"'
    assert old in ROBOT
    with pytest.raises(sabre.UrdfError, match="effort limit -87"):
        sabre.Scene.from_urdf_strings(ROBOT.replace(old, 'effort="-87"', 1), SHELF)
