"""The hidden geometry of an NLOS scene as one triangle mesh (ground truth for ``recon --ground-truth``).

Loads the scene with Mitsuba (``-D`` values applied) and collects every shape
that reaches into the hidden space z > 0 (the relay wall lies in z = 0 and is
left out): triangle meshes as they are (PLY/OBJ files, the procedural
``mannequin``, and Mitsuba's ``rectangle``), ``disk`` shapes as 64-gons and
``sphere`` shapes as icospheres, all in the world frame, metres. Windows
(shapes with a purely delta-transmissive or ``null`` BSDF, e.g. a glass pane
between the device and the wall, see docs/glass.md) are not hidden geometry
and are left out too.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from transient_core.errors import UserInputError

#: Shapes whose bounding box ends at or below this depth belong to the wall plane, not the hidden scene (m).
WALL_PLANE_TOL_M = 1e-6
DISK_SEGMENTS = 64


def _matrix(shape) -> np.ndarray:
    import mitsuba as mi

    m = np.array(mi.traverse(shape)["to_world"].matrix, dtype=np.float64)
    return m.reshape(4, 4) if m.size == 16 else m[..., 0] if m.shape[-1] == 1 else m.reshape(-1, 4, 4)[0]


def _apply(m: np.ndarray, local: np.ndarray) -> np.ndarray:
    return local @ m[:3, :3].T + m[:3, 3]


def shape_triangles(shape) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices [V, 3], faces [F, 3])`` of one Mitsuba shape in the world frame."""
    import drjit as dr
    import mitsuba as mi

    if shape.is_mesh():
        nv, nf = shape.vertex_count(), shape.face_count()
        v = np.array(shape.vertex_position(dr.arange(mi.UInt32, nv)), dtype=np.float64).reshape(3, nv).T
        f = np.array(shape.face_indices(dr.arange(mi.UInt32, nf)), dtype=np.int64).reshape(3, nf).T
        return v, f
    kind = str(shape).split("[", 1)[0].strip()
    if kind == "Disk":
        a = 2 * np.pi * np.arange(DISK_SEGMENTS) / DISK_SEGMENTS
        local = np.concatenate([[[0.0, 0.0, 0.0]], np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], 1)])
        k = np.arange(DISK_SEGMENTS)
        faces = np.stack([np.zeros_like(k), 1 + k, 1 + (k + 1) % DISK_SEGMENTS], 1)
        return _apply(_matrix(shape), local), faces
    if kind == "Rectangle":
        local = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=np.float64)
        return _apply(_matrix(shape), local), np.array([[0, 1, 2], [0, 2, 3]])
    if kind == "Sphere":
        import trimesh

        bb = shape.bbox()
        lo, hi = np.array(bb.min, dtype=np.float64), np.array(bb.max, dtype=np.float64)
        s = trimesh.creation.icosphere(subdivisions=3, radius=float((hi - lo)[0]) / 2)
        return np.asarray(s.vertices) + (lo + hi) / 2, np.asarray(s.faces)
    raise UserInputError(f"shape {shape.id()!r} ({kind}): cannot be turned into triangles for the ground truth; "
                         "give the hidden geometry as a mesh file (PLY/OBJ) in the scene")


def hidden_mesh(scene_file, defines: dict | None = None) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """``(vertices [V, 3], faces [F, 3], shape ids)`` of every shape of the scene in z > 0 (metres)."""
    from .integrators._device_legs import is_window_bsdf
    from .scene_io import load_scene

    scene = load_scene(Path(scene_file), defines)
    sensors = scene.sensors()
    if not any(hasattr(s, "capture_layout") for s in sensors):
        kinds = ", ".join(sorted({type(s).__name__ for s in sensors})) or "no sensor"
        raise UserInputError(f"{scene_file}: not an NLOS scene (sensor: {kinds}); scene-mesh needs a spad_array "
                             "sensor looking at a relay wall in z = 0, whose hidden geometry it writes")
    verts, faces, ids, n = [], [], [], 0
    for shape in scene.shapes():
        if float(shape.bbox().max[2]) <= WALL_PLANE_TOL_M:
            continue  # the relay wall (z = 0) and anything behind it
        if is_window_bsdf(shape.bsdf()):
            continue  # a window the device looks through, not part of the hidden scene
        v, f = shape_triangles(shape)
        verts.append(v)
        faces.append(f + n)
        ids.append(shape.id() or f"<unnamed {type(shape).__name__} {len(ids)}>")
        n += len(v)
    if not verts:
        raise UserInputError(f"{scene_file}: no shape in the hidden space z > 0 (nothing to write)")
    return np.concatenate(verts), np.concatenate(faces), ids
