"""The one cache of the tasks package: values derived from a scene, computed once per scene and key, dropped with the scene."""

from __future__ import annotations

import weakref
from collections.abc import Callable, Hashable
from typing import Any, TypeVar, cast

from ..scene import Scene

__all__ = ["per_scene"]

T = TypeVar("T")

_ENTRIES: weakref.WeakKeyDictionary[Scene, dict[Hashable, Any]] = weakref.WeakKeyDictionary()


def per_scene(scene: Scene, key: Hashable, make: Callable[[Scene], T]) -> T:
    """The value ``make(scene)`` for ``scene`` and ``key``, made on the first call and kept while the scene lives.

    ``make`` is handed a weak proxy of the scene: a value that keeps its scene (a rollout model does)
    would otherwise keep its own cache entry, and the scene with it, alive forever. The key names
    what the value is and everything besides the scene it depends on, e.g. ``("handle", name)``.
    """
    entries = _ENTRIES.setdefault(scene, {})
    if key not in entries:
        entries[key] = make(cast(Scene, weakref.proxy(scene)))
    return cast(T, entries[key])
