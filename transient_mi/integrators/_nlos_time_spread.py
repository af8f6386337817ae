r"""Exact time-bin masses of a linear optical path length over a (triangle x parallelogram) element.

The deterministic NLOS estimator (:mod:`transient_mi.integrators._nlos_quadrature`) integrates three-bounce
light element by element: a small triangle ``e`` of hidden surface times a small square cell ``c`` of a
pixel's wall patch. Across such an element the optical path length (OPL) is linear to second order,

.. math::

    \ell(X, p) \approx \ell_0 + g_e \cdot (X - X_0) + g_c \cdot (p - p_0),

and ``X``, ``p`` are independent and uniform on ``e`` and ``c`` (the radiometric weight is taken at the
centre: a midpoint rule). The arrival time ``T`` is then the sum of three independent variables: ``A``,
the linear function over the triangle, whose distribution is the *triangular* distribution on the sorted
vertex values ``t_0 <= t_1 <= t_2`` (the push-forward of area measure by a linear function over a triangle,
a B-spline of degree 1 with knots ``t_0, t_1, t_2``), and two uniforms ``U_1, U_2`` of widths ``w_1, w_2``
centred on 0 (the cell's two edge vectors dotted with ``g_c``). The bin masses are exact for that
distribution, not a deposit at the centre:

.. math::

    P(T \le x) = \Delta_{w_1} \Delta_{w_2} G_2(x + (w_1 + w_2)/2), \qquad
    \Delta_w G(y) = (G(y) - G(y - w)) / w,

with ``G_k(y) = E[(y - A)_+^k] / k!`` (``G_0`` the CDF of ``A``), evaluated piecewise in closed form in
coordinates local to the element (``t_0 = 0``), so no cancellation grows with the time axis. A width
below ``REL_WIDTH_EPS`` of the element's spread is replaced by the derivative at the midpoint
(``\Delta_w G(y) = G'(y - w/2) + O(w^2 G''')``), which avoids dividing round-off by a vanishing width; the
truncation is below 1e-6 of the element's mass.

Units: everything here is in *bins* (time divided by the bin width, origin at the start of the padded
axis). Numba, float64, one thread: the deposit order is fixed (same inputs, same bytes).
"""

from __future__ import annotations

import numba
import numpy as np

#: Widths below this share of an element's total spread are treated as infinitesimal (see module doc).
REL_WIDTH_EPS = 1e-3


@numba.njit(cache=True, fastmath=False)
def _gk(k, y, a, b, mu, var, mu3):
    """``G_k(y)`` (``k = 0..3``) of the triangular distribution with knots ``0 <= a <= b`` (bins); ``mu``, ``var``,
    ``mu3``: its mean, variance and third central moment."""
    if y <= 0.0:
        return 0.0
    if b <= 0.0:  # point mass at 0
        if k == 0:
            return 1.0
        if k == 1:
            return y
        if k == 2:
            return 0.5 * y * y
        return y * y * y / 6.0
    if y >= b:
        d = y - mu
        if k == 0:
            return 1.0
        if k == 1:
            return d
        if k == 2:
            return 0.5 * (d * d + var)
        return (d * d * d + 3.0 * d * var - mu3) / 6.0
    if y <= a:  # (a > 0 here)
        c = 2.0 / (b * a)
        if k == 0:
            return c * y * y / 2.0
        if k == 1:
            return c * y * y * y / 6.0
        if k == 2:
            return c * y * y * y * y / 24.0
        return c * y * y * y * y * y / 120.0
    z = b - y  # a < y < b, so b > a
    c = 2.0 / (b * (b - a))
    d = y - mu
    if k == 0:
        return 1.0 - c * z * z / 2.0
    if k == 1:
        return d + c * z * z * z / 6.0
    if k == 2:
        return 0.5 * (d * d + var) - c * z * z * z * z / 24.0
    return (d * d * d + 3.0 * d * var - mu3) / 6.0 + c * z * z * z * z * z / 120.0


@numba.njit(cache=True, fastmath=False)
def _cdf(x, a, b, w1, w2, mu, var, mu3, small1, small2):
    """``P(A + U_1 + U_2 <= x)``, ``x`` local (``t_0 = 0``), ``U_i`` centred uniforms of widths ``w_i``."""
    y = x + 0.5 * (w1 + w2)
    if small1 and small2:
        return _gk(0, y - 0.5 * (w1 + w2), a, b, mu, var, mu3)
    if small1:
        y1 = y - 0.5 * w1
        return (_gk(1, y1, a, b, mu, var, mu3) - _gk(1, y1 - w2, a, b, mu, var, mu3)) / w2
    if small2:
        y2 = y - 0.5 * w2
        return (_gk(1, y2, a, b, mu, var, mu3) - _gk(1, y2 - w1, a, b, mu, var, mu3)) / w1
    return (_gk(2, y, a, b, mu, var, mu3) - _gk(2, y - w1, a, b, mu, var, mu3) - _gk(2, y - w2, a, b, mu, var, mu3)
            + _gk(2, y - w1 - w2, a, b, mu, var, mu3)) / (w1 * w2)


@numba.njit(cache=True, fastmath=False)
def _hk(k, y, a, b, mu, var, mu3, w, small):
    """``E[(y - A - U)_+^k] / k!`` for ``U`` a centred uniform of width ``w`` (``k = 0..2``; ``small``: ``U = 0``)."""
    if small:
        return _gk(k, y, a, b, mu, var, mu3)
    return (_gk(k + 1, y + 0.5 * w, a, b, mu, var, mu3) - _gk(k + 1, y - 0.5 * w, a, b, mu, var, mu3)) / w


@numba.njit(cache=True, fastmath=False)
def _tilt(x, a, b, w, w_other, mu, var, mu3, small_other):
    """``E[u 1{A + w u + U' <= x}]`` for ``u`` uniform on ``[-1/2, 1/2]`` and ``U'`` a centred uniform of width
    ``w_other`` (``w > 0``): the first moment that a linear amplitude ``1 + alpha u`` across the cell adds to the
    CDF. With ``H(s) = P(A + U' <= s)`` and ``K``, ``K_2`` its first and second integrals,
    ``E = [K_2(x + w/2) - K_2(x - w/2) - (w/2) (K(x - w/2) + K(x + w/2))] / w^2`` (integration by parts)."""
    lo = x - 0.5 * w
    hi = x + 0.5 * w
    k_lo = _hk(1, lo, a, b, mu, var, mu3, w_other, small_other)
    k_hi = _hk(1, hi, a, b, mu, var, mu3, w_other, small_other)
    k2_lo = _hk(2, lo, a, b, mu, var, mu3, w_other, small_other)
    k2_hi = _hk(2, hi, a, b, mu, var, mu3, w_other, small_other)
    return (k2_hi - k2_lo - 0.5 * w * (k_lo + k_hi)) / (w * w)


@numba.njit(cache=True, fastmath=False)
def _masses(buf, tlo, a, b, u1, u2, t1, t2, n_ext):
    """Bin masses of one pair's arrival distribution (knots ``tlo``, ``tlo + a``, ``tlo + b``, widths ``u1``,
    ``u2``, bins of the padded axis; the cell's amplitude ``1 + t1 v1 + t2 v2`` linear in the cell coordinates
    ``v_i`` in ``[-1/2, 1/2]`` along which the arrival time grows by ``u_i``) written to ``buf[first:last + 1]``
    for the bins inside ``[0, n_ext)``; returns ``(first, last, inside)``, ``inside`` the mass inside (summed in
    bin order). The tilts move light within the pair's spread and leave its total unchanged; a tilt along a width
    below ``REL_WIDTH_EPS`` of the spread is dropped (its effect on any bin is ``|t| u / 12`` of the density there).
    The one mass computation of the primal (:func:`spread_spot`) and its adjoint (:func:`adjoint_spot`)."""
    spread = b + u1 + u2
    eps = REL_WIDTH_EPS * spread
    small1 = u1 <= eps
    small2 = u2 <= eps
    tilt1 = t1 != 0.0 and not small1
    tilt2 = t2 != 0.0 and not small2
    mu = (a + b) / 3.0
    var = (a * a + b * b - a * b) / 18.0
    mu3 = (b - 2.0 * a) * (a + b) * (2.0 * b - a) / 270.0
    lo = tlo - 0.5 * (u1 + u2)
    hi = tlo + b + 0.5 * (u1 + u2)
    b0 = int(np.floor(lo))
    b1 = int(np.floor(hi))
    first = max(b0, 0)
    last = min(b1, n_ext - 1)
    prev = 0.0
    inside = 0.0
    for bin_ in range(b0, b1 + 1):
        edge = float(bin_ + 1) - tlo
        if edge + tlo >= hi:
            cur = 1.0
        else:
            cur = _cdf(edge, a, b, u1, u2, mu, var, mu3, small1, small2)
            if tilt1:
                cur += t1 * _tilt(edge, a, b, u1, u2, mu, var, mu3, small2)
            if tilt2:
                cur += t2 * _tilt(edge, a, b, u2, u1, mu, var, mu3, small1)
        m = cur - prev
        prev = cur
        if 0 <= bin_ < n_ext:
            buf[bin_] = m
            inside += m
    return first, last, inside


@numba.njit(cache=True, fastmath=False)
def _spread_one(buf, hist_k, bound_k, f, fe, tlo, a, b, u1, u2, t1, t2, n_ext):
    """Deposit one pair's light ``f`` (and its visibility error ``fe``) into one pixel's rows; returns the light
    arriving outside the padded axis (``buf``: scratch of ``n_ext`` bins for :func:`_masses`)."""
    first, last, inside = _masses(buf, tlo, a, b, u1, u2, t1, t2, n_ext)
    for bin_ in range(first, last + 1):
        m = buf[bin_]
        hist_k[bin_] += f * m
        bound_k[bin_] += fe * m
    return f * (1.0 - inside)


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
    """Pair ``i`` (element ``e``): its smallest knot (bins on the padded axis) and the other two relative to
    it, ``(t_lo, a, b)``, ``0 <= a <= b`` (see :func:`spread_spot`)."""
    l0 = opl_d[i] + r_pv[i, 0] + r_sv[e, 0] + spot_opl
    l1 = opl_d[i] + r_pv[i, 1] + r_sv[e, 1] + spot_opl
    l2 = opl_d[i] + r_pv[i, 2] + r_sv[e, 2] + spot_opl
    lc = opl_d[i] + r_px[i] + r_sx[e] + spot_opl
    shift = 0.75 * (lc - (l0 + l1 + l2) / 3.0) + cell_shift[i]
    t0 = (l0 + shift) / bin_m - t_origin_bins
    t1 = (l1 + shift) / bin_m - t_origin_bins
    t2 = (l2 + shift) / bin_m - t_origin_bins
    if t0 > t1:
        t0, t1 = t1, t0
    if t1 > t2:
        t1, t2 = t2, t1
    if t0 > t1:
        t0, t1 = t1, t0
    return t0, t1 - t0, t2 - t0


@numba.njit(cache=True, fastmath=False)
def spread_pairs(hist, bound, pixel, weight, err_weight, t_lo, knot_a, knot_b, w1, w2, tilt, n_ext):
    """Deposit a list of pairs (one thread, in order): the test interface of :func:`_spread_one`.

    Parameters
    ----------
    hist, bound : ndarray, float64, shape (n_pixels, n_ext)
        Padded histograms and their error, added to in place.
    pixel : ndarray, int64, shape (n,)
        Flat pixel index of each pair.
    weight, err_weight : ndarray, float64, shape (n,)
        Light of the pair and the part of it whose visibility is uncertain.
    t_lo, knot_a, knot_b : ndarray, float64, shape (n,)
        Smallest vertex arrival (bins on the padded axis) and the other two sorted vertex values relative to
        it (``0 <= a <= b``).
    w1, w2 : ndarray, float64, shape (n,)
        Widths of the cell's two uniform components (bins, >= 0).
    tilt : ndarray, float64, shape (n, 2)
        The cell's relative amplitude slopes along the two components (see :func:`_masses`; zeros: flat).
    n_ext : int
        Bins of the padded axis.

    Returns
    -------
    outside : ndarray, float64, shape (n_pixels,)
        Light of each pixel arriving outside the padded axis.
    """
    outside = np.zeros(hist.shape[0])
    buf = np.zeros(n_ext)
    for i in range(pixel.shape[0]):
        k = pixel[i]
        outside[k] += _spread_one(buf, hist[k], bound[k], weight[i], err_weight[i], t_lo[i], knot_a[i], knot_b[i],
                                  w1[i], w2[i], tilt[i, 0], tilt[i, 1], n_ext)
    return outside


@numba.njit(cache=True, parallel=True, fastmath=False)
def spread_spot(hist, bound, steady, vis_err, outside, pixel_start, pair_elem, base, vis_p, r_pv, r_px, opl_d,
                cell_shift, w1, w2, tilt, f_x, vis_s, spot_weight, r_sv, r_sx, spot_opl, bin_m, t_origin_bins):
    """All pairs of one laser spot: weights, visibility, arrival knots, deposits.

    Pairs are sorted by pixel (``pixel_start[k]:pixel_start[k + 1]``); one thread per pixel, its pairs in
    order (same inputs, same bytes).

    Per pair: ``pair_elem`` (element), ``base`` (photons per pulse before the spot leg), ``vis_p[4]``
    (detector-side visibility of the element's samples), ``r_pv[3]`` and ``r_px`` (cell centre to the
    element's vertices and centroid, m), ``opl_d`` (the detector leg to the cell centre, m),
    ``cell_shift`` (mean deviation of the detector-side path length from its tangent plane over the cell, m),
    ``w1, w2`` (the cell's uniform widths, bins), ``tilt[2]`` (the cell's relative amplitude slopes along them,
    :func:`_masses`), ``f_x`` (BSDF at the element towards the spot). Per element
    (this spot): ``vis_s[4]``, ``spot_weight`` (``f_S cos / r^2``), ``r_sv[3]``, ``r_sx`` (m).
    ``spot_opl``: the laser leg (m). ``t_origin_bins``: time zero of the padded axis in path-length bins.

    The triangle's knots are the path lengths at its vertices, shifted by ``3/4`` of the centroid's deviation
    from their mean: for a quadratic path length the linear interpolant's mean error over a triangle is
    exactly ``3/4`` of its error at the centroid (``E[l_i l_j] = 1/12`` against ``1/9`` for barycentric
    coordinates), so the shift removes the leading (convexity) bias of the arrival times; ``cell_shift`` does
    the same for the cell. ``vis_err``: per pixel, the light whose visibility is uncertain (mixed samples).
    """
    n_pix = hist.shape[0]
    n_ext = hist.shape[1]
    for k in numba.prange(n_pix):
        buf = np.empty(n_ext)
        for i in range(pixel_start[k], pixel_start[k + 1]):
            e = pair_elem[i]
            full = base[i] * f_x[i] * spot_weight[e]
            if full == 0.0:
                continue
            nvis, frac = _visible_share(vis_p, vis_s, i, e)
            if nvis == 0:
                continue
            f = full * frac
            fe = 0.0
            if nvis < 4:
                fe = full * max(frac, 1.0 - frac)
            tlo, a, b = _pair_knots(i, e, r_pv, r_px, opl_d, cell_shift, r_sv, r_sx, spot_opl, bin_m, t_origin_bins)
            outside[k] += _spread_one(buf, hist[k], bound[k], f, fe, tlo, a, b, w1[i], w2[i], tilt[i, 0], tilt[i, 1],
                                      n_ext)
            steady[k] += f
            vis_err[k] += fe


@numba.njit(cache=True, parallel=True, fastmath=False)
def adjoint_spot(g, grad_ext, pixel_start, pair_elem, vis_p, r_pv, r_px, opl_d, cell_shift, w1, w2, tilt, vis_s, r_sv,
                 r_sx, spot_opl, bin_m, t_origin_bins):
    """The adjoint of :func:`spread_spot` with respect to the pairs' weights ``full = base f_x spot_weight``:
    per pair ``g = share * sum_b grad_ext[k, b] m_b`` (``k`` its pixel, ``m_b`` the masses of :func:`_masses`,
    ``share`` its visible share), so that ``sum(grad_ext * hist) = sum(g * full)``. ``grad_ext``
    ``[n_pixels, n_ext]``: the adjoint of the padded histograms. ``g`` (float64, one per pair): written for
    the pairs of ``pixel_start`` that see the spot and the cell, left as it is for the others. The other
    arguments as :func:`spread_spot`. Pairs of zero weight get their ``g`` too (a weight's derivative need not
    vanish with it)."""
    n_pix = grad_ext.shape[0]
    n_ext = grad_ext.shape[1]
    for k in numba.prange(n_pix):
        buf = np.empty(n_ext)
        for i in range(pixel_start[k], pixel_start[k + 1]):
            e = pair_elem[i]
            nvis, frac = _visible_share(vis_p, vis_s, i, e)
            if nvis == 0:
                continue
            tlo, a, b = _pair_knots(i, e, r_pv, r_px, opl_d, cell_shift, r_sv, r_sx, spot_opl, bin_m, t_origin_bins)
            first, last, _ = _masses(buf, tlo, a, b, w1[i], w2[i], tilt[i, 0], tilt[i, 1], n_ext)
            acc = 0.0
            for bin_ in range(first, last + 1):
                acc += grad_ext[k, bin_] * buf[bin_]
            g[i] = frac * acc


@numba.njit(cache=True, fastmath=False)
def _cell_amplitude(qx, qy, qz, X, ne, D, ap_n, wall_n):
    """The part of a pair's weight that varies with the wall point ``q`` across a cell (element at ``X``, normal
    ``ne``): the sensor weight's ``cos(aperture) cos(wall, detector) / |q - D|^2``, the wall's cosine towards
    ``X`` (of its Lambertian ``f_p``) and ``cos(theta_X) / |X - q|^2``."""
    vx, vy, vz = qx - D[0], qy - D[1], qz - D[2]
    rd = np.sqrt(vx * vx + vy * vy + vz * vz)
    vx /= rd
    vy /= rd
    vz /= rd
    w0 = max(vx * ap_n[0] + vy * ap_n[1] + vz * ap_n[2], 0.0) * abs(vx * wall_n[0] + vy * wall_n[1] + vz * wall_n[2])
    w0 /= rd * rd
    ux, uy, uz = X[0] - qx, X[1] - qy, X[2] - qz
    r = np.sqrt(ux * ux + uy * uy + uz * uz)
    ux /= r
    uy /= r
    uz /= r
    cos_p = abs(ux * wall_n[0] + uy * wall_n[1] + uz * wall_n[2])
    cos_x = abs(ux * ne[0] + uy * ne[1] + uz * ne[2])
    return w0 * cos_p * cos_x / (r * r)


@numba.njit(cache=True, parallel=True, fastmath=False)
def pair_geometry(ce, ee, cell_p, cell_w0, X0, tri, nrm, area, D, ax, ay, fl, bin_m, photons, has_cells, ap_n,
                  wall_n):
    """Detector-side geometry of every (cell, element) pair, float64 (one pair per iteration, in parallel).

    Returns ``d_px[n, 3]`` (unit, cell centre to centroid), ``r_px``, ``geo`` (photons per pulse before the
    two BSDFs at the wall and the element and the spot leg: ``N W0_cell A_e cos(theta_X) / r_px^2``),
    ``r_pv[n, 3]``, ``opl_d`` (the detector leg, m), ``w1``, ``w2`` (the cell's uniform widths, bins),
    ``cell_shift`` (mean deviation of the detector-side path length from its tangent plane over the cell:
    for a quadratic, 1/3 of the corner mean minus the centre, m) and ``tilt[n, 2]``: the weight's relative
    slope across the cell along each of the two components, signed so that it grows with arrival time
    (:func:`_masses`), from the central difference of :func:`_cell_amplitude` over the cell's edge midpoints
    (exact for a quadratic; the wall's BSDF is taken Lambertian there: its cosine varies, its albedo not).
    ``ap_n``, ``wall_n``: the aperture's and the wall's unit normals.
    """
    n = ce.shape[0]
    d_px = np.empty((n, 3))
    r_px = np.empty(n)
    geo = np.empty(n)
    r_pv = np.empty((n, 3))
    opl_d = np.empty(n)
    w1 = np.empty(n)
    w2 = np.empty(n)
    cell_shift = np.zeros(n)
    tilt = np.zeros((n, 2))
    for i in numba.prange(n):
        c = ce[i]
        e = ee[i]
        px, py, pz = cell_p[c, 0], cell_p[c, 1], cell_p[c, 2]
        dx, dy, dz = X0[e, 0] - px, X0[e, 1] - py, X0[e, 2] - pz
        r = np.sqrt(dx * dx + dy * dy + dz * dz)
        dx /= r
        dy /= r
        dz /= r
        d_px[i, 0] = dx
        d_px[i, 1] = dy
        d_px[i, 2] = dz
        r_px[i] = r
        cos_x = abs(nrm[e, 0] * dx + nrm[e, 1] * dy + nrm[e, 2] * dz)
        geo[i] = photons * cell_w0[c] * area[e] * cos_x / (r * r)
        for v in range(3):
            ux, uy, uz = tri[e, v, 0] - px, tri[e, v, 1] - py, tri[e, v, 2] - pz
            r_pv[i, v] = np.sqrt(ux * ux + uy * uy + uz * uz)
        qx, qy, qz = px - D[0], py - D[1], pz - D[2]
        rd = np.sqrt(qx * qx + qy * qy + qz * qz)
        opl_d[i] = fl * rd
        gx = fl * qx / rd - dx
        gy = fl * qy / rd - dy
        gz = fl * qz / rd - dz
        s1 = (gx * ax[0] + gy * ax[1] + gz * ax[2]) / bin_m
        s2 = (gx * ay[0] + gy * ay[1] + gz * ay[2]) / bin_m
        w1[i] = abs(s1)
        w2[i] = abs(s2)
        if has_cells:
            a0 = _cell_amplitude(px, py, pz, X0[e], nrm[e], D, ap_n, wall_n)
            if a0 > 0.0:
                for j in range(2):
                    hx = 0.5 * (ax[0] if j == 0 else ay[0])
                    hy = 0.5 * (ax[1] if j == 0 else ay[1])
                    hz = 0.5 * (ax[2] if j == 0 else ay[2])
                    d = (_cell_amplitude(px + hx, py + hy, pz + hz, X0[e], nrm[e], D, ap_n, wall_n)
                         - _cell_amplitude(px - hx, py - hy, pz - hz, X0[e], nrm[e], D, ap_n, wall_n)) / a0
                    sj = s1 if j == 0 else s2
                    tilt[i, j] = d if sj >= 0.0 else -d
            acc = 0.0
            for cu in (-0.5, 0.5):
                for cv in (-0.5, 0.5):
                    sx = px + cu * ax[0] + cv * ay[0]
                    sy = py + cu * ax[1] + cv * ay[1]
                    sz = pz + cu * ax[2] + cv * ay[2]
                    a1 = np.sqrt((sx - D[0]) ** 2 + (sy - D[1]) ** 2 + (sz - D[2]) ** 2)
                    a2 = np.sqrt((X0[e, 0] - sx) ** 2 + (X0[e, 1] - sy) ** 2 + (X0[e, 2] - sz) ** 2)
                    acc += fl * a1 + a2
            cell_shift[i] = (acc / 4.0 - (fl * rd + r)) / 3.0
    return d_px, r_px, geo, r_pv, opl_d, w1, w2, cell_shift, tilt


@numba.njit(cache=True, parallel=True, fastmath=False)
def visibility_rays(ce, ee, cell_p, pts, normal, first, count):
    """Rays from every pair's cell centre (offset 1e-6 m along the wall normal) to the element's visibility
    samples ``first .. first + count - 1`` (0 the centroid, 1-3 the corners): float32 origins, unit
    directions ``[n * count, 3]`` and distances ``[n * count]``, sample-minor order."""
    n = ce.shape[0]
    o = np.empty((n * count, 3), dtype=np.float32)
    d = np.empty((n * count, 3), dtype=np.float32)
    dist = np.empty(n * count, dtype=np.float32)
    for i in numba.prange(n):
        c = ce[i]
        e = ee[i]
        ox = cell_p[c, 0] + 1e-6 * normal[0]
        oy = cell_p[c, 1] + 1e-6 * normal[1]
        oz = cell_p[c, 2] + 1e-6 * normal[2]
        for s in range(count):
            j = i * count + s
            vx = pts[e, first + s, 0] - ox
            vy = pts[e, first + s, 1] - oy
            vz = pts[e, first + s, 2] - oz
            r = np.sqrt(vx * vx + vy * vy + vz * vz)
            o[j, 0] = ox
            o[j, 1] = oy
            o[j, 2] = oz
            d[j, 0] = vx / r
            d[j, 1] = vy / r
            d[j, 2] = vz / r
            dist[j] = r
    return o, d, dist
