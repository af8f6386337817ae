r"""Exact time-bin masses of a linear optical path length over a (triangle x parallelogram) element.

The deterministic NLOS estimator (:mod:`transient_mi.integrators._nlos_quadrature`) integrates three-bounce
light element by element: a small triangle ``e`` of hidden surface times a small square cell ``c`` of a
pixel's wall patch. Across such an element the optical path length (OPL) is linear to second order,

.. math::

    \ell(X, p) \approx \ell_0 + g_e \cdot (X - X_0) + g_c \cdot (p - p_0),

and ``X``, ``p`` are independent and uniform on ``e`` and ``c`` (the radiometric weight is taken at the
centre -- a midpoint rule -- with first-order slopes: the cell's along its two widths, the element's in arrival
time, ``1 + beta (A - mu)``; each moves light within the pair, :func:`masses`). The arrival time ``T`` is then the sum of three independent variables: ``A``,
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

From ``VECTOR_EDGES`` bins on (the paper scene's 1 ps bins: about 80 per pair) the CDF is evaluated at every
edge first and the masses are its differences, in one pass from the first bin up, each loop over a view indexed
from 0 (numba cannot vectorise a loop whose array index could be negative: the views made these loops, and
:func:`~._nlos_pair_kernels.spread_group`'s deposits of pairs of ``DEPOSIT_VIEW_BINS`` bins or more, run several
bins per instruction). The edges split in two runs: where the four points ``x +- h1 +- h2`` all lie at or above
``a`` the polynomial parts of ``G_2`` and ``G_3`` cancel in closed form over the two widths and only the tails
``(b - y)_+`` are summed (:func:`_cdf_far`, a third of the work of evaluating every point's piece); the edges
before take every piece (:func:`_cdf_widths`). On the paper scene's 32 x 32 capture at 1 ps bins the two runs and
the pass from the first bin up took about a tenth off the bin masses and deposits (one run after the other on one
machine: ``bench/results/quadrature_profile_paper_masses.json`` against ``..._before_masses.json``).

Units: everything here is in *bins* (time divided by the bin width, origin at the start of the padded
axis). Numba, float64, one thread: the deposit order is fixed (same inputs, same bytes).
"""

from __future__ import annotations

import numba
import numpy as np

#: Widths below this share of an element's total spread are treated as infinitesimal (see module doc).
REL_WIDTH_EPS = 1e-3
#: From this many bins on, a pair's CDF is evaluated at all its edges first (a loop the compiler vectorises).
VECTOR_EDGES = 4
#: Numba's floating-point flags of the bin-mass kernels (and of the deposits that call them): ``x * y + z`` may be
#: contracted into one fused multiply-add (one rounding instead of two: as accurate or more). Nothing is
#: reassociated, so every sum keeps its order and one machine gives the same bytes run after run; a CPU without
#: FMA instructions gives other last bits (as the golden hashes' CPU classes already differ). On the paper scene's
#: 32 x 32 capture at 1 ps bins it took about a tenth off the three levels (a scratch comparison, back to back on
#: one machine, 2 cores).
MASS_FASTMATH = {"contract"}


_INV3 = 1.0 / 3.0
_INV6 = 1.0 / 6.0
_INV18 = 1.0 / 18.0
_INV24 = 1.0 / 24.0
_INV120 = 1.0 / 120.0
_INV270 = 1.0 / 270.0


@numba.njit(cache=True, fastmath=MASS_FASTMATH, inline="always")
def _shape(a, b):
    """The constants of the triangular distribution with knots ``0 <= a <= b`` (bins) that :func:`_g0`,
    :func:`_g12` and :func:`_g23` read: ``(a, b, mu, var / 2, mu_3 / 6, c_a / 2, c_a / 6, c_a / 24, c_a / 120,
    c_b / 2, c_b / 6, c_b / 24, c_b / 120)`` with its mean ``mu``, variance ``var`` and third central moment
    ``mu_3``, ``c_a = 2 / (a b)`` and ``c_b = 2 / (b (b - a))`` (0 where their denominators vanish: those pieces
    are then empty)."""
    ca = 2.0 / (b * a) if a > 0.0 else 0.0
    cb = 2.0 / (b * (b - a)) if b > a else 0.0
    var = (a * a + b * b - a * b) * _INV18
    mu3 = (b - 2.0 * a) * (a + b) * (2.0 * b - a) * _INV270
    return (a, b, (a + b) * _INV3, 0.5 * var, mu3 * _INV6, 0.5 * ca, ca * _INV6, ca * _INV24, ca * _INV120,
            0.5 * cb, cb * _INV6, cb * _INV24, cb * _INV120)


@numba.njit(cache=True, fastmath=MASS_FASTMATH, inline="always")
def _g0(y, k):
    """``G_0(y)``, the CDF of the triangular distribution of :func:`_shape` ``k``."""
    if y <= 0.0:
        return 0.0
    if y <= k[0]:
        return k[5] * y * y
    z = max(k[1] - y, 0.0)
    return 1.0 - k[9] * z * z


@numba.njit(cache=True, fastmath=MASS_FASTMATH, inline="always")
def _g12(y, k):
    """``(G_1(y), G_2(y))`` with ``G_k(y) = E[(y - A)_+^k] / k!`` (as :func:`_g23`)."""
    yp = max(y, 0.0)
    y3 = yp * yp * yp
    z = max(k[1] - y, 0.0)
    z3 = z * z * z
    d = y - k[2]
    if y <= k[0]:
        return k[6] * y3, k[7] * y3 * yp
    return d + k[10] * z3, 0.5 * d * d + k[3] - k[11] * z3 * z


@numba.njit(cache=True, fastmath=MASS_FASTMATH, inline="always")
def _g23(y, k):
    """``(G_2(y), G_3(y))`` of the triangular distribution of :func:`_shape` ``k`` (knots ``0 <= a <= b``, bins),
    piecewise in closed form: 0 below 0; ``c_a y^(j+2) / (j+2)!`` up to ``a``; from ``b`` on the polynomial of
    its moments, and between ``a`` and ``b`` that polynomial minus ``c_b (b - y)^(j+2) / (j+2)!`` (with the sign
    of ``(-1)^j``), so no cancellation grows with the spread. ``(b - y)_+`` vanishes from ``b`` on and ``y_+``
    below 0, so two forms cover the four pieces."""
    yp = max(y, 0.0)
    y2 = yp * yp
    y4 = y2 * y2
    z = max(k[1] - y, 0.0)
    z2 = z * z
    z4 = z2 * z2
    d = y - k[2]
    d2 = d * d
    near = y <= k[0]  # (a select, not a branch: the edge loop of masses vectorises)
    return (k[7] * y4 if near else 0.5 * d2 + k[3] - k[11] * z4,
            k[8] * y4 * yp if near else d * (d2 * _INV6 + k[3]) - k[4] + k[12] * z4 * z)


@numba.njit(cache=True, fastmath=MASS_FASTMATH, inline="always")
def _cdf_widths(x, k, h1, h2, c0, c1, c2, c3):
    """:func:`_cdf` with both widths finite: ``G_2`` and ``G_3`` at the four points ``x +- h1 +- h2``, no branch
    but the pieces' (the tilt terms are added with their factors, 0 without a tilt; the element's, ``c3``, reads
    ``H_2(y) - mu G_2(y) = (y - mu) G_2(y) - 3 G_3(y)`` at the same points)."""
    pp2, pp3 = _g23(x + h1 + h2, k)
    mp2, mp3 = _g23(x - h1 + h2, k)
    pm2, pm3 = _g23(x + h1 - h2, k)
    mm2, mm3 = _g23(x - h1 - h2, k)
    d3 = pp3 - mp3 - pm3 + mm3
    d2 = pp2 - mp2 - pm2 + mm2
    cur = d2 * c0 + (c1 * (d3 - h1 * (pp2 + mp2 - pm2 - mm2)) + c2 * (d3 - h2 * (pp2 + pm2 - mp2 - mm2)))
    if c3 != 0.0:
        cur += c3 * (((x - k[2]) * d2 + h1 * (pp2 + mp2 - pm2 - mm2) + h2 * (pp2 + pm2 - mp2 - mm2)) - 3.0 * d3)
    return cur


@numba.njit(cache=True, fastmath=MASS_FASTMATH, inline="always")
def _far_factors(k, h1, h2, c0, c1, c2, c3):
    """The factors of :func:`_cdf_far` for one pair: ``(P_A, P_X, P_B, P_1, P_2)``."""
    return (-c0 * k[11], -c3 * k[11], (c1 + c2 - 3.0 * c3) * k[12], h1 * k[11] * (c1 - c3),
            h2 * k[11] * (c2 - c3))


@numba.njit(cache=True, fastmath=MASS_FASTMATH, inline="always")
def _cdf_far(x, k, h1, h2, f):
    """:func:`_cdf_widths` where its four points are at least ``a`` (``x - h1 - h2 >= a``), in closed form.

    There ``G_2(y) = (y - mu)^2 / 2 + var / 2 - c_b z^4 / 24`` and ``G_3(y) = (y - mu)^3 / 6 + (y - mu) var / 2 -
    mu_3 / 6 + c_b z^5 / 120`` with ``z = (b - y)_+``, and the polynomial parts' differences over the two widths
    are exact: ``sum_q s_q (y_q - mu)^2 / 2 = u_1 u_2`` for the signs ``s = (+, -, -, +)`` of ``x + h1 + h2``,
    ``x - h1 + h2``, ``x + h1 - h2``, ``x - h1 - h2``, ``sum_q s_q (y_q - mu)^3 / 6 = u_1 u_2 (x - mu)``, and the
    one-sided sums of the tilts ``4 h_2 (x - mu)`` and ``4 h_1 (x - mu)``. What is left is

    ``1 + (P_A + P_X (x - mu)) Z_4 + P_B Z_5 + P_1 Z_4^(1) + P_2 Z_4^(2)``

    (``Z_j = sum_q s_q z_q^j``, ``Z_4^(1)``, ``Z_4^(2)`` the sums with the signs ``(+, +, -, -)`` and ``(+, -, +,
    -)``; ``f`` = :func:`_far_factors`): a third of the work of the four pieces, and no cancellation of the
    polynomial parts (exactly 1 once every point is past ``b``)."""
    b = k[1]
    zpp = max(b - (x + h1 + h2), 0.0)
    zmp = max(b - (x - h1 + h2), 0.0)
    zpm = max(b - (x + h1 - h2), 0.0)
    zmm = max(b - (x - h1 - h2), 0.0)
    qpp = zpp * zpp
    qmp = zmp * zmp
    qpm = zpm * zpm
    qmm = zmm * zmm
    qpp *= qpp
    qmp *= qmp
    qpm *= qpm
    qmm *= qmm
    d1 = qpp - qmp
    d2 = qpm - qmm
    z5 = (qpp * zpp - qmp * zmp) - (qpm * zpm - qmm * zmm)
    return 1.0 + ((f[0] + f[1] * (x - k[2])) * (d1 - d2) + f[2] * z5 + f[3] * ((qpp - qpm) + (qmp - qmm))
                  + f[4] * (d1 + d2))


@numba.njit(cache=True, fastmath=MASS_FASTMATH, inline="always")
def _cdf(x, k, h1, h2, mode, c0, c1, c2, c3):
    """The pair's tilted CDF at ``x`` (local: ``t_0 = 0``): ``P(T <= x) + t_1 E[v_1 1{T <= x}] + t_2 E[v_2
    1{T <= x}] + beta E[(A - mu) 1{T <= x}]`` (see :func:`masses`), ``k`` the triangular part's :func:`_shape`.
    ``mode`` 0: both widths finite (``G_2``, ``G_3`` at the four points ``x +- h1 +- h2``); 1: only ``w_2``
    (``G_1``, ``G_2`` at ``x +- h2``); 2: only ``w_1``; 3: neither (``G_0``, and ``G_1`` with an element tilt).
    ``c0, c1, c2, c3``: the prepared factors of :func:`masses`."""
    if mode == 0:
        return _cdf_widths(x, k, h1, h2, c0, c1, c2, c3)
    if mode == 3:
        cur = _g0(x, k)
        if c3 != 0.0:
            g1, _ = _g12(x, k)
            cur += c3 * ((x - k[2]) * cur - g1)
        return cur
    h = h2 if mode == 1 else h1
    p1, p2 = _g12(x + h, k)
    m1, m2 = _g12(x - h, k)
    cur = (p1 - m1) * c0
    c = c2 if mode == 1 else c1
    if c != 0.0:
        cur += c * (p2 - m2 - h * (p1 + m1))
    if c3 != 0.0:
        xm = x - k[2]
        cur += c3 * (((xm + h) * p1 - 2.0 * p2) - ((xm - h) * m1 - 2.0 * m2))
    return cur


@numba.njit(cache=True, fastmath=MASS_FASTMATH, inline="always")
def cell_widths(u1, u2, t1, t2):
    """The cell's part of :func:`masses`, computed once per pair for all its spots: ``(u1, u2, u1 / 2, u2 / 2,
    1 / u1, 1 / u2, t1, t2)`` (a reciprocal of a zero width is never read)."""
    return u1, u2, 0.5 * u1, 0.5 * u2, 1.0 / u1 if u1 > 0.0 else 0.0, 1.0 / u2 if u2 > 0.0 else 0.0, t1, t2


@numba.njit(cache=True, fastmath=MASS_FASTMATH, inline="always")
def _differences(v, prev):
    """In place, the CDF values ``v`` at a run of upper bin edges into the bins' masses (``prev``: the CDF at the
    first bin's lower edge); returns the mass of the run, ``v[-1] - prev`` (the sum of its masses, up to rounding:
    exact where the run is the whole support, 1 - 0). One pass from the first bin up, the last value carried in a
    register (a first-order recurrence, which the compiler vectorises: in a scratch timing about six times faster on
    100 bins than the pass from the last bin down it replaced; the same values)."""
    n = v.shape[0]
    inside = v[n - 1] - prev
    p = prev
    for i in range(n):
        c = v[i]
        v[i] = c - p
        p = c
    return inside


@numba.njit(cache=True, fastmath=MASS_FASTMATH, inline="always")
def _edges_below(thr, first, n):
    """How many of the run's upper bin edges ``first + 1, ..., first + n`` (bins of the padded axis) lie below
    ``thr`` (from 0 to ``n``)."""
    return min(max(int(np.ceil(thr)) - first - 1, 0), n)


@numba.njit(cache=True, fastmath=MASS_FASTMATH)
def masses(buf, tlo, a, b, cell, n_ext, beta):
    """Bin masses of one pair's arrival distribution (knots ``tlo``, ``tlo + a``, ``tlo + b``, the cell's widths
    ``u1``, ``u2`` and tilts ``t1``, ``t2`` in ``cell`` = :func:`cell_widths`; bins of the padded axis; the cell's
    amplitude ``1 + t1 v1 + t2 v2`` linear in the cell coordinates
    ``v_i`` in ``[-1/2, 1/2]`` along which the arrival time grows by ``u_i``) written to ``buf[first:last + 1]``
    for the bins inside ``[0, n_ext)``; returns ``(first, last, inside)``, ``inside`` the mass inside (the CDF's
    difference over the bins written; below ``VECTOR_EDGES`` bins their masses summed in bin order). The tilts move light within the pair's spread and leave its total unchanged; a tilt along a width
    below ``REL_WIDTH_EPS`` of the spread is dropped (its effect on any bin is ``|t| u / 12`` of the density there).
    The one mass computation of the primal (:func:`~._nlos_pair_kernels.spread_group`) and its adjoint
    (:func:`~._nlos_pair_kernels.adjoint_group`).

    At a bin edge ``x`` (``h_i = u_i / 2``, ``G_k`` of the triangular part ``A``):

    * ``P(T <= x) = [G_2(x+h1+h2) - G_2(x-h1+h2) - G_2(x+h1-h2) + G_2(x-h1-h2)] / (u1 u2)``, the second
      difference of ``G_2`` over both widths;
    * ``E[v_1 1{T <= x}] = [D_3 - h1 (G_2(x+h1+h2) + G_2(x-h1+h2) - G_2(x+h1-h2) - G_2(x-h1-h2))] / (u2 u1^2)``
      (integration by parts over ``v_1``; ``D_3`` the same second difference of ``G_3``), and ``v_2`` likewise;

    * ``E[(A - mu) 1{T <= x}]`` (the element's slope ``beta``, a weight ``1 + beta (A - mu)`` over the triangular
      part, ``mu = (a + b) / 3`` its mean) is the same second difference of ``H(y) = (y - mu) G_2(y) - 3 G_3(y)``
      (``E[A (y - A)_+^2] / 2 = y G_2 - 3 G_3``), divided by ``u1 u2``;

    so one edge costs ``G_2`` and ``G_3`` at four points. A width below ``REL_WIDTH_EPS`` of the spread is taken
    as zero (its difference becomes the derivative: ``G_1`` at two points, or ``G_0`` at one; the slope's term then
    reads ``(y - mu) G_1 - 2 G_2``, or ``(x - mu) G_0 - G_1``). ``beta`` (per bin, 0: none) comes from
    :func:`~._nlos_element_slope.slope_of`, which keeps the weight >= 0."""
    u1, u2, h1, h2, i1, i2, t1, t2 = cell
    spread = b + u1 + u2
    eps = REL_WIDTH_EPS * spread
    small1 = u1 <= eps
    small2 = u2 <= eps
    k = _shape(a, b)
    c1 = 0.0
    c2 = 0.0
    if not small1 and not small2:
        mode = 0
        c0 = i1 * i2
        c1 = t1 * c0 * i1
        c2 = t2 * c0 * i2
    elif small1 and small2:
        mode = 3
        c0 = 1.0
    elif small1:
        mode = 1
        c0 = i2
        c2 = t2 * c0 * c0
    else:
        mode = 2
        c0 = i1
        c1 = t1 * c0 * c0
    c3 = beta * c0
    lo = tlo - 0.5 * (u1 + u2)
    hi = tlo + b + 0.5 * (u1 + u2)
    b0 = int(np.floor(lo))
    b1 = int(np.floor(hi))
    first = max(b0, 0)
    last = min(b1, n_ext - 1)
    inside = 0.0
    if first > last:
        return first, last, inside
    prev = 0.0
    if first > b0:  # the CDF at the first inside bin's lower edge (the bins below the axis are not needed)
        edge = float(first) - tlo
        prev = 1.0 if edge + tlo >= hi else _cdf(edge, k, h1, h2, mode, c0, c1, c2, c3)
    if mode == 0 and last - first >= VECTOR_EDGES:
        # the CDF at every edge first (no edge depends on another: the loops run several edges per instruction), then
        # the masses as its differences
        v = buf[first:last + 1]  # (a view indexed from 0: with a bin index that could be negative no loop vectorises)
        n = v.shape[0]
        # two runs: the edges whose four points ``x +- h1 +- h2`` are not all at or above ``a`` (every piece, as
        # _cdf_widths selects them), and those where they are (the closed form of _cdf_far)
        i_far = _edges_below(tlo + k[0] + (h1 + h2), first, n)
        for i in range(i_far):
            v[i] = _cdf_widths(float(i + first + 1) - tlo, k, h1, h2, c0, c1, c2, c3)
        f = _far_factors(k, h1, h2, c0, c1, c2, c3)
        for i in range(i_far, n):
            edge = float(i + first + 1) - tlo
            cur = _cdf_far(edge, k, h1, h2, f)
            v[i] = 1.0 if edge + tlo >= hi else cur
        return first, last, _differences(v, prev)
    for bin_ in range(first, last + 1):
        edge = float(bin_ + 1) - tlo
        if edge + tlo >= hi:
            cur = 1.0
        else:
            cur = _cdf(edge, k, h1, h2, mode, c0, c1, c2, c3)
        buf[bin_] = cur - prev
        inside += cur - prev
        prev = cur
    return first, last, inside


@numba.njit(cache=True, fastmath=MASS_FASTMATH)
def _masses(buf, tlo, a, b, u1, u2, t1, t2, n_ext, beta=0.0):
    """:func:`masses` of one pair given its cell's widths and tilts (the per-pair form)."""
    return masses(buf, tlo, a, b, cell_widths(u1, u2, t1, t2), n_ext, beta)


@numba.njit(cache=True, fastmath=MASS_FASTMATH)
def _spread_one(buf, hist_k, bound_k, f, fe, tlo, a, b, u1, u2, t1, t2, n_ext):
    """Deposit one pair's light ``f`` (and its visibility error ``fe``) into one pixel's rows; returns the light
    arriving outside the padded axis (``buf``: scratch of ``n_ext`` bins for :func:`masses`)."""
    first, last, inside = _masses(buf, tlo, a, b, u1, u2, t1, t2, n_ext)
    for bin_ in range(first, last + 1):
        m = buf[bin_]
        hist_k[bin_] += f * m
        bound_k[bin_] += fe * m
    return f * (1.0 - inside)


@numba.njit(cache=True, fastmath=MASS_FASTMATH)
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
        The cell's relative amplitude slopes along the two components (see :func:`masses`; zeros: flat).
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
