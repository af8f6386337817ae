"""3-D output of a reconstruction: an isosurface mesh, depth and normal maps, PLY export.

Isosurface: *surface nets* (Gibson 1998), the dual of marching cubes. Every
cell of 2 x 2 x 2 neighbouring voxel centres whose corners straddle the level
gets one vertex, at the mean of the points where the level crosses the cell's
edges (linear interpolation along each edge); every voxel edge that crosses
the level gets one quad (two triangles) joining the vertices of the four
cells around it, wound so that the normal points from inside (values above
the level) to outside. The result is the same isosurface marching cubes
approximates, to within a voxel, without marching cubes' case tables or a
scikit-image dependency (numpy only).

Depth and normal maps are per voxel column ``[y, x]`` (seen from the wall,
along +z): the depth is the z of the column's maximum
(:func:`recon.filters.depth_map`), the normal the unit vector
``(dz/dx, dz/dy, -1) / |.|`` of that height field (central differences,
one-sided at the edges), facing the wall (negative z). NaN where the column
is empty or a neighbour needed by the difference is.
"""

from __future__ import annotations

import os

import numpy as np

from transient_core.errors import UserInputError
from .grid import VoxelGrid

#: Per edge axis (z, y, x): the quad's cell order runs around the edge in the plane of the two other
#: axes (o1, o2) taken in increasing order; that order is cyclic for z -> (y, x) and x -> (z, y) but not for
#: y -> (z, x), and index order (z, y, x) mirrors world order (x, y, z); hence the winding per axis
#: (checked by tests/test_recon_surface.py: a sphere's mesh has volume +4/3 pi r^3).
_FLIP = (True, False, True)

__all__ = ["isosurface", "reconstruction_surface", "normal_map", "write_ply"]


def isosurface(field: np.ndarray, grid: VoxelGrid, level: float, closed: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Surface-nets isosurface of ``field`` (``[z, y, x]`` on ``grid``) at ``level``.

    With ``closed`` the field is padded by one voxel of a value below ``level``
    on every side, so regions touching the grid's boundary get closed surfaces
    (vertices up to one voxel outside the bounds); without it their surfaces
    stay open there.

    Returns
    -------
    vertices : ndarray float64, shape (n_vertices, 3)
        x, y, z in metres.
    faces : ndarray int64, shape (n_faces, 3)
        Triangles (vertex indices), normals pointing out of the region ``field > level``.
    """
    f = np.asarray(field, dtype=np.float64)
    if f.shape != grid.shape:
        raise UserInputError(f"field has shape {f.shape}, grid has {grid.shape}")
    if not np.isfinite(level):
        raise UserInputError(f"level={level!r} must be finite")
    axes = [np.asarray(a, dtype=np.float64) for a in (grid.z_m, grid.y_m, grid.x_m)]
    if closed:
        f = np.pad(f, 1, constant_values=min(float(level), float(f.min()) if f.size else 0.0) - 1.0)
        axes = [np.concatenate([[a[0] - st], a, [a[-1] + st]])
                for a, st in zip(axes, (grid.voxel_size_m[2], grid.voxel_size_m[1], grid.voxel_size_m[0]))]
    nz, ny, nx = f.shape
    if min(nz, ny, nx) < 2:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    inside = f > level
    # cells: (nz-1, ny-1, nx-1), corners at offsets (dz, dy, dx) in {0,1}^3
    corners = [(a, b, c) for a in (0, 1) for b in (0, 1) for c in (0, 1)]
    cin = np.stack([inside[a:nz - 1 + a, b:ny - 1 + b, c:nx - 1 + c] for a, b, c in corners])
    active = cin.any(axis=0) & ~cin.all(axis=0)
    idx = -np.ones(active.shape, dtype=np.int64)
    cz, cy, cx = np.nonzero(active)
    idx[cz, cy, cx] = np.arange(len(cz))
    # vertex: mean of edge crossings, in fractional voxel-index coordinates (z, y, x)
    acc = np.zeros((len(cz), 3))
    cnt = np.zeros(len(cz))
    edges = [(p, q) for p in range(8) for q in range(p + 1, 8)
             if sum(abs(u - v) for u, v in zip(corners[p], corners[q])) == 1]
    for p, q in edges:
        a, b = np.array(corners[p]), np.array(corners[q])
        fa = f[cz + a[0], cy + a[1], cx + a[2]]
        fb = f[cz + b[0], cy + b[1], cx + b[2]]
        cross = (fa > level) != (fb > level)
        t = np.where(cross, (level - fa) / np.where(fb != fa, fb - fa, 1.0), 0.0)
        pos = a[None] + t[:, None] * (b - a)[None]
        acc[cross] += pos[cross]
        cnt[cross] += 1
    local = acc / np.maximum(cnt, 1)[:, None]
    vz = np.interp(cz + local[:, 0], np.arange(nz), axes[0])
    vy = np.interp(cy + local[:, 1], np.arange(ny), axes[1])
    vx = np.interp(cx + local[:, 2], np.arange(nx), axes[2])
    vertices = np.stack([vx, vy, vz], axis=1)
    # quads: one per voxel edge with a sign change, joining the 4 cells sharing that edge
    faces = []
    for axis in range(3):
        sl_a = [slice(None)] * 3
        sl_b = [slice(None)] * 3
        sl_a[axis] = slice(0, -1)
        sl_b[axis] = slice(1, None)
        a_in = inside[tuple(sl_a)]
        b_in = inside[tuple(sl_b)]
        flip = a_in != b_in
        # the edge from voxel v to v + e_axis; the cells around it are v - (0/1 along the two other axes)
        e = np.argwhere(flip)
        others = [ax for ax in range(3) if ax != axis]
        o1, o2 = others
        ok = (e[:, o1] >= 1) & (e[:, o2] >= 1) & (e[:, o1] < active.shape[o1]) & (e[:, o2] < active.shape[o2])
        ok &= e[:, axis] < active.shape[axis]
        e = e[ok]
        if len(e) == 0:
            continue
        sign = a_in[tuple(e.T)]   # True: inside -> outside along +axis

        def cell(d1, d2):
            c = e.copy()
            c[:, o1] -= d1
            c[:, o2] -= d2
            return idx[c[:, 0], c[:, 1], c[:, 2]]

        q = np.stack([cell(1, 1), cell(0, 1), cell(0, 0), cell(1, 0)], axis=1)
        good = np.all(q >= 0, axis=1)
        q, sign = q[good], sign[good]
        # orientation: (o1, o2, axis) right-handed in (z, y, x) index order <=> handedness of (x, y, z) flips
        q = np.where((sign ^ _FLIP[axis])[:, None], q, q[:, ::-1])
        faces.append(np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]]))
    faces = np.concatenate(faces) if faces else np.zeros((0, 3), dtype=np.int64)
    return vertices, faces.astype(np.int64)


def reconstruction_surface(rec, level: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Isosurface of ``rec.volume`` (the filtered volume) at ``level``.

    Default level: half the smallest positive value of ``volume`` (the filter's
    threshold keeps voxels at or above it and zeroes the rest, so this level
    encloses exactly the kept voxels). A completed reconstruction
    (:func:`recon.completion.complete_surface`) gives the surface of the solid its shell encloses.
    """
    vol = rec.volume
    if "completion" in (rec.params or {}):   # a completed shell: the surface of the solid it encloses
        from scipy.ndimage import binary_fill_holes

        return isosurface(binary_fill_holes(vol > 0).astype(np.float32), rec.grid, 0.5 if level is None else level)
    if level is None:
        pos = vol[vol > 0]
        if pos.size == 0:
            return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
        level = 0.5 * float(pos.min())
    return isosurface(vol, rec.grid, float(level))


def normal_map(depth_m: np.ndarray, grid: VoxelGrid) -> np.ndarray:
    """Unit normals ``[y, x, 3]`` of the height field ``depth_m[y, x]`` facing the wall (see the module docstring)."""
    d = np.asarray(depth_m, dtype=np.float64)
    if d.shape != (len(grid.y_m), len(grid.x_m)):
        raise UserInputError(f"depth map has shape {d.shape}, expected {(len(grid.y_m), len(grid.x_m))}")
    gy = np.gradient(d, grid.y_m, axis=0) if d.shape[0] > 1 else np.zeros_like(d)
    gx = np.gradient(d, grid.x_m, axis=1) if d.shape[1] > 1 else np.zeros_like(d)
    n = np.stack([gx, gy, -np.ones_like(d)], axis=-1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    return n


def write_ply(path: str | os.PathLike, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Write a binary little-endian PLY mesh atomically (vertices in metres)."""
    from transient_core.atomic import atomic_file

    v = np.asarray(vertices, dtype="<f4").reshape(-1, 3)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    header = (f"ply\nformat binary_little_endian 1.0\ncomment transient-mi recon isosurface, metres\n"
              f"element vertex {len(v)}\nproperty float x\nproperty float y\nproperty float z\n"
              f"element face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n").encode("ascii")
    rec = np.zeros(len(f), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    rec["n"] = 3
    rec["i"] = f
    with atomic_file(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(header)
            fh.write(v.tobytes())
            fh.write(rec.tobytes())
