"""The elements of the deterministic NLOS estimator (:mod:`transient_mi.integrators._nlos_quadrature`).

Hidden meshes as triangles (world frame, metres, float64), their uniform and midpoint subdivisions, and the
points where visibility is sampled. Pure numpy.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

#: Visibility samples near each corner sit this far from the centroid, as a share of the way to the corner.
CORNER_SAMPLE = 0.95


class Faces(NamedTuple):
    """The hidden shapes' triangles: ``tri [F, 3, 3]`` float64 world vertices, ``shape [F]`` (index of the
    shape) and ``face [F]`` (the triangle's index in its mesh), int64. Elements refer to their source triangle by
    its row ``src`` in these arrays."""

    tri: np.ndarray
    shape: np.ndarray
    face: np.ndarray


def mesh_triangles(shapes) -> Faces:
    """The :class:`Faces` of the hidden shapes (meshes)."""
    tris, idx, face = [], [], []
    for i, s in enumerate(shapes):
        v = np.asarray(s.vertex_positions_buffer(), dtype=np.float64).reshape(-1, 3)
        f = np.asarray(s.faces_buffer(), dtype=np.int64).reshape(-1, 3)
        tris.append(v[f])
        idx.append(np.full(len(f), i, dtype=np.int64))
        face.append(np.arange(len(f), dtype=np.int64))
    if not tris:
        return Faces(np.zeros((0, 3, 3)), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))
    return Faces(np.concatenate(tris), np.concatenate(idx), np.concatenate(face))


def subdivide(tri: np.ndarray, shape_index: np.ndarray, max_edge_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Split every triangle into ``n^2`` similar ones (``n = ceil(longest edge / max_edge_m)``); ``shape_index``
    (any per-triangle label, e.g. the source row) is repeated for the pieces."""
    edges = np.stack([np.linalg.norm(tri[:, 1] - tri[:, 0], axis=1), np.linalg.norm(tri[:, 2] - tri[:, 1], axis=1),
                      np.linalg.norm(tri[:, 0] - tri[:, 2], axis=1)], axis=1).max(axis=1)
    n_div = np.maximum(1, np.ceil(edges / max_edge_m - 1e-9)).astype(np.int64)
    out, out_idx = [], []
    for n in np.unique(n_div):
        sel = np.flatnonzero(n_div == n)
        t = tri[sel]
        a, b, c = t[:, 0], t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
        local = []
        for i in range(n):
            for j in range(n - i):
                local.append(((i, j), (i + 1, j), (i, j + 1)))
                if j < n - i - 1:
                    local.append(((i + 1, j), (i + 1, j + 1), (i, j + 1)))
        L = np.asarray(local, dtype=np.float64) / n  # [m, 3 vertices, (i, j)]
        pts = a[:, None, None, :] + L[None, :, :, 0:1] * b[:, None, None, :] + L[None, :, :, 1:2] * c[:, None, None, :]
        out.append(pts.reshape(-1, 3, 3))
        out_idx.append(np.repeat(shape_index[sel], len(local)))
    order_tri = np.concatenate(out)
    order_idx = np.concatenate(out_idx)
    return order_tri, order_idx


def split4(tri: np.ndarray) -> np.ndarray:
    """Midpoint subdivision: each triangle ``[n, 3, 3]`` into four, ``[4 n, 3, 3]`` (children of one parent
    consecutive)."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, bc, ca = (a + b) / 2, (b + c) / 2, (c + a) / 2
    kids = np.stack([np.stack([a, ab, ca], 1), np.stack([ab, b, bc], 1), np.stack([ca, bc, c], 1),
                     np.stack([ab, bc, ca], 1)], axis=1)
    return kids.reshape(-1, 3, 3)


def sample_points(tri: np.ndarray) -> np.ndarray:
    """``[n, 4, 3]``: centroid, then three points near the corners (visibility samples)."""
    g = tri.mean(axis=1)
    corners = g[:, None, :] + CORNER_SAMPLE * (tri - g[:, None, :])
    return np.concatenate([g[:, None, :], corners], axis=1)
