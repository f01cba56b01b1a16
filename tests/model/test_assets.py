"""sabre.assets: the built-in URDFs compiled into the extension as text and as content-named files, and a scene
built from those files is the built-in scene."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import sabre
from sabre import assets
from sabre.errors import InvalidValueError, UnknownAssetError

REPOSITORY_ASSETS = Path(__file__).resolve().parents[2] / "assets"


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SABRE_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "cache" / "assets"


def test_the_texts_are_the_repositorys_files():
    assert assets.ROBOTS == sabre.ROBOTS and assets.OBJECTS == sabre.OBJECTS
    for name in assets.ROBOTS:
        assert assets.urdf_text(name) == (REPOSITORY_ASSETS / "robots" / f"{name}.urdf").read_text()
    for name in assets.OBJECTS:
        assert assets.urdf_text(name) == (REPOSITORY_ASSETS / "objects" / f"{name}.urdf").read_text()


def test_an_unknown_name_lists_the_assets():
    with pytest.raises(UnknownAssetError, match=r"royalpanda.*shelf"):
        assets.urdf_text("fridge")
    with pytest.raises(UnknownAssetError):
        assets.urdf_path("fridge")


def test_files_are_named_by_their_content_and_written_once(cache):
    path = assets.urdf_path("drawer")
    assert path.parent == cache and path.name.startswith("drawer-") and path.suffix == ".urdf"
    assert path.read_text() == assets.urdf_text("drawer")
    written = path.stat().st_mtime_ns
    assert assets.urdf_path("drawer") == path and path.stat().st_mtime_ns == written
    # another text gets another file; the same text under the same stem the same one
    edited = assets.urdf_file(assets.urdf_text("drawer").replace('damping="2"', 'damping="3"'), "drawer")
    assert edited != path and edited.parent == cache
    assert assets.urdf_file(edited.read_text(), "drawer") == edited
    # a damaged file is written again
    path.write_text("truncated")
    assert assets.urdf_path("drawer").read_text() == assets.urdf_text("drawer")
    assert not list(cache.glob("*.tmp"))
    with pytest.raises(InvalidValueError):
        assets.urdf_file("<robot/>", "a/b")


def test_the_cache_directory_falls_back_to_xdg_then_home(tmp_path, monkeypatch):
    monkeypatch.delenv("SABRE_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert assets.cache_dir() == tmp_path / "xdg" / "sabre" / "assets"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert assets.cache_dir() == tmp_path / "home" / ".cache" / "sabre" / "assets"


@pytest.mark.parametrize("obj", sabre.OBJECTS)
def test_a_scene_from_the_files_is_the_built_in_scene(obj, cache, rng):
    """Scene.from_urdf on the written files, with the built-in placement, has Scene.load's sizes, names,
    limits, object dynamics and forward kinematics of every frame."""
    built_in = sabre.Scene.load("royalpanda", obj)
    pose = built_in.object_pose[:3, 3].tolist() + [0.0, 0.0, 0.0]
    assert np.allclose(built_in.object_pose[:3, :3], np.eye(3))
    scene = sabre.Scene.from_urdf(assets.urdf_path("royalpanda"), assets.urdf_path(obj), pose)
    for attribute in ("nq", "no", "nx", "nu", "robot_name", "object_name", "joint_names", "frame_names"):
        assert getattr(scene, attribute) == getattr(built_in, attribute), attribute
    assert scene.object_frame_names == built_in.object_frame_names
    for attribute in (
        "q_lower",
        "q_upper",
        "dq_limit",
        "effort_limit",
        "o_lower",
        "o_upper",
        "object_damping",
        "object_friction",
    ):
        np.testing.assert_array_equal(getattr(scene, attribute), getattr(built_in, attribute), err_msg=attribute)
    for _ in range(3):
        q = rng.uniform(np.maximum(scene.q_lower, -2.0), np.minimum(scene.q_upper, 2.0))
        o = rng.uniform(scene.o_lower, scene.o_upper)
        for frame in scene.frame_names:
            np.testing.assert_array_equal(scene.fk(q, frame), built_in.fk(q, frame))
        for frame in scene.object_frame_names:
            np.testing.assert_array_equal(scene.object_fk(o, frame), built_in.object_fk(o, frame))
