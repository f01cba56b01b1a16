"""Convex pieces written as mesh files the way convex decompositions ship them: binary STL (one piece a
file) and OBJ (one object per piece), with outward-facing triangles; written atomically, so that
processes sharing a directory never read half a file."""

from __future__ import annotations

import os
import struct
from collections.abc import Sequence
from pathlib import Path

import numpy as np

Piece = tuple[np.ndarray, np.ndarray]  # (V, 3) vertices and (F, 3) triangles of a convex solid

# the 12 triangles of a box whose corner k has x, y, z at the upper end where bits 2, 1, 0 of k are set
_BOX_FACES = np.array(
    [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1]]
    + [[2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]
)


def _outward(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The triangles of a convex solid, each turned so that its normal points away from the centroid."""
    centre = vertices.mean(axis=0)
    a, b, c = vertices[faces[:, 0]], vertices[faces[:, 1]], vertices[faces[:, 2]]
    inward = np.einsum("ij,ij->i", np.cross(b - a, c - a), a - centre) < 0.0
    out = faces.copy()
    out[inward] = out[inward][:, [0, 2, 1]]
    return out


def box(centre: Sequence[float] | np.ndarray, size: Sequence[float] | np.ndarray) -> Piece:
    """An axis-aligned box of ``size`` (m) centred at ``centre`` (m)."""
    signs = np.array([[sx, sy, sz] for sx in (-0.5, 0.5) for sy in (-0.5, 0.5) for sz in (-0.5, 0.5)])
    vertices = np.asarray(centre, dtype=float) + signs * np.asarray(size, dtype=float)
    return vertices, _outward(vertices, _BOX_FACES)


def prism(centre: Sequence[float] | np.ndarray, axis: int, radius: float, length: float, sides: int = 16) -> Piece:
    """A regular prism of ``sides`` sides around coordinate axis ``axis`` (0, 1, 2): a round bar as
    meshes write one, its corners on the circle of ``radius`` (m), ``length`` (m) long."""
    angles = 2.0 * np.pi * np.arange(sides) / sides
    ring = np.zeros((sides, 3))
    across = [k for k in range(3) if k != axis]
    ring[:, across[0]], ring[:, across[1]] = radius * np.cos(angles), radius * np.sin(angles)
    ends = [np.eye(3)[axis] * h for h in (-length / 2, length / 2)]
    vertices = np.asarray(centre, dtype=float) + np.concatenate([ring + ends[0], ring + ends[1]])
    k = np.arange(sides)
    nxt = (k + 1) % sides
    sides_faces = np.concatenate([np.stack([k, nxt, nxt + sides], 1), np.stack([k, nxt + sides, k + sides], 1)])
    caps = np.concatenate(
        [
            np.stack([np.zeros(sides - 2, int), k[1:-1], k[2:]], 1),
            np.stack([np.full(sides - 2, sides), k[2:] + sides, k[1:-1] + sides], 1),
        ]
    )
    return vertices, _outward(vertices, np.concatenate([sides_faces, caps]))


def _atomic_write(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(f"{path.name}.{os.getpid()}.part")
    partial.write_bytes(data)
    os.replace(partial, path)


def write_text(path: Path, text: str) -> None:
    """A text file (a URDF, a package.xml), written atomically."""
    _atomic_write(path, text.encode())


def write_stl(path: Path, piece: Piece) -> None:
    """One convex piece as a binary STL file."""
    vertices, faces = piece
    out = bytearray(b"convex piece".ljust(80, b" ") + struct.pack("<I", len(faces)))
    for face in faces:
        a, b, c = vertices[face]
        normal = np.cross(b - a, c - a)
        normal = normal / max(float(np.linalg.norm(normal)), 1e-300)
        out += struct.pack("<12fH", *normal, *a, *b, *c, 0)
    _atomic_write(path, bytes(out))


def write_obj(path: Path, pieces: Sequence[tuple[str, Piece]]) -> None:
    """Convex pieces as one OBJ file, one object (``o``) per piece, as convex decompositions are stored."""
    lines = ["# convex pieces, one object each"]
    offset = 1
    for name, (vertices, faces) in pieces:
        lines.append(f"o {name}")
        lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in vertices]
        lines += [f"f {a + offset} {b + offset} {c + offset}" for a, b, c in faces]
        offset += len(vertices)
    _atomic_write(path, ("\n".join(lines) + "\n").encode())
