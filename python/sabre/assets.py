"""The shipped robot and object URDFs as text and as files on disk, for tools other than sabre.

The built-in assets are compiled into the extension (no data files are installed), so
:meth:`sabre.Scene.load` needs nothing on disk. Other tools (MuJoCo's URDF importer, a viewer,
Pinocchio, ROS) read a file: :func:`urdf_path` writes the text once to a content-named file in a
cache directory and returns its path::

    import sabre
    from sabre import assets

    scene = sabre.Scene.from_urdf(assets.urdf_path("royalpanda"), assets.urdf_path("drawer"))

The cache directory is ``$SABRE_CACHE_DIR/assets``, else ``$XDG_CACHE_HOME/sabre/assets``, else
``~/.cache/sabre/assets``. A file is named by its asset and the hash of its text, so a changed
asset gets a new file and an existing file is never rewritten; deleting the directory only costs
writing the files again.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path

from . import _core
from .errors import InvalidValueError, UnknownAssetError
from .scene import OBJECTS, ROBOTS

__all__ = ["ROBOTS", "OBJECTS", "urdf_text", "urdf_path", "urdf_file", "cache_dir"]


def _kind(name: str) -> str:
    if name in ROBOTS:
        return "robot"
    if name in OBJECTS:
        return "object"
    raise UnknownAssetError(f"unknown asset {name!r}; robots: {', '.join(ROBOTS)}; objects: {', '.join(OBJECTS)}")


def urdf_text(name: str) -> str:
    """The URDF text of the built-in robot or object ``name`` (one of :data:`ROBOTS` or :data:`OBJECTS`),
    exactly as :meth:`sabre.Scene.load` reads it.

    Raises:
        UnknownAssetError: ``name`` is neither a built-in robot nor a built-in object.
    """
    return _core.builtin_urdf(_kind(str(name)), str(name))


def cache_dir() -> Path:
    """The directory :func:`urdf_path` writes to (see the module docstring); not created here."""
    explicit = os.environ.get("SABRE_CACHE_DIR")
    if explicit:
        return Path(explicit) / "assets"
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg) if xdg else Path.home() / ".cache"
    return base / "sabre" / "assets"


def urdf_path(name: str) -> Path:
    """A file holding :func:`urdf_text` of ``name``: ``<cache_dir>/<name>-<hash>.urdf``, written on first
    use (see :func:`urdf_file`). The shipped assets use primitives only, so the file needs nothing next to it.

    Raises:
        UnknownAssetError: ``name`` is not a built-in asset.
        OSError: the cache directory cannot be created or written.
    """
    return urdf_file(urdf_text(name), str(name))


def urdf_file(text: str, stem: str = "urdf") -> Path:
    """A file holding ``text`` (a URDF of your own, e.g. a built-in one edited), named ``<stem>-<hash>.urdf``
    by its content in :func:`cache_dir`, for tools that read files. Written atomically on first use, so
    concurrent processes never see a partial file; an existing file of the same content is reused.

    Raises:
        InvalidValueError: ``stem`` is empty or holds a path separator.
        OSError: the cache directory cannot be created or written.
    """
    if not stem or os.sep in stem or (os.altsep and os.altsep in stem):
        raise InvalidValueError(f"stem must be a plain file name part, got {stem!r}")
    digest = hashlib.sha256(text.encode()).hexdigest()[:16]
    folder = cache_dir()
    path = folder / f"{stem}-{digest}.urdf"
    if path.is_file() and path.read_text() == text:
        return path
    folder.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=f".{stem}-", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path
