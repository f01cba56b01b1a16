"""What the tasks derive from a scene (handle frames, the core's task logic) is made once per scene and dropped with the
scene; a changed setting makes it again."""

from __future__ import annotations

import gc
import pickle
import weakref

import sabre
from sabre.tasks._per_scene import per_scene


def test_a_value_is_made_once_per_scene_and_key() -> None:
    first, second = sabre.Scene.load(obj="shelf"), sabre.Scene.load(obj="shelf")
    made: list[tuple[str, str]] = []

    def make(name: str):
        def build(scene: sabre.Scene) -> list[str]:
            made.append((scene.object_name, name))
            return [name]

        return build

    a = per_scene(first, ("test", "a"), make("a"))
    assert per_scene(first, ("test", "a"), make("again")) is a
    b = per_scene(first, ("test", "b"), make("b"))
    c = per_scene(second, ("test", "a"), make("a"))
    assert a == c == ["a"] and b == ["b"] and a is not c
    assert made == [("shelf", "a"), ("shelf", "b"), ("shelf", "a")]


def test_a_scene_is_freed_after_an_open_object_task_used_it() -> None:
    scene = sabre.Scene.load(obj="dishwasher")
    task = sabre.tasks.OpenObject(handle="handle_frame")
    task.check(scene)
    x = scene.default_state()
    scene.split_state(x).o[0] = 0.5 * float(scene.o_upper[0])
    task.self_opening(scene, x)  # builds and keeps the probe rollout model for this scene
    task.guides(scene, x, "open", 10, 0.05)
    alive = weakref.ref(scene)
    del scene
    gc.collect()
    assert alive() is None


def test_a_changed_setting_takes_effect_and_a_used_task_pickles() -> None:
    scene = sabre.Scene.load(obj="drawer")
    task = sabre.tasks.OpenObject()
    x = scene.default_state()
    scene.split_state(x).o[0] = 0.8 * task.target_opening(scene)
    assert not task.success(scene, x)  # 0.8 of the target, short of the default 0.9
    task.open = sabre.tasks.OpenConfig(success_fraction=0.75)
    assert task.success(scene, x)
    copy = pickle.loads(pickle.dumps(task))
    assert copy.open == task.open and copy.success(scene, x)
    copy.opening = float(scene.o_upper[0])  # a copy's settings are its own: 0.6 of the range is short of 0.75 of it
    assert not copy.success(scene, x) and task.success(scene, x)
