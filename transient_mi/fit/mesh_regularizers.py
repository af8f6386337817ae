r"""Regularisers of a free-mesh fit (``transient-mi fit --model mesh``): smoothness, edge length and normal
consistency of a triangle mesh, each with its closed-form gradient with respect to the vertices.

A mesh is ``vertices [V, 3]`` (float64, metres) and ``faces [F, 3]`` (vertex indices, counter-clockwise seen
from the side the normal points to). Every energy is dimensionless (lengths divided by ``h0``, the start's
mean edge length), so its weight does not depend on the mesh's size or resolution:

* **Laplacian** ``E_lap = mean_i |x_i - mean_{j in N(i)} x_j|^2 / h0^2`` (the uniform "umbrella" Laplacian,
  as pytorch3d's ``mesh_laplacian_smoothing`` with uniform weights). On an open mesh a boundary vertex's
  neighbours are its two boundary neighbours only: the boundary curve is smoothed along itself and not
  pulled inwards, so a flat patch with a straight or smoothly curved outline has no Laplacian energy and the
  silhouette is not shrunk by the regulariser;
* **edge length** ``E_edge = mean_e ((|e| - h0) / h0)^2`` (pytorch3d's ``mesh_edge_loss``): keeps triangles
  from degenerating while the vertices move;
* **normal consistency** ``E_normal = mean_{e interior} (1 - n_a . n_b)`` over the two faces of each interior
  edge (pytorch3d's ``mesh_normal_consistency``): penalises folds;
* **reflectance smoothness** (per-face reflectance only, :func:`albedo_regularizer`)
  ``E_albedo = mean_{e interior} ((rho_a - rho_b) / rho_ref)^2`` over the same face pairs: a change of
  reflectance costs at the edges where it happens, so two materials meeting along a line cost little and
  face-to-face noise much.
* **reflectance total variation** (the carving's prior, :func:`reflectance_total_variation`)
  ``E_tv = sum_{e interior} (l_e / sqrt(A)) (sqrt((rho_a - rho_b)^2 + delta^2) - delta)`` over the same face
  pairs, ``l_e`` the edge's length and ``A`` the mesh's area (:func:`outline_weights`): the total variation of a
  piecewise-constant reflectance, rounded within ``delta`` of zero so that it has a gradient (the "Charbonnier"
  form). An object of reflectance ``c`` on empty faces costs about ``c`` times its outline's length over
  ``sqrt(A)``, whatever the faces' size. Unlike the square above it costs a step by its height, not its square,
  so it keeps a sharp edge between an object and the empty faces around it while it fills dark faces inside.

:func:`laplacian_matrix` is the same adjacency as a sparse symmetric matrix ``L = D - A`` (combinatorial,
boundary-aware as above), used for the "large steps" parametrisation of :mod:`transient_mi.fit.mesh_model`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

__all__ = ["MeshTopology", "RegularizerWeights", "albedo_regularizer", "outline_weights",
           "reflectance_total_variation", "regularizer", "laplacian_matrix"]


@dataclass(frozen=True)
class RegularizerWeights:
    """Weights of the energies (dimensionless; each is multiplied by the fit's objective scale; ``albedo`` only
    with per-face reflectance)."""

    laplacian: float = 1.0
    edge: float = 0.05
    normal: float = 0.1
    albedo: float = 1.0


class MeshTopology:
    """The fixed combinatorics of a mesh: edges, boundary, adjacency, interior edges' face pairs.

    Parameters
    ----------
    faces : numpy.ndarray
        ``[F, 3]`` vertex indices.
    n_vertices : int
        ``V``.
    """

    def __init__(self, faces: np.ndarray, n_vertices: int):
        f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        self.faces, self.V = f, int(n_vertices)
        he = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])  # half-edges, face-major per corner
        face_of = np.tile(np.arange(len(f)), 3)
        key = np.sort(he, axis=1)
        uniq, inv, count = np.unique(key, axis=0, return_inverse=True, return_counts=True)
        inv = inv.ravel()
        self.edges = uniq  # [E, 2]
        boundary_edge = count == 1
        self.boundary_edges = uniq[boundary_edge]
        on_boundary = np.zeros(self.V, dtype=bool)
        on_boundary[self.boundary_edges.ravel()] = True
        self.on_boundary = on_boundary
        # interior edges shared by exactly two faces: their face pairs
        order = np.argsort(inv, kind="stable")
        pairs = []
        starts = np.concatenate([[0], np.cumsum(count)])
        for k in np.flatnonzero(count == 2):
            a, b = order[starts[k]: starts[k] + 2]
            pairs.append((face_of[a], face_of[b]))
        self.face_pairs = np.array(pairs, dtype=np.int64).reshape(-1, 2)
        self.interior_edges = uniq[count == 2]  # [P, 2]: the edge each face pair shares, in their order
        # the smoothing adjacency: interior vertices take all their edges, boundary vertices their boundary edges
        e = self.edges
        keep_ij = ~on_boundary[e[:, 0]] | boundary_edge  # edge counts as a neighbour of its first vertex
        keep_ji = ~on_boundary[e[:, 1]] | boundary_edge
        rows = np.concatenate([e[keep_ij, 0], e[keep_ji, 1]])
        cols = np.concatenate([e[keep_ij, 1], e[keep_ji, 0]])
        A = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(self.V, self.V))
        deg = np.asarray(A.sum(axis=1)).ravel()
        self.degree = deg
        inv_deg = np.where(deg > 0, 1.0 / np.maximum(deg, 1), 0.0)
        #: uniform Laplacian ``x_i - mean of neighbours`` (rows without neighbours are zero)
        self.uniform = (sp.diags((deg > 0).astype(np.float64)) - sp.diags(inv_deg) @ A).tocsr()
        self.adjacency = A


def laplacian_matrix(topo: MeshTopology) -> sp.csr_matrix:
    """The symmetric combinatorial Laplacian ``D - A'`` of the smoothing adjacency (``A'`` symmetrised: an edge
    is kept when either end keeps it), ``[V, V]``, positive semi-definite."""
    A = topo.adjacency.maximum(topo.adjacency.T)
    d = np.asarray(A.sum(axis=1)).ravel()
    return (sp.diags(d) - A).tocsr()


def _face_normals(x: np.ndarray, f: np.ndarray):
    a, b, c = x[f[:, 0]], x[f[:, 1]], x[f[:, 2]]
    cr = np.cross(b - a, c - a)
    ln = np.linalg.norm(cr, axis=1)
    n = cr / np.maximum(ln, 1e-300)[:, None]
    return a, b, c, cr, ln, n


def regularizer(x: np.ndarray, topo: MeshTopology, h0: float, w: RegularizerWeights) -> tuple[float, np.ndarray,
                                                                                             dict]:
    """``(E, dE/dx [V, 3], parts)``: the weighted sum of the energies (module docstring) at vertices ``x``
    (``[V, 3]``, m) and its gradient; ``parts`` the three unweighted energies."""
    x = np.asarray(x, dtype=np.float64).reshape(-1, 3)
    g = np.zeros_like(x)
    parts = {}
    V = len(x)
    # Laplacian
    Lx = topo.uniform @ x
    parts["laplacian"] = float(np.sum(Lx * Lx) / (V * h0 * h0))
    g += w.laplacian * (2.0 / (V * h0 * h0)) * (topo.uniform.T @ Lx)
    # edge length
    e = topo.edges
    d = x[e[:, 1]] - x[e[:, 0]]
    ln = np.linalg.norm(d, axis=1)
    r = (ln - h0) / h0
    parts["edge"] = float(np.mean(r * r)) if len(e) else 0.0
    if len(e):
        ge = (2.0 / len(e)) * (r / h0)[:, None] * d / np.maximum(ln, 1e-300)[:, None]
        np.add.at(g, e[:, 1], w.edge * ge)
        np.add.at(g, e[:, 0], -w.edge * ge)
    # normal consistency
    fp = topo.face_pairs
    if len(fp):
        f = topo.faces
        a, b, c, cr, lc, n = _face_normals(x, f)
        parts["normal"] = float(np.mean(1.0 - np.sum(n[fp[:, 0]] * n[fp[:, 1]], axis=1)))
        gn = np.zeros_like(n)  # dE/dn per face
        np.add.at(gn, fp[:, 0], -n[fp[:, 1]] / len(fp))
        np.add.at(gn, fp[:, 1], -n[fp[:, 0]] / len(fp))
        gc = (gn - np.sum(gn * n, axis=1, keepdims=True) * n) / np.maximum(lc, 1e-300)[:, None]  # dE/d(cross)
        gb = np.cross(c - a, gc)
        gcv = np.cross(gc, b - a)
        np.add.at(g, f[:, 1], w.normal * gb)
        np.add.at(g, f[:, 2], w.normal * gcv)
        np.add.at(g, f[:, 0], -w.normal * (gb + gcv))
    else:
        parts["normal"] = 0.0
    total = w.laplacian * parts["laplacian"] + w.edge * parts["edge"] + w.normal * parts["normal"]
    return float(total), g, parts


def albedo_regularizer(rho: np.ndarray, face_pairs: np.ndarray, rho_ref: float) -> tuple[float, np.ndarray]:
    """``(E_albedo, dE/drho [F])`` of per-face reflectances ``rho [F]`` (module docstring) over the interior edges'
    face pairs ``[P, 2]`` (:attr:`MeshTopology.face_pairs`), changes measured against ``rho_ref`` (> 0); 0 without
    interior edges."""
    rho = np.asarray(rho, dtype=np.float64)
    g = np.zeros_like(rho)
    if len(face_pairs) == 0:
        return 0.0, g
    d = (rho[face_pairs[:, 0]] - rho[face_pairs[:, 1]]) / rho_ref
    n = len(face_pairs)
    e = float(np.mean(d * d))
    c = 2.0 * d / (rho_ref * n)
    np.add.at(g, face_pairs[:, 0], c)
    np.add.at(g, face_pairs[:, 1], -c)
    return e, g


def outline_weights(vertices: np.ndarray, topo: MeshTopology) -> np.ndarray:
    """The weights ``l_e / sqrt(A)`` ``[P]`` of :func:`reflectance_total_variation`: each interior edge's length
    over the square root of the mesh's area (``vertices [V, 3]``, m; the result is dimensionless)."""
    x = np.asarray(vertices, dtype=np.float64)
    area = 0.5 * float(_face_normals(x, topo.faces)[4].sum())  # (|cross| is twice a face's area)
    e = topo.interior_edges
    return np.linalg.norm(x[e[:, 1]] - x[e[:, 0]], axis=1) / math.sqrt(max(area, 1e-300))


def reflectance_total_variation(rho: np.ndarray, face_pairs: np.ndarray, weights: np.ndarray,
                                delta: float) -> tuple[float, np.ndarray]:
    """``(E_tv, dE/drho [F])`` of per-face reflectances ``rho [F]`` (module docstring) over the interior edges' face
    pairs ``[P, 2]`` (:attr:`MeshTopology.face_pairs`) with their ``weights [P]`` (:func:`outline_weights`),
    rounded within ``delta`` (> 0, reflectance units); 0 without interior edges."""
    rho = np.asarray(rho, dtype=np.float64)
    g = np.zeros_like(rho)
    if len(face_pairs) == 0:
        return 0.0, g
    d = rho[face_pairs[:, 0]] - rho[face_pairs[:, 1]]
    r = np.sqrt(d * d + delta * delta)
    c = weights * d / r
    np.add.at(g, face_pairs[:, 0], c)
    np.add.at(g, face_pairs[:, 1], -c)
    return float(np.sum(weights * (r - delta))), g
