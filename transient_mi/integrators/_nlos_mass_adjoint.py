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

from transient_mi.integrators._nlos_time_spread import REL_WIDTH_EPS, _gk, _hk, _tilt


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
    """``(C, dC/dx, dC/da, dC/db, dC/dw1, dC/dw2)`` of ``_cdf`` (same branches, ``x`` local)."""
    y = x + 0.5 * (w1 + w2)
    if small1 and small2:
        da, db = _gk_knots(0, x, a, b, mu)
        return _gk(0, x, a, b, mu, var, 0.0), _density(x, a, b), da, db, 0.0, 0.0
    if small1 or small2:
        w = w2 if small1 else w1
        y1 = x + 0.5 * w
        c, cx, ca, cb = _diff1(1, y1, w, a, b, mu, var)
        # d/dw: y1 moves by w/2, the lower end by -w/2, and the 1/w
        cw = 0.5 * (_gk(0, y1, a, b, mu, var, 0.0) + _gk(0, y1 - w, a, b, mu, var, 0.0)) / w - c / w
        if small1:
            return c, cx, ca, cb, 0.0, cw
        return c, cx, ca, cb, cw, 0.0
    y1, y2, y3 = y - w1, y - w2, y - w1 - w2
    g0, g1_, g2_, g3 = (_gk(2, y, a, b, mu, var, 0.0), _gk(2, y1, a, b, mu, var, 0.0), _gk(2, y2, a, b, mu, var, 0.0),
                        _gk(2, y3, a, b, mu, var, 0.0))
    h0, h1, h2, h3 = (_gk(1, y, a, b, mu, var, 0.0), _gk(1, y1, a, b, mu, var, 0.0), _gk(1, y2, a, b, mu, var, 0.0),
                      _gk(1, y3, a, b, mu, var, 0.0))
    a0, b0 = _gk_knots(2, y, a, b, mu)
    a1, b1 = _gk_knots(2, y1, a, b, mu)
    a2, b2 = _gk_knots(2, y2, a, b, mu)
    a3, b3 = _gk_knots(2, y3, a, b, mu)
    ww = w1 * w2
    c = (g0 - g1_ - g2_ + g3) / ww
    cx = (h0 - h1 - h2 + h3) / ww
    ca = (a0 - a1 - a2 + a3) / ww
    cb = (b0 - b1 - b2 + b3) / ww
    cw1 = 0.5 * (h0 + h1 - h2 - h3) / ww - c / w1
    cw2 = 0.5 * (h0 - h1 + h2 - h3) / ww - c / w2
    return c, cx, ca, cb, cw1, cw2


@numba.njit(cache=True, fastmath=False)
def _tilt_dx(x, w, w_other, a, b, mu, var, mu3, small_other):
    """``d/dx`` of ``_tilt`` (its shift derivative)."""
    lo = x - 0.5 * w
    hi = x + 0.5 * w
    return (_hk(1, hi, a, b, mu, var, mu3, w_other, small_other) - _hk(1, lo, a, b, mu, var, mu3, w_other, small_other)
            - 0.5 * w * (_hk(0, lo, a, b, mu, var, mu3, w_other, small_other)
                         + _hk(0, hi, a, b, mu, var, mu3, w_other, small_other))) / (w * w)


@numba.njit(cache=True, fastmath=False)
def mass_adjoint(row, tlo, a, b, u1, u2, t1, t2, n_ext):
    """For one pair (as ``_masses``: knots ``tlo``, ``tlo + a``, ``tlo + b``, widths ``u1``, ``u2``, the cell's
    amplitude tilts ``t1``, ``t2``, bins of the padded axis) and a row of bin adjoints ``row [n_ext]``:
    ``(sum_j row_j m_j`` and its derivatives with respect to ``tlo, a, b, u1, u2)``, the bins outside
    ``[0, n_ext)`` left out as in the primal. The tilt's terms enter the sum and the ``tlo`` derivative exactly;
    their own ``a, b, u`` derivatives are not taken (a first-order correction times a derivative: see
    :mod:`~._nlos_quadrature_geom`)."""
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
    acc = st = sa = sb = s1 = s2 = 0.0  # the sum and its derivatives along tlo, a, b, u1, u2
    p0 = p1 = p2 = p3 = p4 = p5 = 0.0  # C and its derivatives at the bin's lower edge
    for bin_ in range(b0, b1 + 1):
        edge = float(bin_ + 1) - tlo
        if edge + tlo >= hi:
            c0, c1, c2, c3, c4, c5 = 1.0, 0.0, 0.0, 0.0, 0.0, 0.0
        else:
            c0, cx, c2, c3, c4, c5 = cdf_derivatives(edge, a, b, u1, u2, mu, var, small1, small2)
            if tilt1:
                c0 += t1 * _tilt(edge, a, b, u1, u2, mu, var, mu3, small2)
                cx += t1 * _tilt_dx(edge, u1, u2, a, b, mu, var, mu3, small2)
            if tilt2:
                c0 += t2 * _tilt(edge, a, b, u2, u1, mu, var, mu3, small1)
                cx += t2 * _tilt_dx(edge, u2, u1, a, b, mu, var, mu3, small1)
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
        p0, p1, p2, p3, p4, p5 = c0, c1, c2, c3, c4, c5
    return acc, st, sa, sb, s1, s2
