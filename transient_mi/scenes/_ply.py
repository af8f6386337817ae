"""Binary PLY writer for triangle meshes, atomic and byte-for-byte deterministic.

The file holds only what Mitsuba's ``<shape type="ply">`` needs: float32
vertex positions and int32 triangle indices (Mitsuba computes smooth vertex
normals itself unless the shape sets ``face_normals``). It is written under a
temporary name in the target folder and renamed into place, so a reader never
sees half a file and a failed write leaves nothing behind.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from transient_core.atomic import atomic_file
from transient_core.errors import UserInputError


def ply_bytes(vertices: np.ndarray, faces: np.ndarray, face_values: dict | None = None) -> bytes:
    """Binary little-endian PLY of a triangle mesh.

    Parameters
    ----------
    vertices : ndarray, shape (V, 3)
        Positions in metres (stored as float32).
    faces : ndarray, shape (F, 3)
        Vertex indices of each triangle, counter-clockwise seen from outside.
    face_values : dict of str to ndarray, shape (F,), optional
        Float32 face properties after the indices. Mitsuba's PLY loader reads a property ``<name>_0`` as the
        one-channel face attribute ``face_<name>`` (which a ``mesh_attribute`` texture reads) and ignores a name
        without that postfix.
    """
    v = np.ascontiguousarray(vertices, dtype="<f4")
    f = np.asarray(faces, dtype="<i4")
    extra = dict(face_values or {})
    header = (
        "ply\n"
        "format binary_little_endian 1.0\n"
        "comment transient-mi procedural mesh\n"
        f"element vertex {len(v)}\n"
        "property float x\nproperty float y\nproperty float z\n"
        f"element face {len(f)}\n"
        "property list uchar int vertex_indices\n"
        + "".join(f"property float {name}\n" for name in extra)
        + "end_header\n"
    ).encode("ascii")
    rec = np.empty(len(f), dtype=[("n", "u1"), ("idx", "<i4", (3,))] + [(name, "<f4") for name in extra])
    rec["n"] = 3
    rec["idx"] = f
    for name, values in extra.items():
        rec[name] = np.asarray(values, dtype=np.float64).ravel()
    return header + v.tobytes() + rec.tobytes()


def write_bytes_atomic(path: str | os.PathLike, data: bytes, what: str = "output") -> Path:
    """Write ``data`` to ``path`` via a temporary file in the same folder and a rename.

    Raises
    ------
    UserInputError
        When the folder does not exist, ``path`` is a folder, or the file
        cannot be written (permissions, full disk). Nothing is left behind.
    """
    p = Path(path)
    parent = p.parent if str(p.parent) else Path(".")
    if p.is_dir():
        raise UserInputError(f"{what} {str(p)!r} is a directory; give a file name such as {str(p / 'mannequin.ply')!r}")
    if not parent.is_dir():
        raise UserInputError(f"{what} {str(p)!r}: folder {str(parent)!r} does not exist")
    try:
        with atomic_file(p, fsync=True) as tmp:
            tmp.write_bytes(data)
    except OSError as e:
        raise UserInputError(f"{what} {str(p)!r} cannot be written: {e.strerror or e}") from None
    return p


def write_ply(path: str | os.PathLike, vertices: np.ndarray, faces: np.ndarray, face_values: dict | None = None) -> Path:
    """Write a triangle mesh as binary PLY, atomically (``face_values``: :func:`ply_bytes`). Returns the path."""
    return write_bytes_atomic(path, ply_bytes(vertices, faces, face_values), what="output mesh")
