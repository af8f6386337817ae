r"""Derivatives of the quadrature's exact bin masses (:mod:`transient_mi.integrators._nlos_time_spread`) with
respect to the arrival-time knots and the cell's widths.

A pair's arrival time is ``T = A + U_1 + U_2`` (``A`` triangular with sorted knots ``t_lo``, ``t_lo + a``,
``t_lo + b``; ``U_i`` centred uniforms of widths ``w_i``) and bin ``j`` receives
``m_j = C(j + 1 - t_lo) - C(j - t_lo)``, ``C(x) = P(T - t_lo <= x) = Delta_{w_1} Delta_{w_2} G_2(x + (w_1 + w_2)/2)``
with ``G_k(y) = E[(y - A)_+^k] / k!``. The derivatives used here, all in closed form:

* ``d/dx``: ``G_k' = G_{k-1}`` (``G_{-1}`` the triangular density), so the ``t_lo`` derivative of a mass is
  minus the difference of the density of ``T`` at the bin's edges;
* ``d/da``, ``d/db``: the knot derivatives of ``G_k``. ``G_k`` is a divided difference of a truncated power
  (``G_k(y) = 2 [0, a, b] (y - .)_+^{k+2} / (k+2)!``), so a knot derivative is the divided difference with
  that knot repeated; written out piecewise (the same pieces as ``_gk``) every term is bounded by a
  multiple of ``1/b`` whatever the spacing of the knots (coincident knots included: ``a = 0``, ``a = b``
  leave one piece; ``b = 0`` is the point mass, whose ``G_1``, ``G_2`` derivatives are ``-1/3`` and
  ``-y/3``);
* ``d/dw_i``: the product rule on ``Delta_w G(y) = (G(y) - G(y - w)) / w`` with ``y`` moving by ``w/2``;
  a width the primal treats as infinitesimal (below ``REL_WIDTH_EPS`` of the spread) does not enter the
  primal, and its derivative is zero.

Float64, numba, one pair at a time in bin order (same inputs, same bytes).
"""

from __future__ import annotations

import numba
import numpy as np

from transient_mi.integrators._nlos_time_spread import REL_WIDTH_EPS


# The single-antiderivative forms of the masses (the primal, :func:`~._nlos_time_spread.masses`, evaluates
# the same pieces four points at a time).


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
def _density(y, a, b):
    """The triangular density with knots ``0 <= a <= b`` at ``y`` (``G_{-1}``; 0 for the point mass)."""
    if y <= 0.0 or y >= b or b <= 0.0:
        return 0.0
    if y <= a:
        return 2.0 * y / (b * a)
    return 2.0 * (b - y) / (b * (b - a))


@numba.njit(cache=True, fastmath=False)
def _gk_knots(k, y, a, b, mu):
    """``(dG_k/da, dG_k/db)`` at ``y`` for knots ``0 <= a <= b`` (``k`` in 0..2; see the module docstring)."""
    if y <= 0.0:
        return 0.0, 0.0
    if b <= 0.0 or y >= b:
        if k == 0:
            return 0.0, 0.0
        if k == 1:
            return -1.0 / 3.0, -1.0 / 3.0
        d = y - mu
        return -d / 3.0 + (2.0 * a - b) / 36.0, -d / 3.0 + (2.0 * b - a) / 36.0
    if y <= a:  # G = c y^(k+2) with c ~ 1 / (a b)
        g = _gk(k, y, a, b, mu, 0.0, 0.0)  # (var is not read below b)
        return -g / a, -g / b
    z = b - y
    K = b * (b - a)
    dka = -b
    dkb = 2.0 * b - a
    if k == 0:  # 1 - z^2 / K
        return z * z * dka / (K * K), -2.0 * z / K + z * z * dkb / (K * K)
    if k == 1:  # y - mu + z^3 / (3 K)
        return -1.0 / 3.0 - z ** 3 * dka / (3.0 * K * K), -1.0 / 3.0 + z * z / K - z ** 3 * dkb / (3.0 * K * K)
    d = y - mu  # ((y - mu)^2 + var) / 2 - z^4 / (12 K)
    return (-d / 3.0 + (2.0 * a - b) / 36.0 + z ** 4 * dka / (12.0 * K * K),
            -d / 3.0 + (2.0 * b - a) / 36.0 - z ** 3 / (3.0 * K) + z ** 4 * dkb / (12.0 * K * K))


@numba.njit(cache=True, fastmath=False)
def _gk_any(k, y, a, b, mu, var):
    """``G_k`` for ``k`` in -1..2 (``G_{-1}`` the density)."""
    if k < 0:
        return _density(y, a, b)
    return _gk(k, y, a, b, mu, var, 0.0)


@numba.njit(cache=True, fastmath=False)
def _diff1(k, y, w, a, b, mu, var):
    """``(G_k(y) - G_k(y - w)) / w`` and its derivatives ``(d/dy, d/da, d/db)`` (``d/dw`` is formed by the
    caller from the end values)."""
    ga0, gb0 = _gk_knots(k, y, a, b, mu)
    ga1, gb1 = _gk_knots(k, y - w, a, b, mu)
    return ((_gk(k, y, a, b, mu, var, 0.0) - _gk(k, y - w, a, b, mu, var, 0.0)) / w,
            (_gk_any(k - 1, y, a, b, mu, var) - _gk_any(k - 1, y - w, a, b, mu, var)) / w,
            (ga0 - ga1) / w, (gb0 - gb1) / w)


@numba.njit(cache=True, fastmath=False)
def cdf_derivatives(x, a, b, w1, w2, mu, var, small1, small2):
    """``(C, dC/dx, dC/da, dC/db, dC/dw1, dC/dw2)`` of ``_cdf`` (same branches, ``x`` local) where at least one width
    is infinitesimal (``small1`` or ``small2``; with both widths finite :func:`_edge_both_widths` serves)."""
    if small1 and small2:
        da, db = _gk_knots(0, x, a, b, mu)
        return _gk(0, x, a, b, mu, var, 0.0), _density(x, a, b), da, db, 0.0, 0.0
    w = w2 if small1 else w1
    y1 = x + 0.5 * w
    c, cx, ca, cb = _diff1(1, y1, w, a, b, mu, var)
    # d/dw: y1 moves by w/2, the lower end by -w/2, and the 1/w
    cw = 0.5 * (_gk(0, y1, a, b, mu, var, 0.0) + _gk(0, y1 - w, a, b, mu, var, 0.0)) / w - c / w
    if small1:
        return c, cx, ca, cb, 0.0, cw
    return c, cx, ca, cb, cw, 0.0


@numba.njit(cache=True, fastmath=False)
def _tilt_dx(x, w, w_other, a, b, mu, var, mu3, small_other):
    """``d/dx`` of ``_tilt`` (its shift derivative)."""
    lo = x - 0.5 * w
    hi = x + 0.5 * w
    return (_hk(1, hi, a, b, mu, var, mu3, w_other, small_other) - _hk(1, lo, a, b, mu, var, mu3, w_other, small_other)
            - 0.5 * w * (_hk(0, lo, a, b, mu, var, mu3, w_other, small_other)
                         + _hk(0, hi, a, b, mu, var, mu3, w_other, small_other))) / (w * w)


@numba.njit(cache=True, fastmath=False, inline="always")
def _poly3_knots(d, a, b, var):
    """``(dP/da, dP/db)`` of the moments' polynomial ``P = (d^3 + 3 d var - mu3) / 6`` (``d = y - mu``), which is
    ``G_3`` from ``b`` on (``mu``, ``var``, ``mu3`` of :func:`_gk` move with the knots)."""
    da = (-d * d - var + d * (2.0 * a - b) / 6.0 - (2.0 * a * a - 2.0 * a * b - b * b) / 90.0) / 6.0
    db = (-d * d - var + d * (2.0 * b - a) / 6.0 - (2.0 * b * b - 2.0 * a * b - a * a) / 90.0) / 6.0
    return da, db


@numba.njit(cache=True, fastmath=False, inline="always")
def _point(y, a, b, mu, var, mu3, g3_knots):
    """``(G_1, G_2, G_3, dG_2/da, dG_2/db, dG_3/da, dG_3/db)`` at ``y`` in one pass through the pieces (the values of
    :func:`_gk` and :func:`_gk_knots`, same expressions, and the knot derivatives of ``G_3`` that the element
    slope's term reads; zeros unless ``g3_knots``): what :func:`mass_adjoint` reads at each of an edge's four points
    when both widths are finite."""
    if y <= 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    if b <= 0.0:  # point mass at 0 (mu = 0)
        e3a, e3b = _poly3_knots(y, a, b, var) if g3_knots else (0.0, 0.0)
        return (y, 0.5 * y * y, y * y * y / 6.0, -y / 3.0 + (2.0 * a - b) / 36.0, -y / 3.0 + (2.0 * b - a) / 36.0,
                e3a, e3b)
    if y >= b:
        d = y - mu
        e3a, e3b = _poly3_knots(d, a, b, var) if g3_knots else (0.0, 0.0)
        return (d, 0.5 * (d * d + var), (d * d * d + 3.0 * d * var - mu3) / 6.0,
                -d / 3.0 + (2.0 * a - b) / 36.0, -d / 3.0 + (2.0 * b - a) / 36.0, e3a, e3b)
    if y <= a:  # (a > 0 here)
        c = 2.0 / (b * a)
        y3 = y * y * y
        g2 = c * y3 * y / 24.0
        g3 = c * y3 * y * y / 120.0
        return c * y3 / 6.0, g2, g3, -g2 / a, -g2 / b, -g3 / a, -g3 / b
    z = b - y
    c = 2.0 / (b * (b - a))
    d = y - mu
    K = b * (b - a)
    z3 = z * z * z
    z4 = z3 * z
    base = -d / 3.0
    e3a, e3b = _poly3_knots(d, a, b, var) if g3_knots else (0.0, 0.0)
    return (d + c * z3 / 6.0, 0.5 * (d * d + var) - c * z4 / 24.0,
            (d * d * d + 3.0 * d * var - mu3) / 6.0 + c * z4 * z / 120.0,
            base + (2.0 * a - b) / 36.0 + z4 * (-b) / (12.0 * K * K),
            base + (2.0 * b - a) / 36.0 - z3 / (3.0 * K) + z4 * (2.0 * b - a) / (12.0 * K * K),
            e3a + b * z4 * z / (60.0 * K * K),
            e3b + z4 / (12.0 * K) - (2.0 * b - a) * z4 * z / (60.0 * K * K))


@numba.njit(cache=True, fastmath=False, inline="always")
def _tilt_terms(A1, A2, A3, Aa, Ab, A3a, A3b, B1, B2, B3, Ba, Bb, B3a, B3b, C1, C2, C3, Ca, Cb, C3a, C3b,
                D1, D2, D3, Da, Db, D3a, D3b, wa, wo):
    """A cell tilt's term of :func:`_edge_both_widths` along the width ``wa`` (the other ``wo``) and its derivatives:
    ``(T, dT/dx, dT/da, dT/db, dT/dwa, dT/dwo)`` with ``T = [(G_3(A) - G_3(B) - G_3(C) + G_3(D)) / wo - (wa / 2)
    (k_lo + k_hi)] / wa^2``, ``k_hi = (G_2(A) - G_2(B)) / wo``, ``k_lo = (G_2(C) - G_2(D)) / wo`` (:func:`_tilt` on
    both widths). The points (each given as :func:`_point`'s seven values): ``A = y``, ``B = y - wo``, ``C = y -
    wa``, ``D = y - wa - wo``; with ``y = x + (wa + wo) / 2`` they move by ``+-1/2`` with each width (``G_3' = G_2``,
    ``G_2' = G_1``)."""
    wa2 = wa * wa
    k_lo = (C2 - D2) / wo
    k_hi = (A2 - B2) / wo
    kk = k_lo + k_hi
    n = ((A3 - B3) - (C3 - D3)) / wo
    t = (n - 0.5 * wa * kk) / wa2
    tx = (k_hi - k_lo - 0.5 * wa * ((C1 - D1) / wo + (A1 - B1) / wo)) / wa2
    ta = (((A3a - B3a) - (C3a - D3a)) / wo - 0.5 * wa * ((Ca - Da) + (Aa - Ba)) / wo) / wa2
    tb = (((A3b - B3b) - (C3b - D3b)) / wo - 0.5 * wa * ((Cb - Db) + (Ab - Bb)) / wo) / wa2
    dn = 0.5 * (A2 - B2 + C2 - D2) / wo
    dk = 0.5 * (A1 - B1 - C1 + D1) / wo
    t_wa = (dn - 0.5 * kk - 0.5 * wa * dk) / wa2 - 2.0 * t / wa
    dn = 0.5 * (A2 + B2 - C2 - D2) / wo - n / wo
    dk = 0.5 * (C1 + D1 + A1 + B1) / wo - kk / wo
    t_wo = (dn - 0.5 * wa * dk) / wa2
    return t, tx, ta, tb, t_wa, t_wo


@numba.njit(cache=True, fastmath=False, inline="always")
def _edge_both_widths(x, a, b, w1, w2, t1, t2, mu, var, mu3, beta, slope):
    """``(C, dC/dx, dC/da, dC/db, dC/dw1, dC/dw2, E, dC/dt1, dC/dt2)`` at edge ``x`` with both widths finite, the
    tilts' terms added to
    ``C`` and ``dC/dx`` (the second difference of ``G_2`` over both widths, plus ``t_i`` :func:`_tilt` and
    :func:`_tilt_dx` as where a width is infinitesimal): every term is
    a second difference over the same four points ``y``, ``y - w1``, ``y - w2``, ``y - w1 - w2`` (``y = x + (w1 +
    w2) / 2``), so ``G_1 .. G_3`` and the knot derivatives are evaluated once per point (:func:`_point`). ``E`` is
    the element slope's term ``E[(A - mu) 1{T <= x}]`` (``C``'s derivative along ``beta``; 0 unless ``slope`` or
    ``beta`` is not 0)."""
    y = x + 0.5 * (w1 + w2)
    g3k = beta != 0.0 or t1 != 0.0 or t2 != 0.0
    p1, p2, p3, pa, pb, p3a, p3b = _point(y, a, b, mu, var, mu3, g3k)
    q1, q2, q3, qa, qb, q3a, q3b = _point(y - w1, a, b, mu, var, mu3, g3k)
    r1, r2, r3, ra, rb, r3a, r3b = _point(y - w2, a, b, mu, var, mu3, g3k)
    s1, s2, s3, sa, sb, s3a, s3b = _point(y - w1 - w2, a, b, mu, var, mu3, g3k)
    ww = w1 * w2
    c = (p2 - q2 - r2 + s2) / ww
    cx = (p1 - q1 - r1 + s1) / ww
    ca = (pa - qa - ra + sa) / ww
    cb = (pb - qb - rb + sb) / ww
    cw1 = 0.5 * (p1 + q1 - r1 - s1) / ww - c / w1
    cw2 = 0.5 * (p1 - q1 + r1 - s1) / ww - c / w2
    # the cell's tilts: _tilt(x, w1, other w2) reads the points y, y - w2 (at x + w1/2) and y - w1, y - w1 - w2
    # (at x - w1/2); _tilt(x, w2, other w1) the points y, y - w1 and y - w2, y - w1 - w2. C's derivative along
    # each tilt is returned whatever the tilt (the tilts' own derivatives, :func:`mass_adjoint`)
    ct1, x1, a1, b1, wa1, wo1 = _tilt_terms(p1, p2, p3, pa, pb, p3a, p3b, r1, r2, r3, ra, rb, r3a, r3b,
                                            q1, q2, q3, qa, qb, q3a, q3b, s1, s2, s3, sa, sb, s3a, s3b, w1, w2)
    ct2, x2, a2, b2, wa2, wo2 = _tilt_terms(p1, p2, p3, pa, pb, p3a, p3b, q1, q2, q3, qa, qb, q3a, q3b,
                                            r1, r2, r3, ra, rb, r3a, r3b, s1, s2, s3, sa, sb, s3a, s3b, w2, w1)
    c += t1 * ct1 + t2 * ct2
    cx += t1 * x1 + t2 * x2
    ca += t1 * a1 + t2 * a2
    cb += t1 * b1 + t2 * b2
    cw1 += t1 * wa1 + t2 * wo2
    cw2 += t1 * wo1 + t2 * wa2
    # the element's slope: E[(A - mu) 1{T <= x}] with H(y) = (y - mu) G_2(y) - 3 G_3(y) over the same four points,
    # and its x derivative with (y - mu) G_1(y) - 2 G_2(y)
    yq = y - w1
    yr = y - w2
    ys = y - w1 - w2
    ce = 0.0
    if slope or beta != 0.0:
        ce = (((y - mu) * p2 - 3.0 * p3) - ((yq - mu) * q2 - 3.0 * q3) - ((yr - mu) * r2 - 3.0 * r3)
              + ((ys - mu) * s2 - 3.0 * s3)) / ww
    if beta != 0.0:
        hp = (y - mu) * p1 - 2.0 * p2  # H'(y) at the four points
        hq = (yq - mu) * q1 - 2.0 * q2
        hr = (yr - mu) * r1 - 2.0 * r2
        hs = (ys - mu) * s1 - 2.0 * s2
        c += beta * ce
        cx += beta * (hp - hq - hr + hs) / ww
        # its knot derivatives (mu moves by 1/3 of a knot) and width derivatives (the points move by +-1/2)
        g2 = (p2 - q2 - r2 + s2) / ww
        ca += beta * (-g2 / 3.0 + ((y - mu) * pa - (yq - mu) * qa - (yr - mu) * ra + (ys - mu) * sa) / ww
                      - 3.0 * (p3a - q3a - r3a + s3a) / ww)
        cb += beta * (-g2 / 3.0 + ((y - mu) * pb - (yq - mu) * qb - (yr - mu) * rb + (ys - mu) * sb) / ww
                      - 3.0 * (p3b - q3b - r3b + s3b) / ww)
        cw1 += beta * (0.5 * (hp + hq - hr - hs) / ww - ce / w1)
        cw2 += beta * (0.5 * (hp - hq + hr - hs) / ww - ce / w2)
    return c, cx, ca, cb, cw1, cw2, ce, ct1, ct2


@numba.njit(cache=True, fastmath=False)
def _element_tilt(x, a, b, w1, w2, mu, var, mu3, small1, small2):
    """``(E, dE/dx, dE/da, dE/db, dE/dw)`` of the element slope's term ``E = E[(A - mu) 1{T <= x}]`` where at least
    one width is infinitesimal (:func:`~._nlos_time_spread.masses`; ``w`` the finite width, if any)."""
    if small1 and small2:
        g0 = _gk(0, x, a, b, mu, var, mu3)
        g0a, g0b = _gk_knots(0, x, a, b, mu)
        g1a, g1b = _gk_knots(1, x, a, b, mu)
        return ((x - mu) * g0 - _gk(1, x, a, b, mu, var, mu3), (x - mu) * _density(x, a, b),
                -g0 / 3.0 + (x - mu) * g0a - g1a, -g0 / 3.0 + (x - mu) * g0b - g1b, 0.0)
    w = w2 if small1 else w1
    hi = x + 0.5 * w
    lo = x - 0.5 * w
    g1h, g2h = _gk(1, hi, a, b, mu, var, mu3), _gk(2, hi, a, b, mu, var, mu3)
    g1l, g2l = _gk(1, lo, a, b, mu, var, mu3), _gk(2, lo, a, b, mu, var, mu3)
    g0h, g0l = _gk(0, hi, a, b, mu, var, mu3), _gk(0, lo, a, b, mu, var, mu3)
    e = (((hi - mu) * g1h - 2.0 * g2h) - ((lo - mu) * g1l - 2.0 * g2l)) / w
    dh = (hi - mu) * g0h - g1h  # H_1'(y) = (y - mu) G_0 - G_1
    dl = (lo - mu) * g0l - g1l
    a1h, b1h = _gk_knots(1, hi, a, b, mu)
    a2h, b2h = _gk_knots(2, hi, a, b, mu)
    a1l, b1l = _gk_knots(1, lo, a, b, mu)
    a2l, b2l = _gk_knots(2, lo, a, b, mu)
    ea = (-(g1h - g1l) / 3.0 + (hi - mu) * a1h - (lo - mu) * a1l - 2.0 * (a2h - a2l)) / w
    eb = (-(g1h - g1l) / 3.0 + (hi - mu) * b1h - (lo - mu) * b1l - 2.0 * (b2h - b2l)) / w
    return e, (dh - dl) / w, ea, eb, 0.5 * (dh + dl) / w - e / w


@numba.njit(cache=True, fastmath=False)
def mass_adjoint(row, tlo, a, b, u1, u2, t1, t2, n_ext, beta=0.0, slope=False):
    """For one pair (as ``_masses``: knots ``tlo``, ``tlo + a``, ``tlo + b``, widths ``u1``, ``u2``, the cell's
    amplitude tilts ``t1``, ``t2``, the element's amplitude slope ``beta`` per bin, bins of the padded axis) and a
    row of bin adjoints ``row [n_ext]``:
    ``(sum_j row_j m_j`` and its derivatives with respect to ``tlo, a, b, u1, u2, beta)``, the bins outside
    ``[0, n_ext)`` left out as in the primal, then its derivatives with respect to the cell's tilts ``t1, t2`` (the
    sum is linear in them; 0 along a width the primal takes as infinitesimal). The tilts' terms (the cell's and the
    element's) enter the sum and the ``tlo`` derivative exactly, the element slope's term its ``a, b, u`` derivatives
    too, and with ``slope`` the ``beta`` derivative is returned (0 otherwise; the caller differentiates the slope
    through its inputs); the cell tilts' terms' ``a, b, u`` derivatives are taken where both widths are finite (the
    fused path, :func:`_edge_both_widths`), not where a width is infinitesimal (a first-order correction times a
    derivative, on a cell seen edge-on: see :mod:`~._nlos_quadrature_geom`)."""
    spread = b + u1 + u2
    eps = REL_WIDTH_EPS * spread
    small1 = u1 <= eps
    small2 = u2 <= eps
    tilt1 = t1 != 0.0 and not small1
    tilt2 = t2 != 0.0 and not small2
    both = not small1 and not small2  # (the common case: one fused evaluation per edge point)
    mu = (a + b) / 3.0
    var = (a * a + b * b - a * b) / 18.0
    mu3 = (b - 2.0 * a) * (a + b) * (2.0 * b - a) / 270.0
    lo = tlo - 0.5 * (u1 + u2)
    hi = tlo + b + 0.5 * (u1 + u2)
    b0 = int(np.floor(lo))
    b1 = int(np.floor(hi))
    # the sum and its derivatives along tlo, a, b, u1, u2, beta, t1, t2
    acc = st = sa = sb = s1 = s2 = se = sk1 = sk2 = 0.0
    p0 = p1 = p2 = p3 = p4 = p5 = p6 = p7 = p8 = 0.0  # C and its derivatives at the bin's lower edge
    for bin_ in range(b0, b1 + 1):
        edge = float(bin_ + 1) - tlo
        if edge + tlo >= hi:
            c0, c1, c2, c3, c4, c5, c6, c7, c8 = 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        elif both:
            c0, cx, c2, c3, c4, c5, c6, c7, c8 = _edge_both_widths(edge, a, b, u1, u2, t1, t2, mu, var, mu3, beta,
                                                                   slope)
            c1 = -cx
        else:
            c0, cx, c2, c3, c4, c5 = cdf_derivatives(edge, a, b, u1, u2, mu, var, small1, small2)
            c7 = 0.0 if small1 else _tilt(edge, a, b, u1, u2, mu, var, mu3, small2)
            c8 = 0.0 if small2 else _tilt(edge, a, b, u2, u1, mu, var, mu3, small1)
            if tilt1:
                c0 += t1 * c7
                cx += t1 * _tilt_dx(edge, u1, u2, a, b, mu, var, mu3, small2)
            if tilt2:
                c0 += t2 * c8
                cx += t2 * _tilt_dx(edge, u2, u1, a, b, mu, var, mu3, small1)
            c6 = 0.0
            if slope or beta != 0.0:
                c6, ex_, ea_, eb_, ew_ = _element_tilt(edge, a, b, u1, u2, mu, var, mu3, small1, small2)
            if beta != 0.0:
                c0 += beta * c6
                cx += beta * ex_
                c2 += beta * ea_
                c3 += beta * eb_
                if small1 and not small2:
                    c5 += beta * ew_
                elif small2 and not small1:
                    c4 += beta * ew_
            c1 = -cx  # d/dtlo of C(edge - tlo)
        if 0 <= bin_ < n_ext:
            r = row[bin_]
            if r != 0.0:
                acc += r * (c0 - p0)
                st += r * (c1 - p1)
                sa += r * (c2 - p2)
                sb += r * (c3 - p3)
                s1 += r * (c4 - p4)
                s2 += r * (c5 - p5)
                se += r * (c6 - p6)
                sk1 += r * (c7 - p7)
                sk2 += r * (c8 - p8)
        p0, p1, p2, p3, p4, p5, p6, p7, p8 = c0, c1, c2, c3, c4, c5, c6, c7, c8
    return acc, st, sa, sb, s1, s2, se, sk1, sk2
