"""The visibility refinement of the deterministic NLOS estimator (:mod:`~._nlos_quadrature`): which elements are
split, and which element of a level integrates each pair (cell, spot) after the split.

* **The test** (:func:`mixed_elements`, :func:`mixed_lit`): an element is split where a pair (cell, spot) that can
  carry light sees its four visibility samples partly; from a cell only the elements a seen spot lights from the
  cell's side are traced (:func:`refinement_test_pairs`).
* **The split** (:func:`refine_visibility`): a split element stays in the level and its four children are appended,
  up to ``refine_levels`` times.
* **The pairs** (:class:`Refinement`, :func:`refined_pairs`): each pair goes to the split element where the test's
  cell and the spot see all its samples or none, and to its children where they see them partly; so the pairs that
  did not ask for the split cost one pair, not four.

World frame, metres, float64; masks are uint8, bit ``j`` for sample ``j`` (0 the centroid). ``g`` below is a level's
geometry, :class:`~._nlos_quadrature._Geometry` (its cells ``cell_p``, ``cell_pixel``, ``m`` per patch side and the
wall's ``normal``).
"""

from __future__ import annotations

import numba
import numpy as np

from transient_mi.integrators._nlos_elements import sample_points, split4
from transient_mi.integrators._nlos_pair_kernels import _side
from transient_mi.integrators._nlos_pairs import TracedVisibility, chunk_starts, spot_masks
from transient_mi.integrators._nlos_surfaces import ElementSurfaces, is_lambertian, visibility_masks


@numba.njit(cache=True, parallel=True, fastmath=False)
def mixed_lit(vc, vs, e0, X0, n_sh, cell_p, S, cell_spot, side_test, out):
    """The visibility refinement's test (:func:`refine_visibility`) for the elements ``e0:e0 +
    k``: ``out[e0 + j]`` is set when some cell ``c`` and spot ``s`` whose pair can carry light see the element's
    samples partly, ``m = vc[c, j] & vs[e0 + j, s]`` neither 0 nor all four: the pairs
    :func:`~._nlos_pair_kernels.spread_group` bounds as mixed. A pair can carry light as ``lit`` of
    :func:`~._nlos_pair_kernels.pair_geometry` says by geometry: with ``side_test`` (Lambertian elements) the cell and
    the spot lie on the same side of the element's shading normal ``n_sh [n, 3]`` at its centroid ``X0 [n, 3]``.
    ``vc [C, k]``, ``vs [n, G]`` uint8 masks; ``cell_p [C, 3]``, ``S [G, 3]`` (m); ``cell_spot [C]``: the one spot
    each cell pairs with (:func:`cell_spots`)."""
    C, k = vc.shape
    G = vs.shape[1]
    for j in numba.prange(k):
        e = e0 + j
        side_s = np.ones(G, dtype=np.int64)  # each spot's side, once per element (1: no side test)
        if side_test:
            for s in range(G):
                side_s[s] = _side_of(S, s, X0, n_sh, e)
        hit = False
        for c in range(C):
            mp = vc[c, j]
            if mp == 0:
                continue
            sx = _side_of(cell_p, c, X0, n_sh, e) if side_test else 1
            if sx == 0:
                continue
            s_lo = 0 if cell_spot[c] < 0 else cell_spot[c]
            s_hi = G if cell_spot[c] < 0 else cell_spot[c] + 1
            for s in range(s_lo, s_hi):
                m = mp & vs[e, s]
                if m == 0 or m == 15 or sx * side_s[s] <= 0:
                    continue
                hit = True
                break
            if hit:
                break
        if hit:
            out[e] = True


#: A cell and a spot count as on opposite sides of an element for :func:`refinement_test_pairs` when the product of
#: their direction cosines with its shading normal is below minus this (the render's own side test, ``lit`` of
#: :func:`~._nlos_pair_kernels.pair_geometry`, normalises otherwise: a margin, so no pair it lights is left untraced
#: by a rounding).
SIDE_COS_MARGIN = 1e-9


@numba.njit(cache=True, parallel=True, fastmath=False)
def refinement_test_pairs(vs, e0, ne, X0, n_sh, cell_p, S, cell_spot):
    """The pairs of the visibility refinement's test that are traced from the cells: bool ``[C ne]`` (cell-major,
    the elements ``e0:e0 + ne``), set where some spot that sees a sample of the element (``vs [n, G]``; a confocal
    cell's own spot ``cell_spot[c]``, -1 for every spot) lies on the cell's side of its shading normal ``n_sh``
    at the centroid ``X0`` (up to :data:`SIDE_COS_MARGIN`). The others carry no light for any spot
    (``lit`` of :func:`~._nlos_pair_kernels.pair_geometry`); their masks would be read by nothing. For Lambertian
    elements (the side test)."""
    C = cell_p.shape[0]
    G = S.shape[0]
    out = np.zeros(C * ne, dtype=np.bool_)
    for c in numba.prange(C):
        s_lo = 0 if cell_spot[c] < 0 else cell_spot[c]
        s_hi = G if cell_spot[c] < 0 else cell_spot[c] + 1
        for j in range(ne):
            e = e0 + j
            cc = _cos_side(cell_p, c, X0, n_sh, e)
            for s in range(s_lo, s_hi):
                if vs[e, s] != 0 and cc * _cos_side(S, s, X0, n_sh, e) > -SIDE_COS_MARGIN:
                    out[c * ne + j] = True
                    break
    return out


@numba.njit(cache=True, fastmath=False, inline="always")
def _cos_side(P, i, X0, n_sh, e):
    """The cosine between element ``e``'s shading normal and the direction from its centroid to ``P[i]``."""
    dx, dy, dz = P[i, 0] - X0[e, 0], P[i, 1] - X0[e, 1], P[i, 2] - X0[e, 2]
    r = np.sqrt(dx * dx + dy * dy + dz * dz)
    return (dx * n_sh[e, 0] + dy * n_sh[e, 1] + dz * n_sh[e, 2]) / r if r > 0.0 else 0.0


@numba.njit(cache=True, fastmath=False, inline="always")
def _partial(m) -> bool:
    """A visibility mask that sees some of an element's four samples but not all."""
    return m != 0 and m != 15


@numba.njit(cache=True, fastmath=False, inline="always")
def _children_take(cm, sm, ct, cs, si) -> bool:
    """Whether the pairs of a test cell ``ct`` with split element ``si`` (its column in ``cm [C_test, n_split]``,
    row of ``sm [n_split, G]``) are integrated by its four children: the cell sees its samples partly, or its spot
    ``cs`` does (every spot of the group, ``cs = -1``)."""
    if _partial(cm[ct, si]):
        return True
    if cs >= 0:
        return _partial(sm[si, cs])
    for s in range(sm.shape[1]):
        if _partial(sm[si, s]):
            return True
    return False


@numba.njit(cache=True, parallel=True, fastmath=False)
def refined_pairs(lit, e0, ne, parent, split_idx, cm, sm, cell_of, cell_spot):
    """In place, clear ``lit`` (bool ``[C ne]``, cell-major pairs of the level's cells ``c`` with the elements
    ``e0:e0 + ne``) for the pairs that the visibility refinement gives to other elements of the level, so that every
    pair (cell, piece of surface) is integrated once, at the finest level its visibility asks for
    (:func:`refine_visibility`): a split element's pair goes to its four children where
    :func:`_children_take` says so (its samples seen partly from the cell's test cell ``cell_of[c]`` or from the
    pair's spot, ``cell_spot[c]``, -1 for any of the group), and stays with it otherwise; a child's pair is
    integrated only where every ancestor's gives it away. ``parent [n]``: each element's parent (-1: none);
    ``split_idx [n]``: the column of a split element in the test's masks ``cm [C_test, n_split]``, ``sm [n_split,
    G]`` (-1: not split)."""
    C = lit.shape[0] // max(ne, 1)
    for c in numba.prange(C):
        ct = cell_of[c]
        cs = cell_spot[c]
        for j in range(ne):
            i = c * ne + j
            if not lit[i]:
                continue
            e = e0 + j
            si = split_idx[e]
            keep = si < 0 or not _children_take(cm, sm, ct, cs, si)
            a = parent[e]
            while keep and a >= 0:
                keep = _children_take(cm, sm, ct, cs, split_idx[a])
                a = parent[a]
            if not keep:
                lit[i] = False


@numba.njit(cache=True, fastmath=False, inline="always")
def _side_of(P, i, X0, n_sh, e):
    """The side (+1, -1; 0 in the plane) of point ``P[i]`` with respect to element ``e``'s shading normal
    ``n_sh[e]`` at its centroid ``X0[e]``."""
    return _side((P[i, 0] - X0[e, 0]) * n_sh[e, 0] + (P[i, 1] - X0[e, 1]) * n_sh[e, 1]
                 + (P[i, 2] - X0[e, 2]) * n_sh[e, 2])


class Refinement:
    """Which element of a level integrates each pair after the visibility refinement
    (:func:`refine_visibility`): a split element stays in the level beside its four children,
    and each of its pairs (cell, spot) is integrated by it where the test's cell (``cell_of``) and the spot see its
    samples wholly or not at all, by its children otherwise (:func:`refined_pairs`).

    ``parent [n]`` (int64, -1: none), ``split_idx [n]`` (int64: a split element's column in the masks, -1 for the
    others), the split elements' masks from the test's cells ``cell_masks [C_test, n_split]`` and from the spots
    ``spot_masks [n_split, G]`` (uint8), the test cell of every cell of the level ``cell_of [C]`` and each cell's
    spot ``cell_spot [C]`` (its pixel's for a confocal capture, -1: every spot of the group)."""

    def __init__(self, parent, split_idx, cell_masks, spot_masks_, cell_of, cell_spot):
        self.parent, self.split_idx = parent, split_idx
        self.cell_masks, self.spot_masks = cell_masks, spot_masks_
        self.cell_of, self.cell_spot = np.ascontiguousarray(cell_of), np.ascontiguousarray(cell_spot)

    def owned(self, n_cells: int, e0: int, ne: int) -> np.ndarray:
        """The pairs (bool ``[n_cells ne]``, cells with the elements ``e0:e0 + ne``, cell-major) that the elements
        themselves integrate, not other elements of the level (:func:`refined_pairs` of every pair). Known before
        the pairs' geometry, which then skips the others (:func:`~._nlos_pair_kernels.pair_geometry`)."""
        mask = np.ones(n_cells * ne, dtype=np.bool_)
        refined_pairs(mask, e0, ne, self.parent, self.split_idx, self.cell_masks, self.spot_masks, self.cell_of,
                      self.cell_spot)
        return mask


def mixed_elements(scene, setup, g, spots, tri, keep_cells: bool = False, n_sh=None, confocal: bool = False,
                   owner: "Refinement | None" = None, first: int = 0):
    """Elements with a pair (cell of ``g``, spot) that can carry light and whose visibility samples it sees partly
    (:func:`mixed_lit`: the pairs the render bounds as mixed): ``(mixed, traced, cells)``,
    bool ``[n]``, the masks traced for the test (:class:`~._nlos_pairs.TracedVisibility`; its cells' masks only
    with ``keep_cells``) and the cells' masks of the mixed elements, ``uint8 [C, n_mixed]`` (what
    :class:`Refinement` reads). ``n_sh [n, 3]``: the elements' shading normals where they are
    Lambertian (a pair then carries light only with the cell and the spot on one side), ``None`` otherwise;
    ``confocal``: each cell pairs with its pixel's spot only. ``owner``, optional: the :class:`Refinement` of the
    splits so far, whose elements ``first:first + n`` these are: only the pairs their ancestors give them are
    tested (:meth:`Refinement.owned`; the others are integrated by an ancestor whatever these elements' visibility,
    and their masks are left 0).

    The test asked before whether the samples disagreed for some cell or some spot alone. On the paper scene (16 x
    16, 2.1 cm elements, the first test) that split 8605 of 33,732 elements; the masks combined (samples seen from
    both) leave 7188, and the side test 5719. Splitting the others changed no bound, only the count."""
    pts = sample_points(tri)
    vs = np.ascontiguousarray(spot_masks(scene, setup, spots, pts))
    n = len(tri)
    mixed = np.zeros(n, dtype=bool)
    C = len(g.cell_p)
    X0 = np.ascontiguousarray(pts[:, 0])
    side_test = n_sh is not None
    nrm = np.ascontiguousarray(n_sh if side_test else np.zeros((n, 3)), dtype=np.float64)
    S = np.ascontiguousarray(np.asarray(setup.spots, dtype=np.float64)[list(spots)])
    cell_spot = cell_spots(g, confocal)
    cell_p = np.ascontiguousarray(g.cell_p, dtype=np.float64)
    vc = np.empty((C, n), dtype=np.uint8) if keep_cells else None
    vc_mixed = [np.empty((C, 0), dtype=np.uint8)]
    for e0, e1 in chunk_starts(4 * C, n):
        own = None if owner is None else owner.owned(C, first + e0, e1 - e0)
        if side_test or own is not None:  # (only the pairs that can carry light: the cell on a seen spot's side)
            todo = (refinement_test_pairs(vs, e0, e1 - e0, X0, nrm, cell_p, S, cell_spot) if side_test
                    else np.ones(C * (e1 - e0), dtype=np.bool_))
            todo = np.flatnonzero(todo if own is None else todo & own)
            v = np.zeros(C * (e1 - e0), dtype=np.uint8)
            v[todo] = visibility_masks(scene, g.cell_p, g.normal, pts, e0, e1, todo)
            v = v.reshape(C, e1 - e0)
        else:
            v = np.ascontiguousarray(visibility_masks(scene, g.cell_p, g.normal, pts, e0, e1).reshape(C, e1 - e0))
        mixed_lit(v, vs, e0, X0, nrm, cell_p, S, cell_spot, side_test, mixed)
        vc_mixed.append(v[:, np.flatnonzero(mixed[e0:e1])])
        if keep_cells:
            vc[:, e0:e1] = v
    return (mixed, TracedVisibility(spots, vs, g.cell_p if keep_cells else None, vc),
            np.ascontiguousarray(np.concatenate(vc_mixed, axis=1)))


def refine_visibility(scene, setup, g, spots, tri, src, refine_levels: int, prov=None,
                      keep_cells: bool = False, faces=None, hidden_ptrs=None, confocal: bool = False,
                      owned_only: bool = False):
    """Split mixed-visibility elements (and ``prov``) in four, ``refine_levels`` times at most: ``(tri, src, levels,
    prov, traced, split)`` (``src``: each element's source triangle, a row of the :class:`~._nlos_elements.Faces`;
    ``traced``: the masks of the tests, of the elements they tested, which come first, as
    :class:`~._nlos_pairs.TracedVisibility` (cells' masks with ``keep_cells``), or ``None`` without a test;
    ``split``: ``(parent, split_idx, cell_masks, spot_masks)`` as :class:`Refinement` takes them,
    or ``None`` when nothing was split).

    A split element stays in the list and its four children are appended: each pair (cell, spot) is integrated by
    the element or by its children as its own visibility asks (:func:`refined_pairs`), so the
    pairs that see the element wholly or not at all cost one pair, not four. Each test after the first traces the
    children of the one before only (the elements tested already keep their masks: the same rays). With ``faces``
    and ``hidden_ptrs`` (the :class:`~._nlos_elements.Faces` and the hidden shapes) the test reads Lambertian
    elements' shading normals (a pair carries light with the cell and the spot on one side); ``confocal``: each
    cell pairs with its pixel's spot (:func:`mixed_elements`).

    ``owned_only`` (a render that shares the pairs, :class:`Refinement`): the children are tested with the pairs
    their ancestors give them only. A child's split changes no integral through the other pairs, which an ancestor
    integrates; on the paper scene's 32 x 32 capture at 1 s (10.3 mm elements, three levels) the elements' split
    then took 25.8 s instead of 40.1 s and left 1,053,368 fine elements instead of 1,061,548 (scratch timings, one
    run each). Without it (the fit's forward model, where the children take every pair) every pair is tested."""
    levels = 0
    traced = None
    lambertian = faces is not None and all(is_lambertian(sh.bsdf()) for sh in setup.hidden_shapes)
    parent = np.full(len(tri), -1, dtype=np.int64)
    split_idx = np.full(len(tri), -1, dtype=np.int64)
    split_cell, split_spot = [], []
    n_split = 0
    for _ in range(refine_levels):
        # (the elements tested already come first, their masks in ``traced``: only the children appended since
        # are tested)
        n0 = 0 if traced is None else traced.n
        n_sh = (ElementSurfaces(setup.hidden_shapes, hidden_ptrs, faces, tri[n0:], src[n0:]).n_sh if lambertian
                else None)
        owner = None
        if owned_only and n_split:
            owner = Refinement(parent, split_idx, np.ascontiguousarray(np.concatenate(split_cell, axis=1)),
                               np.ascontiguousarray(np.concatenate(split_spot)), np.arange(len(g.cell_p)),
                               cell_spots(g, confocal))
        mixed, new, vc_mixed = mixed_elements(scene, setup, g, spots, tri[n0:], keep_cells, n_sh, confocal, owner,
                                              n0)
        traced = new if traced is None else traced.then(new)
        if not mixed.any():
            break
        idx = n0 + np.flatnonzero(mixed)
        split_idx[idx] = n_split + np.arange(len(idx))
        n_split += len(idx)
        split_cell.append(vc_mixed)
        split_spot.append(new.spot[mixed])
        tri = np.concatenate([tri, split4(tri[idx])])
        src = np.concatenate([src, np.repeat(src[idx], 4)])
        prov = None if prov is None else np.concatenate([prov, split4(prov[idx])])
        parent = np.concatenate([parent, np.repeat(idx, 4)])
        split_idx = np.concatenate([split_idx, np.full(4 * len(idx), -1, dtype=np.int64)])
        levels += 1
    split = None if n_split == 0 else (parent, split_idx, np.ascontiguousarray(np.concatenate(split_cell, axis=1)),
                                       np.ascontiguousarray(np.concatenate(split_spot)))
    return tri, src, levels, prov, traced, split


def cell_spots(g, confocal: bool) -> np.ndarray:
    """The one spot each cell of ``g`` pairs with, ``int64 [C]``: its pixel's for a confocal capture, -1 (every spot
    of the group) otherwise."""
    return (np.ascontiguousarray(g.cell_pixel, dtype=np.int64) if confocal
            else np.full(len(g.cell_p), -1, dtype=np.int64))


def refinement_cells_of(g, m_test: int) -> np.ndarray:
    """The cell of the refinement test's geometry (``m_test`` cells per patch side) that holds each cell of ``g``
    (its centre), ``int64 [P g.m^2]`` (the identity when ``m_test == g.m``)."""
    m = g.m
    c = np.arange(len(g.cell_p))
    k, r = np.divmod(c, m * m)
    iv, iu = np.divmod(r, m)
    return k * m_test * m_test + ((2 * iv + 1) * m_test) // (2 * m) * m_test + ((2 * iu + 1) * m_test) // (2 * m)
