r"""Geometry derivatives of the deterministic three-bounce estimator (``estimator="quadrature"``): reverse mode
with respect to the hidden meshes' vertex positions (and so to whatever moves them in Dr.Jit: Mitsuba's
``vertex_positions``, a ``rectangle``'s ``to_world``, a fit model's parameters).

What moves with a vertex
------------------------
Every element is a fixed barycentric combination of its mesh triangle's vertices (the subdivision, the
midpoint splits and the visibility refinement are linear: :func:`~._nlos_elements.provenance`), so an
element's vertices move linearly with the mesh's and the chain rule to the mesh is a fixed sparse map. A pair
(element ``e``, cell ``c``) deposits ``F m_j(t_lo, a, b, w_1, w_2)`` (``F``: its light, the visible share
included; ``m_j``: the exact bin masses). Differentiated, for the light ``F`` (the product of the element's
area, ``|cos theta_X|``, ``1 / r_pX^2``, the wall's ``f_p cos``, the element's ``f_X cos``, the spot's
``f_S cos`` and ``1 / r_SX^2``, all at the centroid ``X_0``, the unit normal ``n`` and the area of the
element):

* area and normal from the element's vertices (``n A = (V_1 - V_0) x (V_2 - V_0) / 2``);
* distances and directions from ``X_0`` (the mean of the vertices) to the cell centre and to the spot;
* the BSDFs: the relay wall's and the differentiated shapes' BSDFs must be diffuse (``f`` independent of the
  directions: Mitsuba's ``diffuse``, ``twosided`` of it, textured or not), so ``f cos = k cos`` with ``k`` the
  primal's value over its cosine, and only the cosine moves; a textured reflectance is read at the centroid's
  fixed barycentric position, so it does not. Other BSDFs are refused in one line. Meshes with smooth vertex
  normals are refused too (their shading normal would move in a way not differentiated here); flat ones (a
  ``rectangle``'s) shade with the element's normal.

and for the masses, through the knots (the vertices' path lengths ``|V_v - p| + |V_v - S|``, the 3/4
convexity shift of the centroid's ``|X_0 - p| + |X_0 - S|``, the cell's shift, which reads ``X_0``) and the
cell's widths ``w_1, w_2`` (which read the direction ``p -> X_0``) with the closed-form mass derivatives of
:mod:`~._nlos_mass_adjoint`.

Held fixed: visibility (which samples of an element see the cell and the spot, so the visible share of
a mixed pair), the elements' subdivision (counts, refinement), the point where the wall is hit. So this is
the *interior* derivative of the quadrature's primal: light appearing or vanishing behind an occluding
edge, at a silhouette or where an element's visibility samples change their verdict is not differentiated
(the primal jumps there); neither is the geometric dependence of the cell tilt's weight part (the first-order
amplitude slope across a wall cell from the weight's variation, in ``Chunk.tilt``; the tilt's terms' knot, width
and tilt derivatives are taken where both widths are finite, :func:`~._nlos_mass_adjoint.mass_adjoint`). The
tilt's other part, the path length's curvature (:func:`~._nlos_cell_curvature.cell_curvature`), is
differentiated with its shift by :func:`~._nlos_cell_curvature.curvature_gradient`. On the rigid-motion test's
scene the gradient is then within 2.4e-3 of central differences, against 5.4e-3 with neither the curvature's
derivatives nor the tilt terms' (a scratch measurement, 2026-12-08), the error estimate
(the element's slope, by contrast, is differentiated: its term's knot and width derivatives in
:func:`~._nlos_mass_adjoint.mass_adjoint`, and the slope itself through its knots and its vertices' amplitudes,
:func:`~._nlos_element_slope.slope_adjoint`; without them the confocal rigid-motion gradient of the tests was 1.6 % off), the error estimate
(coarse level), nor a branch switch of the primal
(a cell width crossing ``REL_WIDTH_EPS`` of the spread: the primal's truncation there is below 1e-6).

Numba, float64, tiles of cells x elements in parallel (:func:`geometry_adjoint`), each adding into its own
accumulators, summed in a fixed order; jobs (spots) in order: the same inputs give the same bytes on any number of
threads.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numba
import numpy as np

from transient_mi._upload import upload
from transient_mi.props import PluginParameterError

from transient_mi.integrators._nlos_mass_adjoint import mass_adjoint
from transient_mi.integrators._nlos_cell_curvature import cell_curvature, curvature_gradient, edge_width_m
from transient_mi.integrators._nlos_pair_kernels import MAX_TILT_SUM
from transient_mi.integrators._nlos_element_slope import laser_slope_terms, slope_adjoint, slope_of

#: A cosine or distance below this does not take part in the log-derivative of a pair's light (a grazing pair).
_TINY = 1e-12


@numba.njit(cache=True, fastmath=False)
def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@numba.njit(cache=True, fastmath=False)
def _cross(a, b):
    out = np.empty(3)
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]
    return out


@numba.njit(cache=True, fastmath=False)
def _visible_share(vis_p, vis_s, i, e):
    """``(nvis, share)``: how many of pair ``i``'s four visibility samples see both the cell and the spot, and
    their share of the pair (centroid 1/2, corners 1/6 each)."""
    nvis = 0
    frac = 0.0
    for s in range(4):
        if vis_p[i, s] and vis_s[e, s]:
            nvis += 1
            frac += 0.5 if s == 0 else 1.0 / 6.0
    return nvis, frac


@numba.njit(cache=True, fastmath=False)
def _pair_knots(i, e, r_pv, r_px, opl_d, cell_shift, r_sv, r_sx, spot_opl, bin_m, t_origin_bins):
    """Pair ``i`` (element ``e``): its knots in vertex order (bins on the padded axis), then sorted: the smallest
    and the other two relative to it, ``(t_0, t_1, t_2, t_lo, a, b)``, ``0 <= a <= b``, from the lengths of
    :func:`pair_lengths` (the primal's knots, :func:`~._nlos_pair_kernels._knots`, to rounding)."""
    l0 = opl_d[i] + r_pv[i, 0] + r_sv[e, 0] + spot_opl
    l1 = opl_d[i] + r_pv[i, 1] + r_sv[e, 1] + spot_opl
    l2 = opl_d[i] + r_pv[i, 2] + r_sv[e, 2] + spot_opl
    lc = opl_d[i] + r_px[i] + r_sx[e] + spot_opl
    shift = 0.75 * (lc - (l0 + l1 + l2) / 3.0) + cell_shift[i]
    v0 = (l0 + shift) / bin_m - t_origin_bins
    v1 = (l1 + shift) / bin_m - t_origin_bins
    v2 = (l2 + shift) / bin_m - t_origin_bins
    t0, t1, t2 = v0, v1, v2
    if t0 > t1:
        t0, t1 = t1, t0
    if t1 > t2:
        t1, t2 = t2, t1
    if t0 > t1:
        t0, t1 = t1, t0
    return v0, v1, v2, t0, t1 - t0, t2 - t0


@numba.njit(cache=True, parallel=True, fastmath=False)
def pair_lengths(cell_p, X0, tri, e0, e1, D, ax, ay, fl, has_cells):
    """The detector-side lengths :func:`geometry_adjoint` reads, per pair of a chunk (cells x elements ``e0:e1``,
    cell-major, as :class:`~._nlos_pairs.Chunk`): ``r_pv [n, 3]`` (cell centre to the element's vertices),
    ``r_px`` (to its centroid), ``opl_d`` (the detector leg) and ``cell_shift`` (the cell's convexity shift), m;
    the primal folds them into its knots (:func:`~._nlos_pair_kernels.pair_geometry`)."""
    C = cell_p.shape[0]
    ne = e1 - e0
    n = C * ne
    r_pv = np.empty((n, 3))
    r_px = np.empty(n)
    opl_d = np.empty(n)
    cell_shift = np.zeros(n)
    for i in numba.prange(n):  # (written out per component: no heap allocation per pair; the same operations)
        c = i // ne
        e = e0 + i - c * ne
        p = cell_p[c]
        x = X0[e]
        r = np.sqrt((x[0] - p[0]) * (x[0] - p[0]) + (x[1] - p[1]) * (x[1] - p[1]) + (x[2] - p[2]) * (x[2] - p[2]))
        r_px[i] = r
        for v in range(3):
            t = tri[e, v]
            r_pv[i, v] = np.sqrt((t[0] - p[0]) * (t[0] - p[0]) + (t[1] - p[1]) * (t[1] - p[1])
                                 + (t[2] - p[2]) * (t[2] - p[2]))
        rd = np.sqrt((p[0] - D[0]) * (p[0] - D[0]) + (p[1] - D[1]) * (p[1] - D[1]) + (p[2] - D[2]) * (p[2] - D[2]))
        opl_d[i] = fl * rd
        if has_cells:
            acc = 0.0
            for cu in (-0.5, 0.5):
                for cv in (-0.5, 0.5):
                    q0 = p[0] + cu * ax[0] + cv * ay[0]
                    q1 = p[1] + cu * ax[1] + cv * ay[1]
                    q2 = p[2] + cu * ax[2] + cv * ay[2]
                    acc += fl * np.sqrt((q0 - D[0]) * (q0 - D[0]) + (q1 - D[1]) * (q1 - D[1])
                                        + (q2 - D[2]) * (q2 - D[2])) \
                        + np.sqrt((x[0] - q0) * (x[0] - q0) + (x[1] - q1) * (x[1] - q1) + (x[2] - q2) * (x[2] - q2))
            # the curvature along each edge (the primal's cell_curvature: the same shift, from the same widths)
            l0 = fl * rd + r
            sw = 0.0
            for h in (ax, ay):
                sh, _ = cell_curvature(x, p[0], p[1], p[2], D[0], D[1], D[2], l0, h[0], h[1], h[2], fl,
                                       edge_width_m(x, p, D, h, fl, r, rd))
                sw += sh
            cell_shift[i] = (acc / 4.0 - (fl * rd + r)) / 3.0 + sw
    return r_pv, r_px, opl_d, cell_shift


#: Cells per block of :func:`geometry_adjoint` (at most): the pairs are walked cell by cell, each cell's elements in
#: order, so the pair arrays are read in memory order and a pixel's adjoint row stays in cache; every block adds into
#: its own accumulators, which are summed in block order (fixed by the cell count: the same bytes on any threads).
GEOM_CELL_BLOCKS = 8
#: Elements per block of :func:`geometry_adjoint` (blocks of cells x blocks of elements run in parallel).
GEOM_ELEMENT_BLOCK = 64
# accumulator layout per (cell block, element): adjoints of the centroid (0:3), the unit normal (3:6), the area (6),
# of the vertices directly (7:16, vertex-major) and the weights of the element slope's laser-side amplitude
# gradients per vertex (16:19, applied once per element: :func:`~._nlos_element_slope.slope_adjoint`)
_ACC = 19


@numba.njit(cache=True, parallel=True, fastmath=False)
def geometry_adjoint(out, grad_ext, e0, ne, c_lo, c_hi, cell_pixel, cell_p, ax, ay, D, fl, has_cells, wall_n,
                     tri, X0, nrm, area, base, f_x, vis_p, r_pv, r_px, opl_d, cell_shift, w1, w2, tilt, vis_s,
                     spot_weight, S, r_sv, r_sx, spot_opl, bin_m, t_origin_bins, amp, amp_s):
    """Add to ``out [n, 3, 3]`` (per element, per vertex, xyz) the derivative of ``sum(grad_ext * hist)`` with
    respect to the element vertices, for one job of a chunk: the elements ``e0 .. e0 + ne - 1`` and the cells
    ``c_lo .. c_hi - 1`` (pair ``i = c ne + (e - e0)``) lit by the spot ``S``.

    ``grad_ext [n_pixels, n_ext]``: the adjoint of the padded histograms (pixel ``cell_pixel[c]``). Per pair
    (chunk order, as :class:`~._nlos_pairs.Chunk`): ``base`` (``geo f_p``), ``f_x``, ``vis_p`` (bool ``[n, 4]``),
    ``r_pv``, ``r_px``, ``opl_d``, ``cell_shift`` (:func:`pair_lengths`), ``w1``, ``w2``. Per element (this spot): ``vis_s``, ``spot_weight``,
    ``r_sv``, ``r_sx``; ``tri``, ``X0``, ``nrm``, ``area`` of :func:`~._nlos_pairs.element_terms`. ``ax``,
    ``ay``: the cell's edge vectors (m); ``amp [n_pairs, 3]`` and ``amp_s [n, 3]`` (this spot): the relative
    amplitudes at the vertices that give the element's slope (:func:`~._nlos_element_slope.slope_of`; an empty
    ``amp_s``: no slope); ``wall_n``: the relay wall's unit normal; ``D``: the detector; ``fl``: 1 when the detector
    leg is in the path length. Lengths in metres, ``spot_opl`` the laser leg,
    ``t_origin_bins`` the padded axis's origin in path-length bins.

    Tiles of (:data:`GEOM_CELL_BLOCKS` blocks of cells) x (blocks of :data:`GEOM_ELEMENT_BLOCK` elements) run in
    parallel, each walking its cells in order and each cell's elements in order.
    """
    # (per pair, every vector expression is written out per component: no heap allocation per pair)
    nc = c_hi - c_lo
    if nc <= 0 or ne <= 0:
        return
    n_cb = min(GEOM_CELL_BLOCKS, nc)
    n_eb = (ne + GEOM_ELEMENT_BLOCK - 1) // GEOM_ELEMENT_BLOCK
    acc = np.zeros((n_cb, ne, _ACC))
    # the element's side towards the spot, once per element: unit direction, distance, the two cosines
    us_e = np.empty((ne, 3))
    rs_e = np.empty(ne)
    cx_e = np.empty(ne)
    cs_e = np.empty(ne)
    for j in numba.prange(ne):
        e = e0 + j
        x0 = X0[e]
        u0 = S[0] - x0[0]
        u1 = S[1] - x0[1]
        u2 = S[2] - x0[2]
        rs = np.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
        u0 = u0 / rs
        u1 = u1 / rs
        u2 = u2 / rs
        us_e[j, 0] = u0
        us_e[j, 1] = u1
        us_e[j, 2] = u2
        rs_e[j] = rs
        cx_e[j] = nrm[e, 0] * u0 + nrm[e, 1] * u1 + nrm[e, 2] * u2
        cs_e[j] = -(wall_n[0] * u0 + wall_n[1] * u1 + wall_n[2] * u2)
    n_ext = grad_ext.shape[1]
    slope = amp_s.shape[0] > 0  # (element_slope=false: no laser-side amplitudes, every slope 0)
    for tile in numba.prange(n_cb * n_eb):
        cb = tile // n_eb
        eb = tile - cb * n_eb
        ca = c_lo + (cb * nc) // n_cb
        cz = c_lo + ((cb + 1) * nc) // n_cb
        ja = eb * GEOM_ELEMENT_BLOCK
        jz = min(ne, ja + GEOM_ELEMENT_BLOCK)
        perm = np.empty(3, dtype=np.int64)
        tk = np.empty(3)
        tb = np.empty(3)
        d = np.empty(3)
        g = np.empty(3)
        gv = np.empty(3)
        dsh = np.empty(3)
        dtl = np.empty(3)
        for c in range(ca, cz):
            k = cell_pixel[c]
            row = grad_ext[k]
            p = cell_p[c]
            for j in range(ja, jz):
                e = e0 + j
                i = c * ne + j
                full = base[i] * f_x[i] * spot_weight[e]
                if full == 0.0:
                    continue
                nvis, frac = _visible_share(vis_p, vis_s, i, e)
                if nvis == 0:
                    continue
                f = full * frac
                v0, v1, v2, tlo, a, b = _pair_knots(i, e, r_pv, r_px, opl_d, cell_shift, r_sv, r_sx, spot_opl,
                                                    bin_m, t_origin_bins)
                beta = 0.0
                if slope:
                    beta = slope_of(v0, v1, v2, amp[i, 0] * amp_s[e, 0], amp[i, 1] * amp_s[e, 1],
                                    amp[i, 2] * amp_s[e, 2], a, b, tilt[i, 0], tilt[i, 1])
                m_acc, s_t, s_a, s_b, s_w1, s_w2, s_e, s_k1, s_k2 = mass_adjoint(row, tlo, a, b, w1[i], w2[i],
                                                                                 tilt[i, 0], tilt[i, 1], n_ext, beta,
                                                                                 slope)
                if (m_acc == 0.0 and s_t == 0.0 and s_a == 0.0 and s_b == 0.0 and s_w1 == 0.0 and s_w2 == 0.0
                        and s_e == 0.0 and s_k1 == 0.0 and s_k2 == 0.0):
                    continue
                rs = rs_e[j]
                c_x = cx_e[j]
                c_s = cs_e[j]
                for q in range(3):
                    d[q] = X0[e, q] - p[q]
                r = np.sqrt(_dot(d, d))
                for q in range(3):
                    d[q] = d[q] / r  # cell -> centroid
                # --- the light F (log-derivative of each factor, times F * m_acc)
                fa = f * m_acc
                acc[cb, j, 6] += fa / area[e]
                cx = nrm[e, 0] * d[0] + nrm[e, 1] * d[1] + nrm[e, 2] * d[2]
                if abs(cx) > _TINY:
                    for q in range(3):
                        acc[cb, j, 3 + q] += fa * d[q] / cx
                    for q in range(3):
                        acc[cb, j, q] += fa * (nrm[e, q] - cx * d[q]) / (r * cx)
                m2r = fa * (-2.0 / r)
                for q in range(3):
                    acc[cb, j, q] += m2r * d[q]
                cp = _dot(wall_n, d)
                if abs(cp) > _TINY:
                    for q in range(3):
                        acc[cb, j, q] += fa * (wall_n[q] - cp * d[q]) / (r * cp)
                if abs(c_x) > _TINY:
                    for q in range(3):
                        acc[cb, j, 3 + q] += fa * us_e[j, q] / c_x
                    for q in range(3):
                        acc[cb, j, q] -= fa * (nrm[e, q] - c_x * us_e[j, q]) / (rs * c_x)
                if abs(c_s) > _TINY:
                    for q in range(3):
                        acc[cb, j, q] += fa * (wall_n[q] + c_s * us_e[j, q]) / (rs * c_s)  # d/dX0 of wall_n . (-us)
                p2r = fa * (2.0 / rs)
                for q in range(3):
                    acc[cb, j, q] += p2r * us_e[j, q]
                # --- the masses: knots (sorted as _pair_knots sorts them) and widths
                for v in range(3):
                    tk[v] = r_pv[i, v] + r_sv[e, v]
                    perm[v] = v
                for (u, w) in ((0, 1), (1, 2), (0, 1)):
                    if tk[perm[u]] > tk[perm[w]] or (tk[perm[u]] == tk[perm[w]] and perm[u] > perm[w]):
                        perm[u], perm[w] = perm[w], perm[u]
                tb[perm[0]] = s_t - s_a - s_b
                tb[perm[1]] = s_a
                tb[perm[2]] = s_b
                if slope and s_e != 0.0:  # the element's slope through its knots and its vertices' amplitudes
                    slope_adjoint(acc[cb, j], f, s_e, tb, v0, v1, v2, amp, amp_s, i, e, a, b, tilt, tri, X0, nrm,
                                  p, S, wall_n)
                fb = f / bin_m
                for v in range(3):
                    lb = fb * (tb[v] - 0.25 * s_t)  # knot v = (l_v + 0.75 (l_c - mean l) + shift) / bin_m - origin
                    for q in range(3):
                        acc[cb, j, 7 + 3 * v + q] += lb * ((tri[e, v, q] - p[q]) / r_pv[i, v] + (tri[e, v, q] - S[q])
                                                  / r_sv[e, v])
                cs = 0.75 * fb * s_t
                for q in range(3):
                    acc[cb, j, q] += cs * (d[q] - us_e[j, q])  # the centroid's path length r_pX + r_SX
                if has_cells:
                    for q in range(3):
                        g[q] = 0.0
                    for cu in (-0.5, 0.5):
                        for cv in (-0.5, 0.5):
                            for q in range(3):
                                gv[q] = X0[e, q] - (p[q] + cu * ax[q] + cv * ay[q])
                            nq = np.sqrt(_dot(gv, gv))
                            for q in range(3):
                                g[q] += gv[q] / nq
                    c3 = fb * s_t / 3.0
                    for q in range(3):
                        acc[cb, j, q] += c3 * (0.25 * g[q] - d[q])
                    # the cell's curvature along each edge: its shift through the knots, its tilt through the
                    # masses (not where the primal scaled the tilts down to MAX_TILT_SUM)
                    clamped = abs(tilt[i, 0]) + abs(tilt[i, 1]) >= MAX_TILT_SUM * (1.0 - 1e-12)
                    for (hv, s_k) in ((ax, s_k1), (ay, s_k2)):
                        curvature_gradient(X0[e], p, D, hv, fl, r, d, dsh, dtl)
                        for q in range(3):
                            acc[cb, j, q] += fb * s_t * dsh[q]
                        if not clamped:
                            for q in range(3):
                                acc[cb, j, q] += f * s_k * dtl[q]
                if s_w1 != 0.0 or s_w2 != 0.0:
                    for q in range(3):
                        gv[q] = p[q] - D[q]
                    nd = np.sqrt(_dot(gv, gv))
                    for q in range(3):
                        gv[q] = fl * gv[q] / nd - d[q]
                    for (wv, sw) in ((ax, s_w1), (ay, s_w2)):
                        if sw != 0.0:
                            sg = 1.0 if _dot(gv, wv) > 0.0 else -1.0
                            cw = f * sw * sg / bin_m
                            wd = _dot(wv, d)
                            for q in range(3):
                                acc[cb, j, q] -= cw * (wv[q] - wd * d[q]) / r
    # --- per element: the blocks' sums in block order, then centroid, unit normal and area to the vertices
    for j in numba.prange(ne):
        e = e0 + j
        t = np.zeros(_ACC)
        for cb in range(n_cb):
            for q in range(_ACC):
                t[q] += acc[cb, j, q]
        if slope:
            laser_slope_terms(t, tri[e], X0[e], nrm[e], S, wall_n)
        nn = nrm[e]
        xb = t[0:3]
        nb = t[3:6]
        ab = t[6]
        e1 = tri[e, 1] - tri[e, 0]
        e2 = tri[e, 2] - tri[e, 0]
        nr = _cross(e1, e2)
        ln = np.sqrt(_dot(nr, nr))
        nrb = ab * 0.5 * nn + (nb - _dot(nb, nn) * nn) / ln
        e1b = _cross(e2, nrb)
        e2b = _cross(nrb, e1)
        for v in range(3):
            for q in range(3):
                out[e, v, q] += t[7 + 3 * v + q] + xb[q] / 3.0
        for q in range(3):
            out[e, 1, q] += e1b[q]
            out[e, 2, q] += e2b[q]
            out[e, 0, q] -= e1b[q] + e2b[q]


def mesh_vertex_gradients(shapes, prov: np.ndarray, grad_elem: np.ndarray) -> list[np.ndarray]:
    """Pull the element-vertex gradients ``grad_elem [n, 3, 3]`` back to every hidden mesh's vertices: one
    ``[V_s, 3]`` float64 array per shape (order of ``shapes``), through the elements' ``prov [n, 3, 4]``
    (:func:`~._nlos_elements.provenance` on :func:`~._nlos_elements.mesh_triangles`' rows). Deterministic
    (``np.add.at`` adds in order)."""
    src = np.rint(prov[:, 0, 3]).astype(np.int64)
    contrib = np.einsum("evu,evk->euk", prov[:, :, :3], grad_elem)  # [n, source vertex, xyz]
    faces = [np.asarray(s.faces_buffer(), dtype=np.int64).reshape(-1, 3) for s in shapes]
    n_tri = sum(len(f) for f in faces)
    per_tri = np.zeros((n_tri, 3, 3))
    np.add.at(per_tri, src, contrib)
    out, row = [], 0
    for s, f in zip(shapes, faces):
        g = np.zeros((int(s.vertex_count()), 3))
        np.add.at(g, f.ravel(), per_tri[row: row + len(f)].reshape(-1, 3))
        out.append(g)
        row += len(f)
    return out


def is_diffuse(bsdf) -> bool:
    """Whether ``bsdf`` reflects diffusely only (``f`` independent of the directions: ``diffuse``, ``twosided``
    of it; a texture is allowed)."""
    ok = int(mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide
             | mi.BSDFFlags.SpatiallyVarying)
    f = int(bsdf.flags())
    return bool(f & int(mi.BSDFFlags.DiffuseReflection)) and not (f & ~ok)


def flat_shaded(mesh) -> bool:
    """Whether ``mesh``'s shading normal is its faces' geometric normal (no vertex normals, or each face's equal
    to its normal within 1e-5 rad, as a ``rectangle``'s): then the element normal's derivative is the shading
    normal's."""
    if not mesh.has_vertex_normals():
        return True
    v = np.asarray(mesh.vertex_positions_buffer(), dtype=np.float64).reshape(-1, 3)
    n = np.asarray(mesh.vertex_normals_buffer(), dtype=np.float64).reshape(-1, 3)
    f = np.asarray(mesh.faces_buffer(), dtype=np.int64).reshape(-1, 3)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
    cos = np.einsum("fk,fvk->fv", fn, n[f]) / np.maximum(np.linalg.norm(n[f], axis=2), 1e-300)
    return bool(np.all(cos > 1.0 - 5e-11))


def check_geometry(name: str, setup, params, keys) -> None:
    """Refuse, in one line, a geometry parameter the quadrature's reverse mode does not differentiate: anything
    but a hidden mesh's ``vertex_positions`` or ``to_world``, the relay wall's geometry, meshes with vertex
    normals, BSDFs that are not diffuse (of the moving shape or of the relay wall)."""
    hidden = {s.id(): s for s in setup.hidden_shapes}
    wall = setup.relay_wall.id()
    for key in keys:
        node = params.properties[key][2]
        why = None
        if node.id() == wall:
            why = "the relay wall's geometry is not differentiated"
        elif key.rsplit(".", 1)[-1] not in ("vertex_positions", "to_world"):
            why = "only a hidden mesh's vertex_positions or to_world are"
        elif node.id() not in hidden:
            why = "it is not a hidden mesh of the capture"
        elif not flat_shaded(node):
            why = "the mesh has smooth vertex normals (the moving shading normal is not differentiated)"
        elif not is_diffuse(node.bsdf()):
            why = "its BSDF is not diffuse (only a direction-independent f is differentiated in the directions)"
        elif not is_diffuse(setup.relay_wall.bsdf()):
            why = "the relay wall's BSDF is not diffuse"
        if why is not None:
            raise PluginParameterError(f"{name}: {key} is being differentiated; estimator=quadrature cannot: {why} "
                                       "(use estimator=monte_carlo)")


def vertex_backward(shapes, grads, flags) -> None:
    """Back-propagate each shape's vertex gradient ``[V, 3]`` into whatever its vertex buffer is attached to
    (``vertex_positions``, ``to_world``); shapes whose buffer is not attached are skipped."""
    with dr.resume_grad():
        for s, g in zip(shapes, grads):
            buf = s.vertex_positions_buffer()
            if dr.grad_enabled(buf) and np.any(g):
                dr.backward_from(buf * upload(mi.Float, g), flags=flags)
