r"""Start meshes of ``transient-mi fit --model mesh`` and the resolution changes between its stages.

Three starts, all wound so that the surface's front faces the relay wall (-z; a diffuse surface reflects on
its front side only):

* :func:`front_surface` (``--start front``, the default): the reconstruction's front surface as a height field.
  The depth map of a reconstruction volume (:func:`recon.filters.depth_map`: per ``[y, x]`` column the depth of
  its maximum) is sampled on a grid of ``cell_m`` (the median of the columns in each cell), and every grid
  square whose four corners are occupied becomes two triangles. An open surface seen from the wall: no part of
  it hides another from the wall, which is what the quadrature's interior derivatives assume;
* :func:`closed_surface` (``--start closed``): a coarse closed surface around the occupied voxels (the surface
  nets isosurface of :func:`recon.surface.isosurface` of the occupancy, at level 0.5), outward normals;
* :func:`load_mesh` (``--start-mesh PATH``): any PLY or OBJ, e.g. a ``recon`` method's ``surface.ply``.

A start must leave the device's view clear: the scene refuses a mesh that hides a wall patch from the detector
or a laser spot from the laser (:class:`~transient_mi.sensors._nlos_setup.NLOSSetup`), and a reconstruction's
surface near the wall can (found on a generated chair captured on 4 x 4 pixels). :func:`clear_view` drops the
start's faces that a line of sight crosses (:func:`device_sight_lines`: detector to the wall's target, to every
patch's corners and centre; laser to every spot); the true shape crosses none of them.

Meshes finer than the fit's resolution are simplified by vertex clustering (:func:`cluster`: vertices snapped to
a grid of ``cell_m``, merged, degenerate faces dropped; Rossignac and Borrel 1993). :func:`subdivide` splits
every triangle in four (edge midpoints): the next, finer stage. :func:`grow_ring` adds a ring of faces around an
open surface's boundary (the carving step's candidates beyond the start: :mod:`~transient_mi.fit.mesh_fit`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from transient_core.errors import UserInputError

__all__ = ["front_surface", "closed_surface", "load_mesh", "cluster", "subdivide", "grow_ring", "orient_to_wall",
           "encloses_volume",
           "device_sight_lines", "crossed_faces", "clear_view"]


def _clean(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drop degenerate and duplicate faces and unreferenced vertices."""
    f = np.asarray(f, dtype=np.int64).reshape(-1, 3)
    ok = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
    f = f[ok]
    if len(f):
        _, keep = np.unique(np.sort(f, axis=1), axis=0, return_index=True)
        f = f[np.sort(keep)]
    used = np.unique(f)
    remap = -np.ones(len(v), dtype=np.int64)
    remap[used] = np.arange(len(used))
    return np.asarray(v, dtype=np.float64)[used], remap[f]


def cluster(v: np.ndarray, f: np.ndarray, cell_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Vertex clustering on a grid of ``cell_m`` (m): each occupied cell's vertices merge at their mean."""
    v = np.asarray(v, dtype=np.float64)
    key = np.floor((v - v.min(axis=0)) / cell_m).astype(np.int64)
    _, lab = np.unique(key, axis=0, return_inverse=True)
    lab = lab.ravel()
    n = lab.max() + 1
    cnt = np.bincount(lab, minlength=n).astype(np.float64)
    c = np.stack([np.bincount(lab, weights=v[:, k], minlength=n) / cnt for k in range(3)], axis=1)
    return _clean(c, lab[np.asarray(f, dtype=np.int64)])


#: A mesh whose area-weighted normals sum to less than this share of its area encloses a volume (a closed surface's
#: sum to zero; a sheet facing the wall's to about its area): :func:`orient_to_wall` winds it outwards.
CLOSED_NORMAL_SHARE = 0.1


def orient_to_wall(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Faces wound consistently: those of a closed mesh outwards (positive signed volume), those of an open one with
    their area-weighted mean normal towards the wall (-z). Closed: watertight, or with area-weighted normals summing
    to under :data:`CLOSED_NORMAL_SHARE` of the area (a surface that encloses a volume but that clustering left with
    non-manifold edges, or a face or two dropped). Such a surface's mean normal is about zero, and the open rule
    wound midpoint-fk's closed surface of the paper mannequin inwards, its front faces turned from the wall, until
    2026-12-07."""
    import trimesh

    f = np.asarray(f, dtype=np.int64)
    m = trimesh.Trimesh(vertices=v, faces=f, process=False)
    trimesh.repair.fix_winding(m)
    f = np.asarray(m.faces, dtype=np.int64)
    if _encloses(m):
        return f if m.volume > 0 else f[:, ::-1].copy()
    return f if float((m.face_normals[:, 2] * m.area_faces).sum()) <= 0 else f[:, ::-1].copy()


def encloses_volume(v: np.ndarray, f: np.ndarray) -> bool:
    """Whether the mesh is closed in :func:`orient_to_wall`'s sense: watertight, or its area-weighted normals sum to
    under :data:`CLOSED_NORMAL_SHARE` of its area (whatever its winding, once made consistent)."""
    import trimesh

    m = trimesh.Trimesh(vertices=np.asarray(v, dtype=np.float64), faces=np.asarray(f, dtype=np.int64), process=False)
    trimesh.repair.fix_winding(m)
    return _encloses(m)


def _encloses(m) -> bool:
    na = m.face_normals * m.area_faces[:, None]
    return bool(m.is_watertight or np.linalg.norm(na.sum(axis=0)) < CLOSED_NORMAL_SHARE * float(m.area))


def front_surface(volume: np.ndarray, grid, cell_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Height-field mesh of a reconstruction volume's front surface (module docstring).

    ``volume [z, y, x]`` on ``grid`` (:class:`recon.grid.VoxelGrid`), thresholded (0 where empty); returns
    ``(vertices [V, 3] m, faces [F, 3])``.
    """
    from recon.filters import depth_map

    d = depth_map(volume, grid)  # [y, x], NaN where empty
    dx = float(abs(grid.x_m[1] - grid.x_m[0])) if len(grid.x_m) > 1 else cell_m
    s = max(1, int(round(cell_m / dx)))
    ny, nx = d.shape
    ys, xs = np.arange(0, ny, s), np.arange(0, nx, s)
    if ys[-1] != ny - 1:
        ys = np.append(ys, ny - 1)
    if xs[-1] != nx - 1:
        xs = np.append(xs, nx - 1)
    h = max(1, s // 2)
    node = np.full((len(ys), len(xs)), np.nan)
    for a, j in enumerate(ys):
        for b, i in enumerate(xs):
            w = d[max(0, j - h): j + h + 1, max(0, i - h): i + h + 1]
            if np.isfinite(w).any():
                node[a, b] = float(np.nanmedian(w))
    idx = -np.ones(node.shape, dtype=np.int64)
    ok = np.isfinite(node)
    if ok.sum() < 3:
        raise UserInputError("the reconstruction holds too few occupied columns to start a mesh from "
                             f"({int(ok.sum())} at {100 * cell_m:.1f} cm)")
    idx[ok] = np.arange(int(ok.sum()))
    X, Y = np.meshgrid(np.asarray(grid.x_m)[xs], np.asarray(grid.y_m)[ys])
    v = np.stack([X[ok], Y[ok], node[ok]], axis=1)
    faces = []
    for a in range(len(ys) - 1):
        for b in range(len(xs) - 1):
            q = idx[a, b], idx[a, b + 1], idx[a + 1, b + 1], idx[a + 1, b]
            if min(q) >= 0:  # (x right, y up: (q0, q2, q1) faces -z)
                faces += [[q[0], q[2], q[1]], [q[0], q[3], q[2]]]
    if not faces:
        raise UserInputError("the reconstruction's occupied columns form no grid square to start a mesh from "
                             f"at {100 * cell_m:.1f} cm; use a smaller --cell-m or --start closed")
    return _clean(v, np.array(faces))


def closed_surface(volume: np.ndarray, grid, cell_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Closed surface around the occupied voxels of ``volume [z, y, x]`` (module docstring), clustered to
    ``cell_m``."""
    from scipy.ndimage import binary_dilation

    from recon.surface import isosurface

    occ = binary_dilation(volume > 0, iterations=1).astype(np.float64)
    if not occ.any():
        raise UserInputError("the reconstruction is empty: nothing to start a mesh from")
    v, f = isosurface(occ, grid, 0.5, closed=True)
    v, f = cluster(v, f, cell_m)
    return v, orient_to_wall(v, f)


def load_mesh(path, cell_m: float) -> tuple[np.ndarray, np.ndarray]:
    """A mesh file (PLY, OBJ, ...), clustered to ``cell_m`` and oriented to the wall."""
    import trimesh

    p = Path(path)
    if not p.is_file():
        raise UserInputError(f"--start-mesh {str(p)!r}: no such file")
    try:
        m = trimesh.load(p, force="mesh", process=True)
    except Exception as e:  # noqa: BLE001 (any parser error is the user's file)
        raise UserInputError(f"--start-mesh {str(p)!r}: not a readable mesh ({type(e).__name__})") from None
    if len(getattr(m, "faces", [])) == 0:
        raise UserInputError(f"--start-mesh {str(p)!r}: holds no triangles")
    v, f = cluster(np.asarray(m.vertices), np.asarray(m.faces), cell_m)
    if len(f) == 0:
        raise UserInputError(f"--start-mesh {str(p)!r}: nothing left at a {100 * cell_m:.1f} cm resolution")
    return v, orient_to_wall(v, f)


def subdivide(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every triangle split in four at its edges' midpoints (the winding kept)."""
    import trimesh

    v2, f2 = trimesh.remesh.subdivide(np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64))
    return np.asarray(v2, dtype=np.float64), np.asarray(f2, dtype=np.int64)


def device_sight_lines(sensor, scene, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """``(origins [N, 3], ends [N, 3])`` (m) of the lines of sight an array capture needs clear: the detector to
    the wall's target, to each patch's corners (pulled in by 1e-4 of a side, as the scene's check) and centre,
    and the laser to each spot."""
    D = np.asarray(sensor.origin, dtype=np.float64)
    fr, pitch = sensor.frame, float(sensor.pixel_pitch_m)
    ends = [np.asarray(sensor.target, dtype=np.float64)[None],
            fr.grid_corners(width, height, pitch, shrink=1e-4, cell=float(sensor.pixel_footprint_m)).reshape(-1, 3),
            fr.grid(width, height, pitch).reshape(-1, 3)]
    origins = [np.broadcast_to(D, (sum(len(e) for e in ends), 3))]
    for em in scene.emitters():
        if hasattr(em, "spot_targets"):
            t = em.spot_targets()
            ends.append(t)
            origins.append(np.broadcast_to(np.asarray(em.origin, dtype=np.float64), t.shape))
    return np.concatenate(origins), np.concatenate(ends)


def ray_triangles(a: np.ndarray, e1: np.ndarray, e2: np.ndarray, o: np.ndarray, d: np.ndarray):
    """Moller-Trumbore intersection of the line ``o + t d`` with triangles ``a, a + e1, a + e2`` (both sides).

    Parameters
    ----------
    a, e1, e2 : ndarray, shape (F, 3)
        Each triangle's first vertex and its two edges from it (m).
    o, d : ndarray, shape (3,)
        The line's origin (m) and direction (any length: ``t`` is in its units).

    Returns
    -------
    inside : ndarray of bool, shape (F,)
        The line crosses the triangle (parallel lines never do).
    t : ndarray, shape (F,)
        The line parameter of the crossing (meaningless where not ``inside``).
    """
    p = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, p)
    ok = np.abs(det) > 1e-15
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = o - a
    u = np.einsum("ij,ij->i", s, p) * inv
    q = np.cross(s, e1)
    w = (q @ d) * inv
    t = np.einsum("ij,ij->i", e2, q) * inv
    return ok & (u >= 0) & (w >= 0) & (u + w <= 1), t


def crossed_faces(v: np.ndarray, f: np.ndarray, origins: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Which faces (bool ``[F]``) a segment ``origins -> ends`` crosses (Moller-Trumbore, both sides)."""
    v = np.asarray(v, dtype=np.float64)
    f = np.asarray(f, dtype=np.int64)
    a, e1, e2 = v[f[:, 0]], v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]
    hit = np.zeros(len(f), dtype=bool)
    for o, d in zip(np.asarray(origins, dtype=np.float64), np.asarray(ends, dtype=np.float64) - origins):
        inside, t = ray_triangles(a, e1, e2, o, d)
        hit |= inside & (t > 0) & (t < 1)
    return hit


def clear_view(v: np.ndarray, f: np.ndarray, origins: np.ndarray, ends: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mesh without the faces that a segment ``origins -> ends`` crosses (Moller-Trumbore, both sides), unused
    vertices dropped; the mesh unchanged (same arrays) when none does."""
    v = np.asarray(v, dtype=np.float64)
    f = np.asarray(f, dtype=np.int64)
    hit = crossed_faces(v, f, origins, ends)
    if not hit.any():
        return v, f
    if hit.all():
        raise UserInputError("the start mesh lies across the device's view of the wall (every face hides a wall "
                             "patch or a laser spot); start from another surface (--start-mesh)")
    return _clean(v, f[~hit])


def grow_ring(v: np.ndarray, f: np.ndarray, width_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The mesh with one ring of faces ``width_m`` wide around its open boundary, wound as its faces.

    Every boundary vertex (of an edge that one face uses) gets a copy moved ``width_m`` along the mean of the
    outward directions of its boundary edges, each in its face's plane and away from the face's third vertex; every
    boundary edge ``(a, b)`` (in its face's order) becomes the quad ``b, a, a', b'``, two triangles that hold the
    edge in the opposite order (a consistent winding). A closed mesh is returned as it is.

    Parameters
    ----------
    v : ndarray, float, shape (V, 3)
        Vertices (m).
    f : ndarray, int, shape (F, 3)
        Faces.
    width_m : float
        How far the ring reaches beyond the boundary (m).

    Returns
    -------
    v, f : ndarray
        The vertices (the ``V`` first unchanged, then one per boundary vertex) and the faces (the ``F`` first
        unchanged, then two per boundary edge).
    """
    v = np.asarray(v, dtype=np.float64)
    f = np.asarray(f, dtype=np.int64).reshape(-1, 3)
    edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    third = np.concatenate([f[:, 2], f[:, 0], f[:, 1]])
    _, inverse, count = np.unique(np.sort(edges, axis=1), axis=0, return_inverse=True, return_counts=True)
    open_edge = count[inverse.ravel()] == 1
    be, bc = edges[open_edge], third[open_edge]
    if not len(be):
        return v, f
    a, b, c = v[be[:, 0]], v[be[:, 1]], v[bc]
    out = np.cross(b - a, np.cross(b - a, c - a))  # (in the face's plane, across the edge)
    out *= -np.sign(np.einsum("ij,ij->i", out, c - 0.5 * (a + b)))[:, None]  # (away from the third vertex)
    out /= np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-300)
    direction = np.zeros_like(v)
    np.add.at(direction, be[:, 0], out)
    np.add.at(direction, be[:, 1], out)
    rim = np.unique(be)
    d = direction[rim] / np.maximum(np.linalg.norm(direction[rim], axis=1, keepdims=True), 1e-300)
    copy = np.full(len(v), -1, dtype=np.int64)
    copy[rim] = len(v) + np.arange(len(rim))
    ap, bp = copy[be[:, 0]], copy[be[:, 1]]
    ring = np.concatenate([np.stack([be[:, 1], be[:, 0], ap], axis=1), np.stack([be[:, 1], ap, bp], axis=1)])
    return np.concatenate([v, v[rim] + float(width_m) * d]), np.concatenate([f, ring])
