r"""The per-pair numba kernels of the deterministic NLOS estimator (:mod:`transient_mi.integrators._nlos_quadrature`).

A *chunk* holds the pairs (cell, element) of every cell with the elements ``e0:e1``, cell-major: pair ``i`` is
cell ``i // ne`` and element ``e0 + i % ne`` (``ne = e1 - e0``); a pixel's cells are consecutive, so pixel
``k``'s pairs are ``k * per_pixel .. (k + 1) * per_pixel - 1``. What depends on the pair only (the detector
side: geometry, the wall's BSDF, visibility from the cell) is computed once per chunk
(:func:`pair_geometry`); what depends on the element and the spot (the laser side: the spot's intensity, the
element's Lambertian BSDF towards the spot, visibility from the spot, the laser-side path lengths) once per
(element, spot). :func:`spread_group` then deposits every pair for every spot of the group in one call, one
thread per pixel (its pairs in order, then the spots: same inputs, same bytes).

Arrival knots: the path length at a vertex ``v`` of the element is ``l_v = d_D + |p - X_v| + |X_v - S| + d_L``
(detector leg, the two hidden legs, laser leg; the first and last only with ``include_first_last``), shifted by
``3/4`` of the centroid's deviation from the vertex mean (exact for a quadratic over a triangle: the linear
interpolant's mean error is ``3/4`` of its error at the centroid, ``E[l_i l_j] = 1/12`` against ``1/9`` for
barycentric coordinates) and by the cell's convexity shift. The sum splits into a detector part ``A_v`` (per
pair) and a laser part ``B_v`` (per element and spot), in bins: ``t_v = A_v + B_v``.
"""

from __future__ import annotations

import numba
import numpy as np

from transient_mi.integrators._nlos_cell_curvature import cell_curvature
from transient_mi.integrators._nlos_element_slope import slope_of
from transient_mi.integrators._nlos_time_spread import MASS_FASTMATH, cell_widths, masses


#: The largest ``|t1| + |t2|`` of a cell's amplitude slopes: the linear weight ``1 + t1 v1 + t2 v2`` over the cell
#: (``|v_i| <= 1/2``) stays >= 0 (:func:`pair_geometry`).
MAX_TILT_SUM = 2.0


def _share(mask: int) -> float:
    """The visible share of a pair whose samples ``mask`` (bit ``j``: sample ``j``) see both the cell and the spot:
    centroid 1/2, corners 1/6 each (summed in sample order)."""
    f = 0.0
    for j in range(4):
        if mask >> j & 1:
            f += 0.5 if j == 0 else 1.0 / 6.0
    return f


#: From this many bins on a pair's deposit runs through a view of its row (a loop that vectorises); shorter ones,
#: and the few of mixed visibility, index the rows directly (a view costs more than it saves on two or three bins).
DEPOSIT_VIEW_BINS = 8

#: Visible share and count of visible samples per 4-bit visibility mask.
_SHARE = np.array([_share(m) for m in range(16)])
_NVIS = np.array([bin(m).count("1") for m in range(16)], dtype=np.int64)


@numba.njit(cache=True, fastmath=False)
def _knots(A, B, i, e, s):
    """Pair ``i`` (element ``e``) with spot ``s``: its smallest knot (bins on the padded axis) and the other two
    relative to it, ``(t_lo, a, b)``, ``0 <= a <= b`` (sorted by a min/max network: no branches)."""
    t0 = A[i, 0] + B[e, s, 0]
    t1 = A[i, 1] + B[e, s, 1]
    t2 = A[i, 2] + B[e, s, 2]
    lo = min(t0, t1)
    hi = max(t0, t1)
    mid = max(lo, min(hi, t2))
    lo = min(lo, t2)
    hi = max(hi, t2)
    return lo, mid - lo, hi - lo


@numba.njit(cache=True, fastmath=False, inline="always")
def element_slope(A, B, amp, amp_s, i, e, s, a, b, c1, c2):
    """:func:`slope_of` for pair ``i`` (element ``e``) with spot ``s``: knots ``A[i, v] + B[e, s, v]``, relative
    amplitudes ``amp[i, v] amp_s[e, s, v]`` (detector part per pair, laser part per element and spot); 0 without
    the laser side's (empty ``amp_s``: ``element_slope=false``)."""
    if amp_s.shape[0] == 0:
        return 0.0
    return slope_of(A[i, 0] + B[e, s, 0], A[i, 1] + B[e, s, 1], A[i, 2] + B[e, s, 2],
                    amp[i, 0] * amp_s[e, s, 0], amp[i, 1] * amp_s[e, s, 1], amp[i, 2] * amp_s[e, s, 2], a, b, c1, c2)


@numba.njit(cache=True, parallel=True, fastmath=MASS_FASTMATH)
def spread_group(hist, bound, steady, vis_err, outside, per_pixel, e0, ne, geo, f_p, vis_p, A, w1, w2, tilt, side_x,
                 fx_pair, vis_s, B, sw, fx_e, side_s, lambertian, confocal, amp, amp_s):
    """Every pair of a chunk with every spot of the group: weights, visibility, arrival knots, deposits.

    Outputs (added to), row ``r`` per spot (one row, the pixel's own spot, for ``confocal``): ``hist``, ``bound``
    ``[R, n_pixels, n_ext]`` (light, and light of mixed visibility; ``bound`` may have no bins, ``[R, n_pixels,
    0]``: not deposited), ``steady``, ``vis_err``, ``outside`` ``[R, n_pixels]`` (total light, its
    mixed-visibility part, light arriving outside the padded axis).

    Per pair ``i`` (:func:`pair_geometry`): ``geo`` (photons per pulse before the two BSDFs and the spot leg),
    ``f_p`` (wall BSDF), ``vis_p`` (uint8 mask of the samples seen from the cell,
    :func:`~._nlos_surfaces.visibility_masks`), ``A[3]`` (detector parts of the knots, bins), ``w1, w2`` (the cell's
    uniform widths, bins), ``tilt[2]`` (the cell's amplitude slopes), ``side_x`` (side of the element's shading
    normal the cell lies on), ``fx_pair[r, i]`` (the element's BSDF towards the spot, for ``lambertian=False``). Per
    element ``e`` and spot ``s``: ``vis_s[e, s]`` (mask of the samples seen from the spot), ``B[e, s, 3]`` (laser
    parts of the knots, bins, with the axis origin), ``sw[e, s]`` (spot intensity over ``r_SX^2``), and for
    ``lambertian``: ``fx_e[e, s]`` (the BSDF with ``wi = wo``) and ``side_s[e, s]`` (the spot's side), a pair's
    ``f_x`` being ``fx_e`` when its cell lies on the spot's side and 0 otherwise.

    ``amp [n, 3]`` (per pair) and ``amp_s [n_e, G, 3]`` (per element and spot): the relative amplitudes at the
    element's vertices whose regression on the knots is the element's slope (:func:`element_slope`; an empty
    ``amp_s``: none). A pair's light is ``geo f_p f_x sw`` times the visible share of its samples, spread by
    :func:`~._nlos_time_spread.masses` with that slope; where the samples disagree, ``max(share, 1 - share)`` of it
    goes to ``bound`` and ``vis_err``.
    """
    n_pix = hist.shape[1]
    n_ext = hist.shape[2]
    G = sw.shape[1]
    keep_bound = bound.shape[2] > 0  # a level that only feeds the error estimate passes no bins for it
    for k in numba.prange(n_pix):
        buf = np.empty(n_ext)
        s_lo = k if confocal else 0
        s_hi = k + 1 if confocal else G
        for i in range(k * per_pixel, (k + 1) * per_pixel):
            base = geo[i] * f_p[i]
            mp = vis_p[i]
            if base == 0.0 or mp == 0:
                continue
            e = e0 + i % ne
            sx = side_x[i]
            cell = cell_widths(w1[i], w2[i], tilt[i, 0], tilt[i, 1])
            for s in range(s_lo, s_hi):
                row = 0 if confocal else s
                if lambertian:
                    if sx * side_s[e, s] <= 0:
                        continue
                    full = base * fx_e[e, s] * sw[e, s]
                else:
                    full = base * fx_pair[row, i] * sw[e, s]
                m = mp & vis_s[e, s]
                if full == 0.0 or m == 0:
                    continue
                frac = _SHARE[m]
                f = full * frac
                tlo, a, b = _knots(A, B, i, e, s)
                beta = element_slope(A, B, amp, amp_s, i, e, s, a, b, tilt[i, 0], tilt[i, 1])
                first, last, inside = masses(buf, tlo, a, b, cell, n_ext, beta)
                if _NVIS[m] < 4:
                    fe = full * max(frac, 1.0 - frac)
                    if keep_bound:
                        for bin_ in range(first, last + 1):
                            hist[row, k, bin_] += f * buf[bin_]
                            bound[row, k, bin_] += fe * buf[bin_]
                    else:
                        for bin_ in range(first, last + 1):
                            hist[row, k, bin_] += f * buf[bin_]
                    vis_err[row, k] += fe
                elif last - first < DEPOSIT_VIEW_BINS:
                    for bin_ in range(first, last + 1):
                        hist[row, k, bin_] += f * buf[bin_]
                else:  # (views indexed from 0: the loop runs several bins per instruction)
                    mv = buf[first:last + 1]
                    hv = hist[row, k, first:last + 1]
                    for j in range(mv.shape[0]):
                        hv[j] += f * mv[j]
                outside[row, k] += f * (1.0 - inside)
                steady[row, k] += f


@numba.njit(cache=True, parallel=True, fastmath=MASS_FASTMATH)
def adjoint_group(g, grad_ext, per_pixel, e0, ne, vis_p, A, w1, w2, tilt, vis_s, B, confocal, amp, amp_s):
    """The adjoint of :func:`spread_group` with respect to the pairs' weights ``full = geo f_p f_x sw``: per pair
    and spot ``g[r, i] = share * sum_b grad_ext[r, k, b] m_b`` (``k`` the pair's pixel, ``m_b`` the masses of
    :func:`~._nlos_time_spread.masses`, ``share`` its visible share), so that ``sum(grad_ext * hist) =
    sum(g * full)``. ``grad_ext`` ``[R, n_pixels, n_ext]``: the adjoint of the padded histograms. ``g``
    ``[R, n_pairs]`` float64: written for the pairs that see the spot and the cell, left as it is for the
    others; pairs of zero weight get theirs too (a weight's derivative need not vanish with it). The other
    arguments as :func:`spread_group`."""
    n_pix = grad_ext.shape[1]
    n_ext = grad_ext.shape[2]
    G = B.shape[1]
    for k in numba.prange(n_pix):
        buf = np.empty(n_ext)
        s_lo = k if confocal else 0
        s_hi = k + 1 if confocal else G
        for i in range(k * per_pixel, (k + 1) * per_pixel):
            e = e0 + i % ne
            cell = cell_widths(w1[i], w2[i], tilt[i, 0], tilt[i, 1])
            for s in range(s_lo, s_hi):
                row = 0 if confocal else s
                m = vis_p[i] & vis_s[e, s]
                if m == 0:
                    continue
                tlo, a, b = _knots(A, B, i, e, s)
                beta = element_slope(A, B, amp, amp_s, i, e, s, a, b, tilt[i, 0], tilt[i, 1])
                first, last, _ = masses(buf, tlo, a, b, cell, n_ext, beta)
                acc = 0.0
                for bin_ in range(first, last + 1):
                    acc += grad_ext[row, k, bin_] * buf[bin_]
                g[row, i] = _SHARE[m] * acc


def cell_terms(cell_p: np.ndarray, D: np.ndarray, ax: np.ndarray, ay: np.ndarray, fl: float, ap_n: np.ndarray,
               wall_n: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What :func:`pair_geometry` needs of each cell alone (cells ``[C, 3]``, edge vectors ``ax``, ``ay``):
    ``rd [C]`` (m) and ``uq [C, 3]``, distance and direction from the detector ``D``; ``w0 [C, 5]``, the sensor
    weight's varying part ``cos(aperture) cos(wall, detector) / |q - D|^2`` at the centre and at the edge
    midpoints ``+ax/2, -ax/2, +ay/2, -ay/2``; ``corner_d [C]``, the detector legs ``fl |q - D|`` summed over the
    cell's four corners (m)."""
    v = cell_p - D
    rd = np.linalg.norm(v, axis=1)
    uq = v / rd[:, None]
    w0 = np.empty((len(cell_p), 5))
    for j, off in enumerate((0.0 * ax, 0.5 * ax, -0.5 * ax, 0.5 * ay, -0.5 * ay)):
        q = v + off
        r = np.linalg.norm(q, axis=1)
        u = q / r[:, None]
        w0[:, j] = np.maximum(u @ ap_n, 0.0) * np.abs(u @ wall_n) / r ** 2
    corner_d = np.zeros(len(cell_p))
    for cu in (-0.5, 0.5):
        for cv in (-0.5, 0.5):
            corner_d += fl * np.linalg.norm(v + cu * ax + cv * ay, axis=1)
    return rd, np.ascontiguousarray(uq), w0, corner_d


@numba.njit(cache=True, fastmath=False)
def _side(v):
    return 1 if v > 0.0 else (-1 if v < 0.0 else 0)


@numba.njit(cache=True, fastmath=False)
def _amplitude_parts(X, q0, q1, q2, ne, wall_n):
    """``(|u . n_wall| |u . n_e|, |u|^4)`` for ``u = X - q``: the wall's cosine times ``cos(theta_X)`` over
    ``|X - q|^2`` is their ratio (no square root)."""
    ux, uy, uz = X[0] - q0, X[1] - q1, X[2] - q2
    u2 = ux * ux + uy * uy + uz * uz
    return (abs(ux * wall_n[0] + uy * wall_n[1] + uz * wall_n[2]) * abs(ux * ne[0] + uy * ne[1] + uz * ne[2]),
            u2 * u2)


#: Chunks of fewer pairs than this run :func:`pair_geometry` on one thread: about 50 ns a pair (12 ms at this size),
#: where a parallel region cost more than it saved on the shared 2-core machine (its threads wait for a core: the
#: confocal 32 x 32 benchmark's render, 172,032 pairs in its largest chunk, took 0.29 s against 0.32 s median,
#: 0.15 s of CPU against 0.18 s, at load 9). Same bytes either way (the pairs are independent).
PARALLEL_MIN_PAIRS = 1 << 18


def pair_geometry(cell_p, cell_w0, rd_c, uq_c, w0_c, corner_d, X0, tri, nrm, area, n_sh, wall_n_sh, wall_side, e0, e1,
                  ax, ay, fl, bin_m, photons, has_cells, wall_n, per_pixel, vis_s, side_s, wall_lambertian, lambertian,
                  confocal, out=None, slope=True, owned=None):
    """:func:`_pair_geometry` (its docstring has the arguments and results), on one thread for a chunk of fewer than
    :data:`PARALLEL_MIN_PAIRS` pairs. ``out``, optional: :func:`pair_results` of at least the chunk's pairs, which
    the results are written to (their first rows; a level's chunks reuse one set: see :func:`pair_results`).
    ``owned``, optional: bool ``[n]``, the pairs this level's elements integrate after the visibility refinement
    (:meth:`~._nlos_refinement.Refinement.owned`); the others get no light and no geometry (``None``: every pair)."""
    n = len(cell_p) * (e1 - e0)
    out = pair_results(n) if out is None else tuple(a[:n] for a in out)
    owned = np.ones(0, dtype=np.bool_) if owned is None else owned
    args = (cell_p, cell_w0, rd_c, uq_c, w0_c, corner_d, X0, tri, nrm, area, n_sh, wall_n_sh, wall_side, e0, e1, ax,
            ay, fl, bin_m, photons, has_cells, wall_n, per_pixel, vis_s, side_s, wall_lambertian, lambertian, confocal,
            bool(slope), owned, *out)
    if n >= PARALLEL_MIN_PAIRS:
        return _pair_geometry(*args)
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        return _pair_geometry(*args)
    finally:
        numba.set_num_threads(threads)


def pair_results(n: int) -> tuple:
    """Arrays for :func:`pair_geometry`'s results of ``n`` pairs: ``geo``, ``cos_p``, ``A [n, 3]``, ``w1``, ``w2``,
    ``tilt [n, 2]`` (float64), ``side_x`` (int8), ``lit`` (bool), ``amp [n, 3]`` (float64); uninitialised (the
    kernel writes every row).

    Allocated by numpy, which asks the kernel for huge pages for large arrays (``madvise``), and reused by a level's
    chunks: first touching fresh 4 KiB pages for about 75 bytes a pair (a chunk of 2^20 pairs: 80 MB), chunk after
    chunk, cost more system time than the geometry itself took (the paper scene's 32 x 32 capture: 1.2 million page
    faults a render and 6 s of system time over its two cores, when the kernel allocated them)."""
    return (np.empty(n), np.empty(n), np.empty((n, 3)), np.empty(n), np.empty(n), np.empty((n, 2)),
            np.empty(n, dtype=np.int8), np.empty(n, dtype=np.bool_), np.empty((n, 3)))


@numba.njit(cache=True, fastmath=False, inline="always")
def _no_light(i, A, w1, w2, tilt, amp):
    """Pair ``i`` of :func:`_pair_geometry` without light: knots, widths and slopes 0, amplitude ratios 1."""
    for j in range(3):
        A[i, j] = 0.0
        amp[i, j] = 1.0
    w1[i] = 0.0
    w2[i] = 0.0
    tilt[i, 0] = 0.0
    tilt[i, 1] = 0.0


@numba.njit(cache=True, parallel=True, fastmath=False)
def _pair_geometry(cell_p, cell_w0, rd_c, uq_c, w0_c, corner_d, X0, tri, nrm, area, n_sh, wall_n_sh, wall_side, e0,
                   e1, ax, ay, fl, bin_m, photons, has_cells, wall_n, per_pixel, vis_s, side_s, wall_lambertian,
                   lambertian, confocal, slope, owned, geo, cos_p, A, w1, w2, tilt, side_x, lit, amp):
    """Detector-side geometry of the chunk's pairs (cells x elements ``e0:e1``, cell-major), float64, one pair per
    iteration in parallel; ``rd_c``, ``uq_c``, ``w0_c``, ``corner_d``: :func:`cell_terms`; ``per_pixel`` (pairs
    per pixel), ``vis_s``, ``side_s``, ``lambertian``, ``confocal``: as :func:`spread_group`, ``wall_lambertian``
    whether the wall's BSDF is Lambertian.

    Which pairs can carry light for some spot of the group is decided first, by geometry alone (so a zero BSDF
    value or intensity still gets its derivative): ``geo > 0``, the element in front of a Lambertian wall
    (``cos_p > 0``), and a spot that sees one of the element's samples, on the cell's side of a Lambertian element.
    The others (about half of the paper mannequin's: the elements facing away from the wall) have no light and no
    derivative whatever their visibility from the cell: their knots, widths and slopes are not computed (0; every
    kernel skips a pair without light before reading them), and ``lit`` (bool ``[n]``) says which are which.
    So are the pairs outside ``owned`` (bool ``[n]``; empty: every pair owned), which other elements of a refined
    level integrate: on the paper scene's 32 x 32 capture at 1 s (10 mm elements, three visibility levels) 117 of
    the 645 million pairs with light by geometry stay with their element, a scratch count; their ``geo``,
    ``cos_p`` and ``side_x`` are 0 too.

    Returns ``geo`` (photons per pulse before the two BSDFs and the spot leg: ``N W0_cell A_e cos(theta_X) /
    r_px^2``), ``cos_p`` (the wall's ``|cos|`` towards the element where it lies on the side of the wall's
    ``wi``, ``wall_side``, else 0: a Lambertian wall's ``f_p`` over its per-cell value), ``A[n, 3]`` (the detector
    parts of the three knots, bins: the detector leg, the cell-to-vertex legs, the 3/4 centroid shift's
    detector part and the cell's shift; module docstring), ``w1``, ``w2`` (the cell's uniform widths, bins),
    ``tilt[n, 2]`` (the weight's relative slope across the cell along each width, signed so that it grows with
    arrival time, :func:`~._nlos_time_spread.masses`: the central difference over the cell's edge midpoints of
    the weight's varying part, the sensor weight's ``cos cos / |q - D|^2``, the wall's cosine and
    ``cos(theta_X) / |X - q|^2``, exact for a quadratic; the wall's BSDF is taken Lambertian there: its cosine
    varies, its albedo not; plus the path length's curvature along each width, :func:`cell_curvature`) and
    ``side_x`` int8 (the side of the element's shading normal ``n_sh`` the cell centre lies on). The cell's shift is
    the mean deviation of the detector-side path length from its tangent plane over the cell: for a quadratic, 1/3
    of the corner mean minus the centre (m), plus :func:`cell_curvature`'s shifts. ``wall_n``: the wall's
    unit normal. ``lit``, then ``amp[n, 3]``: the detector side's part of the weight at the element's vertices
    over its value at the centroid (the wall's cosine at the cell times the element's over ``|V - p|^2``; 1 without
    ``slope`` and for unlit pairs), which :func:`~._nlos_element_slope.slope_of` regresses on the knots. The results
    are written to the last nine arguments, in that order (``n = C ne`` rows, every one written).
    """
    C = cell_p.shape[0]
    ne = e1 - e0
    n = C * ne
    G = side_s.shape[1]
    inv_bin = 1.0 / bin_m
    restricted = owned.shape[0] > 0
    for i in numba.prange(n):
        c = i // ne
        e = e0 + i - c * ne
        if restricted and not owned[i]:  # (another element of the level integrates the pair)
            geo[i] = 0.0
            cos_p[i] = 0.0
            side_x[i] = 0
            lit[i] = False
            _no_light(i, A, w1, w2, tilt, amp)
            continue
        px, py, pz = cell_p[c, 0], cell_p[c, 1], cell_p[c, 2]
        dx, dy, dz = X0[e, 0] - px, X0[e, 1] - py, X0[e, 2] - pz
        r = np.sqrt(dx * dx + dy * dy + dz * dz)
        inv_r = 1.0 / r
        dx *= inv_r
        dy *= inv_r
        dz *= inv_r
        cos_x = abs(nrm[e, 0] * dx + nrm[e, 1] * dy + nrm[e, 2] * dz)
        geo[i] = photons * cell_w0[c] * area[e] * cos_x * inv_r * inv_r
        cw = wall_n_sh[c, 0] * dx + wall_n_sh[c, 1] * dy + wall_n_sh[c, 2] * dz
        cos_p[i] = abs(cw) if _side(cw) * wall_side[c] > 0 else 0.0
        side_x[i] = _side(-(n_sh[e, 0] * dx + n_sh[e, 1] * dy + n_sh[e, 2] * dz))
        on = False
        if geo[i] != 0.0 and not (wall_lambertian and cos_p[i] == 0.0):
            k = i // per_pixel
            s_lo = k if confocal else 0
            s_hi = k + 1 if confocal else G
            for s in range(s_lo, s_hi):
                if vis_s[e, s] != 0 and (not lambertian or side_x[i] * side_s[e, s] > 0):
                    on = True
                    break
        lit[i] = on
        if not on:
            _no_light(i, A, w1, w2, tilt, amp)
            continue
        tilt[i, 0] = 0.0
        tilt[i, 1] = 0.0
        amp[i, 0] = 1.0
        amp[i, 1] = 1.0
        amp[i, 2] = 1.0
        r_pv0 = np.sqrt((tri[e, 0, 0] - px) ** 2 + (tri[e, 0, 1] - py) ** 2 + (tri[e, 0, 2] - pz) ** 2)
        r_pv1 = np.sqrt((tri[e, 1, 0] - px) ** 2 + (tri[e, 1, 1] - py) ** 2 + (tri[e, 1, 2] - pz) ** 2)
        r_pv2 = np.sqrt((tri[e, 2, 0] - px) ** 2 + (tri[e, 2, 1] - py) ** 2 + (tri[e, 2, 2] - pz) ** 2)
        gx = fl * uq_c[c, 0] - dx
        gy = fl * uq_c[c, 1] - dy
        gz = fl * uq_c[c, 2] - dz
        s1 = (gx * ax[0] + gy * ax[1] + gz * ax[2]) * inv_bin
        s2 = (gx * ay[0] + gy * ay[1] + gz * ay[2]) * inv_bin
        w1[i] = abs(s1)
        w2[i] = abs(s2)
        cell_shift = 0.0
        # the detector side's amplitude parts at the centroid, which the cell's tilt and the element's slope share
        n0, q0 = _amplitude_parts(X0[e], px, py, pz, nrm[e], wall_n) if has_cells or slope else (0.0, 1.0)
        if has_cells:
            a0 = w0_c[c, 0] * n0
            if a0 > 0.0:
                for j in range(2):
                    hx = 0.5 * (ax[0] if j == 0 else ay[0])
                    hy = 0.5 * (ax[1] if j == 0 else ay[1])
                    hz = 0.5 * (ax[2] if j == 0 else ay[2])
                    n_p, q_p = _amplitude_parts(X0[e], px + hx, py + hy, pz + hz, nrm[e], wall_n)
                    n_m, q_m = _amplitude_parts(X0[e], px - hx, py - hy, pz - hz, nrm[e], wall_n)
                    # (a(+) - a(-)) / a(0) with a = w0 N / Q
                    d = ((w0_c[c, 1 + 2 * j] * n_p * q_m - w0_c[c, 2 + 2 * j] * n_m * q_p) * q0
                         / (q_p * q_m * a0))
                    sj = s1 if j == 0 else s2
                    tilt[i, j] = d if sj >= 0.0 else -d
            # the path length's curvature along each edge: a later centre and a falling density (cell_curvature)
            l0 = fl * rd_c[c] + r
            D0, D1, D2 = px - rd_c[c] * uq_c[c, 0], py - rd_c[c] * uq_c[c, 1], pz - rd_c[c] * uq_c[c, 2]
            sh1, tc1 = cell_curvature(X0[e], px, py, pz, D0, D1, D2, l0, ax[0], ax[1], ax[2], fl, s1 * bin_m)
            sh2, tc2 = cell_curvature(X0[e], px, py, pz, D0, D1, D2, l0, ay[0], ay[1], ay[2], fl, s2 * bin_m)
            tilt[i, 0] += tc1
            tilt[i, 1] += tc2
            # the linear weight 1 + t1 v1 + t2 v2 (|v| <= 1/2) must not go below 0 at a corner: where the
            # geometric factors vary that much across the cell (grazing), the slopes are scaled down to
            # |t1| + |t2| = 2, the weight 0 at one corner (else bins could come out negative)
            tsum = abs(tilt[i, 0]) + abs(tilt[i, 1])
            if tsum > MAX_TILT_SUM:
                tilt[i, 0] *= MAX_TILT_SUM / tsum
                tilt[i, 1] *= MAX_TILT_SUM / tsum
            acc = corner_d[c]
            for cu in (-0.5, 0.5):
                for cv in (-0.5, 0.5):
                    sx = px + cu * ax[0] + cv * ay[0]
                    sy = py + cu * ax[1] + cv * ay[1]
                    sz = pz + cu * ax[2] + cv * ay[2]
                    acc += np.sqrt((X0[e, 0] - sx) ** 2 + (X0[e, 1] - sy) ** 2 + (X0[e, 2] - sz) ** 2)
            cell_shift = (acc * 0.25 - (fl * rd_c[c] + r)) * (1.0 / 3.0) + sh1 + sh2
        if slope and n0 > 0.0:
            for v in range(3):
                nv, qv = _amplitude_parts(tri[e, v], px, py, pz, nrm[e], wall_n)
                amp[i, v] = nv * q0 / (qv * n0)
        base = fl * rd_c[c] + 0.75 * (r - (r_pv0 + r_pv1 + r_pv2) * (1.0 / 3.0)) + cell_shift
        A[i, 0] = (base + r_pv0) * inv_bin
        A[i, 1] = (base + r_pv1) * inv_bin
        A[i, 2] = (base + r_pv2) * inv_bin
    return geo, cos_p, A, w1, w2, tilt, side_x, lit, amp


def spot_knots(tri: np.ndarray, X0: np.ndarray, S: np.ndarray, spot_opl: np.ndarray, bin_m: float,
               t_origin_bins: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The laser parts of the knots ``B [n, G, 3]`` (bins, with the padded axis's origin ``t_origin_bins``
    subtracted: module docstring), ``r_SV [n, G, 3]`` and ``r_SX [n, G]`` (m) of every element (vertices
    ``tri [n, 3, 3]``, centroids ``X0``) for the spots ``S [G, 3]`` with laser legs ``spot_opl [G]`` (m, 0 without
    ``include_first_last``). One pass over the (element, spot) combinations (a confocal capture has one per element
    and pixel), in the order and rounding of the numpy expressions in :func:`_spot_knots` (same bytes)."""
    n, G = len(tri), len(S)
    B, r_sv, r_sx = np.empty((n, G, 3)), np.empty((n, G, 3)), np.empty((n, G))
    _spot_knots(np.ascontiguousarray(tri, dtype=np.float64), np.ascontiguousarray(X0, dtype=np.float64),
                np.ascontiguousarray(S, dtype=np.float64), np.ascontiguousarray(spot_opl, dtype=np.float64),
                float(bin_m), float(t_origin_bins), B, r_sv, r_sx)
    return B, r_sv, r_sx


@numba.njit(cache=True, fastmath=False)
def _dist(a0, a1, a2, b0, b1, b2):
    """``|a - b|`` summed as numpy's ``norm`` along a length-3 axis: ``sqrt((d0^2 + d1^2) + d2^2)``."""
    d0, d1, d2 = a0 - b0, a1 - b1, a2 - b2
    return np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)


@numba.njit(cache=True, fastmath=False)
def _spot_knots(tri, X0, S, spot_opl, bin_m, t_origin_bins, B, r_sv, r_sx):
    """:func:`spot_knots` into ``B``, ``r_sv``, ``r_sx``: ``r_sv = |V - S|``, ``r_sx = |X0 - S|``, ``base =
    spot_opl + 0.75 (r_sx - (r_sv0 + r_sv1 + r_sv2) / 3)``, ``B = (base + r_sv) / bin_m - t_origin_bins``
    (single-threaded: a few nanoseconds per combination, less than a parallel launch costs on a busy machine)."""
    for e in range(tri.shape[0]):
        for s in range(S.shape[0]):
            s0, s1, s2 = S[s, 0], S[s, 1], S[s, 2]
            for v in range(3):
                r_sv[e, s, v] = _dist(tri[e, v, 0], tri[e, v, 1], tri[e, v, 2], s0, s1, s2)
            rx = _dist(X0[e, 0], X0[e, 1], X0[e, 2], s0, s1, s2)
            r_sx[e, s] = rx
            base = spot_opl[s] + 0.75 * (rx - (r_sv[e, s, 0] + r_sv[e, s, 1] + r_sv[e, s, 2]) / 3.0)
            for v in range(3):
                B[e, s, v] = (base + r_sv[e, s, v]) / bin_m - t_origin_bins
