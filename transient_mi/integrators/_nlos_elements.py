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


def _longest_edges(tri: np.ndarray) -> np.ndarray:
    """Per triangle ``[F, 3, 3]``, its longest edge (m, ``[F]``)."""
    return np.stack([np.linalg.norm(tri[:, 1] - tri[:, 0], axis=1), np.linalg.norm(tri[:, 2] - tri[:, 1], axis=1),
                     np.linalg.norm(tri[:, 0] - tri[:, 2], axis=1)], axis=1).max(axis=1)


def _areas(tri: np.ndarray) -> np.ndarray:
    """Per triangle ``[F, 3, 3]``, its area (m^2, ``[F]``)."""
    return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)


def _divisions(tri: np.ndarray, max_edge_m: float) -> np.ndarray:
    """Per triangle ``[F, 3, 3]``, the divisions ``n`` of :func:`subdivide`: ``ceil(longest edge / max_edge_m)``,
    at least 1 (int64 ``[F]``)."""
    return np.maximum(1, np.ceil(_longest_edges(tri) / max_edge_m - 1e-9)).astype(np.int64)


def _subdivision(tri: np.ndarray, max_edge_m: float):
    """Per division count ``n`` (ascending): ``(sel, L)``, the triangles split into ``n^2`` and their children's
    local coordinates ``L [m, 3 vertices, (i, j)]`` (vertex ``a + L_i (b - a) + L_j (c - a)``)."""
    n_div = _divisions(tri, max_edge_m)
    for n in np.unique(n_div):
        local = []
        for i in range(n):
            for j in range(n - i):
                local.append(((i, j), (i + 1, j), (i, j + 1)))
                if j < n - i - 1:
                    local.append(((i + 1, j), (i + 1, j + 1), (i, j + 1)))
        yield np.flatnonzero(n_div == n), np.asarray(local, dtype=np.float64) / n


def fine_count(tri: np.ndarray, element_size_m: float) -> int:
    """The number of fine elements the quadrature makes of the triangles ``tri [F, 3, 3]`` with
    ``element_size_m`` before visibility refinement: each split into ``n^2`` at twice the size (the coarse level,
    :func:`subdivide`), then in four (:func:`split4`). Cheap (no elements are built)."""
    n_div = _divisions(tri, 2.0 * element_size_m)
    return int(4 * (n_div * n_div).sum())


def element_scale_m(tri: np.ndarray, element_size_m: float) -> float:
    """The fine elements' size as their discretisation error sees it (m): the root of the area-weighted mean of
    the squared longest edge of the fine elements the quadrature makes of ``tri [F, 3, 3]`` with
    ``element_size_m`` (each triangle split into ``n^2`` similar ones, then in four: longest edge ``e / (2 n)``).
    A second-order error is a sum over the surface of area times the squared size, so where a mesh has many small
    triangles and a few large ones (the mannequin: median edge 1.2 cm, 5 % above 14 cm) the large ones set it,
    which the mean element area (:func:`effective_edge_m`, dominated by the count of small ones) hides."""
    area = _areas(tri)
    if len(tri) == 0 or area.sum() <= 0.0:
        return float(element_size_m)
    size = _longest_edges(tri) / (2.0 * _divisions(tri, 2.0 * element_size_m))
    return float(np.sqrt((area * size * size).sum() / area.sum()))


def effective_edge_m(tri: np.ndarray, n_elements: int) -> float:
    """The edge of an equilateral triangle of the mean element area (m): the elements' size where the meshes'
    own triangles, not ``element_size_m``, set it."""
    area = _areas(tri).sum()
    return float(np.sqrt(4.0 * area / (np.sqrt(3.0) * max(1, n_elements))))


def subdivide(tri: np.ndarray, shape_index: np.ndarray, max_edge_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Split every triangle into ``n^2`` similar ones (``n = ceil(longest edge / max_edge_m)``); ``shape_index``
    (any per-triangle label, e.g. the source row) is repeated for the pieces."""
    out, out_idx = [], []
    for sel, L in _subdivision(tri, max_edge_m):
        t = tri[sel]
        a, b, c = t[:, 0], t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
        pts = a[:, None, None, :] + L[None, :, :, 0:1] * b[:, None, None, :] + L[None, :, :, 1:2] * c[:, None, None, :]
        out.append(pts.reshape(-1, 3, 3))
        out_idx.append(np.repeat(shape_index[sel], len(L)))
    order_tri = np.concatenate(out)
    order_idx = np.concatenate(out_idx)
    return order_tri, order_idx


def provenance(n: int) -> np.ndarray:
    """``[n, 3, 4]`` provenance of ``n`` source triangles themselves: row ``v`` of element ``e`` holds the
    barycentric weights of its vertex ``v`` on its source triangle's vertices, then the source's index (a float,
    exact). Linear in the vertices, so :func:`split4` carries it as it splits the triangles."""
    p = np.zeros((n, 3, 4))
    p[:, :, :3] = np.eye(3)
    p[:, :, 3] = np.arange(n, dtype=np.float64)[:, None]
    return p


def subdivide_provenance(tri: np.ndarray, prov: np.ndarray, max_edge_m: float) -> np.ndarray:
    """The provenance ``[n_out, 3, 4]`` of :func:`subdivide`'s output (same order), from the input's ``prov``."""
    out = []
    for sel, L in _subdivision(tri, max_edge_m):
        w = np.stack([1.0 - L[..., 0] - L[..., 1], L[..., 0], L[..., 1]], axis=-1)  # [m, 3 child v, 3 parent v]
        kid = np.einsum("mvu,suk->smvk", w, prov[sel][:, :, :3])
        src = np.broadcast_to(prov[sel][:, None, :1, 3:], kid.shape[:3] + (1,))
        out.append(np.concatenate([kid, src], axis=-1).reshape(-1, 3, 4))
    return np.concatenate(out)


def fine_provenance(tri0: np.ndarray, max_edge_m: float) -> np.ndarray:
    """The provenance of the quadrature's fine elements before refinement: ``split4(subdivide(tri0, max_edge_m))``."""
    return split4(subdivide_provenance(tri0, provenance(len(tri0)), max_edge_m))


def split4(tri: np.ndarray) -> np.ndarray:
    """Midpoint subdivision: each triangle ``[n, 3, k]`` into four, ``[4 n, 3, k]`` (children of one parent
    consecutive; any ``k``: vertices, or their :func:`provenance`)."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, bc, ca = (a + b) / 2, (b + c) / 2, (c + a) / 2
    kids = np.stack([np.stack([a, ab, ca], 1), np.stack([ab, b, bc], 1), np.stack([ca, bc, c], 1),
                     np.stack([ab, bc, ca], 1)], axis=1)
    return kids.reshape(-1, 3, tri.shape[-1])


def sample_points(tri: np.ndarray) -> np.ndarray:
    """``[n, 4, 3]``: centroid, then three points near the corners (visibility samples)."""
    g = tri.mean(axis=1)
    corners = g[:, None, :] + CORNER_SAMPLE * (tri - g[:, None, :])
    return np.concatenate([g[:, None, :], corners], axis=1)
