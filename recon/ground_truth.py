"""Ground truth from a mesh, as seen from the relay wall: depth map and silhouette.

The relay wall is the plane z = 0 and the hidden space is z > 0 (the world
frame of transient-mi). Looking from the wall into the hidden space along +z,
every wall coordinate (x, y) sees the surface point with the smallest z on the
line through (x, y) parallel to the z axis. These functions compute that
orthographic depth map and its silhouette on a grid, by exact rasterisation of
the mesh triangles (barycentric point-in-triangle tests and linear
interpolation of z), so they need no ray-casting library.

numpy only: no Mitsuba, no trimesh import (any object with ``vertices`` and
``faces`` arrays works, e.g. a :class:`trimesh.Trimesh`, or a
``(vertices, faces)`` tuple).

Axis order of every returned map is ``[y, x]``: ``depth[i, j]`` belongs to
``(x_m[j], y_m[i])``, matching the ``[pixel_y, pixel_x]`` order of captures.
"""

from __future__ import annotations

import numpy as np

from transient_core.errors import UserInputError

__all__ = ["ground_truth_depth_map", "ground_truth_silhouette"]


def _mesh_arrays(mesh) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices [V, 3] float64, faces [F, 3] int64)`` of a mesh-like object."""
    if isinstance(mesh, (tuple, list)) and len(mesh) == 2:
        vertices, faces = mesh
    elif hasattr(mesh, "vertices") and hasattr(mesh, "faces"):
        vertices, faces = mesh.vertices, mesh.faces
    else:
        raise UserInputError(
            f"mesh={type(mesh).__name__!s}: expected an object with 'vertices' and 'faces' "
            "(e.g. a trimesh.Trimesh) or a (vertices [V, 3], faces [F, 3]) tuple"
        )
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or not np.all(np.isfinite(v)):
        raise UserInputError(f"mesh vertices: expected finite [V, 3] coordinates, got shape {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise UserInputError(f"mesh faces: expected integer [F, 3] vertex indices, got shape {f.shape}, dtype {f.dtype}")
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise UserInputError(f"mesh faces: vertex indices must lie in [0, {len(v) - 1}], got [{f.min()}, {f.max()}]")
    return v, f.astype(np.int64, copy=False)


def _grid_axis(name: str, values) -> np.ndarray:
    a = np.asarray(values, dtype=np.float64)
    if a.ndim != 1 or a.size == 0:
        raise UserInputError(f"{name}: expected a non-empty 1-D array of coordinates in metres, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise UserInputError(f"{name}: coordinates must be finite")
    if a.size > 1 and not np.all(np.diff(a) > 0):
        raise UserInputError(f"{name}: coordinates must be strictly increasing")
    return a


def ground_truth_depth_map(mesh, x_m, y_m) -> np.ndarray:
    """Depth (z, metres) of the nearest surface seen from the wall, on a grid.

    Parameters
    ----------
    mesh : trimesh.Trimesh or (vertices, faces)
        Triangle mesh in world coordinates (metres). It need not be
        watertight; every triangle counts.
    x_m, y_m : array_like, shape (nx,) and (ny,)
        Strictly increasing grid coordinates on the wall, metres.

    Returns
    -------
    depth_m : ndarray, float64, shape (ny, nx), axes ``[y, x]``
        ``depth_m[i, j]`` is the smallest z at which the line
        ``(x_m[j], y_m[i], z)`` meets the mesh, NaN where it misses the mesh.
        Points on a triangle's edge count as hits, so silhouettes are closed.

    Notes
    -----
    Exact for the triangle mesh: z is interpolated linearly on the triangle
    hit. Triangles seen edge-on (zero projected area) are skipped; on a
    closed mesh their neighbours cover the same points. Cost grows with the
    number of grid points inside each triangle's bounding box.
    """
    v, f = _mesh_arrays(mesh)
    x = _grid_axis("x_m", x_m)
    y = _grid_axis("y_m", y_m)
    depth = np.full((y.size, x.size), np.inf)
    if f.size == 0:
        return np.full_like(depth, np.nan)

    tri = v[f]  # [F, 3 corners, xyz]
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    e1 = b[:, :2] - a[:, :2]
    e2 = c[:, :2] - a[:, :2]
    det = e1[:, 0] * e2[:, 1] - e2[:, 0] * e1[:, 1]
    scale = np.ptp(v[:, :2], axis=0).max() if len(v) else 1.0
    keep = np.abs(det) > 1e-14 * max(scale, 1e-300) ** 2
    lo = tri[:, :, :2].min(axis=1)
    hi = tri[:, :, :2].max(axis=1)
    # Grid index ranges covered by each triangle's bounding box (inclusive).
    ix0 = np.searchsorted(x, lo[:, 0], side="left")
    ix1 = np.searchsorted(x, hi[:, 0], side="right")
    iy0 = np.searchsorted(y, lo[:, 1], side="left")
    iy1 = np.searchsorted(y, hi[:, 1], side="right")
    keep &= (ix1 > ix0) & (iy1 > iy0)
    tol = 1e-12
    for t in np.flatnonzero(keep):
        xs = x[ix0[t]:ix1[t]]
        ys = y[iy0[t]:iy1[t]]
        px = xs[None, :] - a[t, 0]
        py = ys[:, None] - a[t, 1]
        inv = 1.0 / det[t]
        lb = (px * e2[t, 1] - e2[t, 0] * py) * inv
        lc = (e1[t, 0] * py - px * e1[t, 1]) * inv
        la = 1.0 - lb - lc
        inside = (la >= -tol) & (lb >= -tol) & (lc >= -tol)
        if not inside.any():
            continue
        z = la * a[t, 2] + lb * b[t, 2] + lc * c[t, 2]
        sub = depth[iy0[t]:iy1[t], ix0[t]:ix1[t]]
        np.minimum(sub, np.where(inside, z, np.inf), out=sub)
    depth[np.isinf(depth)] = np.nan
    return depth


def ground_truth_silhouette(mesh, x_m, y_m) -> np.ndarray:
    """Silhouette of the mesh seen from the wall along +z, on a grid.

    Parameters
    ----------
    mesh : trimesh.Trimesh or (vertices, faces)
        Triangle mesh in world coordinates (metres).
    x_m, y_m : array_like, shape (nx,) and (ny,)
        Strictly increasing grid coordinates on the wall, metres.

    Returns
    -------
    silhouette : ndarray, bool, shape (ny, nx), axes ``[y, x]``
        True where the line ``(x_m[j], y_m[i], z)`` meets the mesh
        (orthographic projection onto the wall plane).
    """
    return np.isfinite(ground_truth_depth_map(mesh, x_m, y_m))
