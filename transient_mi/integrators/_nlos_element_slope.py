r"""The element's slope of the deterministic NLOS estimator (:mod:`transient_mi.integrators._nlos_quadrature`).

A pair (element, cell) is weighted by its integrand at the element's centroid. Across an element the weight varies
(both ``1 / r^2`` legs, the wall's cosines at the laser spot and at the cell, the element's own cosines), and where
the element spreads its light over several bins its early side and its late side are not equally bright. The
weight is therefore taken linear in the arrival time ``A`` over the element, ``w(A) = 1 + beta (A - mu)`` (``mu``
the mean of ``A``), whose bin masses are exact (:func:`~._nlos_time_spread.masses`). ``beta`` regresses the
relative weight at the three vertices ``r_v = w(V_v) / w(X_0)`` on their arrival knots ``t_v`` (bins):

.. math::

    \beta = \frac{\sum_v (r_v - \bar r)(t_v - \bar t)}{\sum_v (t_v - \bar t)^2},

exact for a weight and a path length linear over the triangle (the covariance of two linear functions over a
triangle is 1/12 of their vertex deviations' products summed, and its variance likewise). ``r_v`` is the product of
a detector part (per pair: :func:`~._nlos_pair_kernels.pair_geometry`'s ``amp``, the wall's cosine at the cell
times the element's over ``|X - p|^2``) and a laser part (per element and spot: :func:`laser_amplitudes`, the
wall's cosine at the spot times the element's over ``|X - S|^2``); the beam's profile, the BSDFs' albedos and the
sensor weight are held at their centroid values. ``beta`` is clamped so that the weight stays >= 0 over the
element together with the cell's slopes (:func:`slope_of`).

The reverse mode (:func:`slope_adjoint`, called by :func:`~._nlos_quadrature_geom.geometry_adjoint`)
differentiates ``beta`` through its knots and its vertices' amplitudes; the masses' own derivatives along
``beta``, the knots and the widths are :func:`~._nlos_mass_adjoint.mass_adjoint`'s.

Float64, numba; no allocation per pair.
"""

from __future__ import annotations

import numba
import numpy as np

#: A cosine or squared distance below this does not take part in the log-derivative of a vertex's amplitude.
_TINY = 1e-12


@numba.njit(cache=True, fastmath=False, inline="always")
def _regression(t0, t1, t2, r0, r1, r2, a, b, c1, c2):
    """The regression :func:`slope_of` clamps, and what :func:`slope_adjoint` differentiates: ``(beta, lim, d0, d1,
    d2, den, rm)`` with ``beta`` unclamped, ``lim`` its clamp (negative for an element of no spread: no slope),
    ``d_v`` the knots' deviations from their mean, ``den`` their sum of squares and ``rm`` the amplitudes' mean."""
    tm = (t0 + t1 + t2) * (1.0 / 3.0)
    rm = (r0 + r1 + r2) * (1.0 / 3.0)
    d0 = t0 - tm
    d1 = t1 - tm
    d2 = t2 - tm
    den = d0 * d0 + d1 * d1 + d2 * d2
    mu = (a + b) * (1.0 / 3.0)
    reach = max(mu, b - mu)
    if den <= 0.0 or reach <= 0.0:
        return 0.0, -1.0, d0, d1, d2, den, rm
    beta = ((r0 - rm) * d0 + (r1 - rm) * d1 + (r2 - rm) * d2) / den
    return beta, max(1.0 - 0.5 * (abs(c1) + abs(c2)), 0.0) / reach, d0, d1, d2, den, rm


@numba.njit(cache=True, fastmath=False, inline="always")
def slope_of(t0, t1, t2, r0, r1, r2, a, b, c1, c2):
    """The element's amplitude slope per bin: the regression of the relative amplitudes ``r0, r1, r2`` at its
    vertices (over the centroid's) on their arrival knots ``t0, t1, t2`` (bins; sorted they are ``t_lo``, ``t_lo +
    a``, ``t_lo + b``), clamped so that the weight ``1 + beta (A - mu)`` (``A`` in ``[0, b]``, ``mu = (a + b) / 3``)
    stays >= 0 with the cell's slopes ``c1``, ``c2`` at their worst (``1 - (|c1| + |c2|) / 2`` left to it); 0 for
    an element of no spread."""
    beta, lim = _regression(t0, t1, t2, r0, r1, r2, a, b, c1, c2)[:2]
    if lim < 0.0:
        return 0.0
    return min(max(beta, -lim), lim)


@numba.njit(cache=True, fastmath=False, inline="always")
def _laser_amplitude(x, s, wall_n, n_e):
    """``|u . n_wall| |u . n_e| / |u|^4`` for ``u = x - s`` (each dot product summed in axis order)."""
    u0 = x[0] - s[0]
    u1 = x[1] - s[1]
    u2 = x[2] - s[2]
    q = u0 * u0 + u1 * u1 + u2 * u2
    return abs(u0 * wall_n[0] + u1 * wall_n[1] + u2 * wall_n[2]) * abs(u0 * n_e[0] + u1 * n_e[1] + u2 * n_e[2]) / (
        q * q)


@numba.njit(cache=True, parallel=True, fastmath=False)
def laser_amplitudes(tri: np.ndarray, X0: np.ndarray, nrm: np.ndarray, S: np.ndarray, wall_n: np.ndarray) -> np.ndarray:
    """The laser side's amplitude at each element's vertices (``tri [n, 3, 3]``) over its value at the centroid
    (``X0 [n, 3]``), ``[n, G, 3]`` for the spots ``S [G, 3]``: the wall's cosine at the spot (normal ``wall_n``)
    times the element's (unit normals ``nrm [n, 3]``) over the squared distance (1 where the centroid's value is
    not positive). One element per iteration, no temporaries (a confocal capture has every pixel's spot: the
    ``[n, G, 3, 3]`` arrays of a vectorised form took a fifth of the 64 x 64 letter's render)."""
    n, G = X0.shape[0], S.shape[0]
    out = np.empty((n, G, 3))
    for e in numba.prange(n):
        for g in range(G):
            a0 = _laser_amplitude(X0[e], S[g], wall_n, nrm[e])
            for v in range(3):
                out[e, g, v] = _laser_amplitude(tri[e, v], S[g], wall_n, nrm[e]) / a0 if a0 > 0.0 else 1.0
    return out


@numba.njit(cache=True, fastmath=False, inline="always")
def _log_amplitude_grad(acc, x_at, X, o, n_e, wall_n, w):
    """Add ``w`` times the gradient of ``ln(|u . n_wall| |u . n_e| / |u|^4)`` (``u = X - o``) with respect to ``X``
    to ``acc[x_at:x_at + 3]`` and with respect to the unit normal ``n_e`` to ``acc[3:6]`` (nothing where a cosine
    vanishes)."""
    u0 = X[0] - o[0]
    u1 = X[1] - o[1]
    u2 = X[2] - o[2]
    cw = u0 * wall_n[0] + u1 * wall_n[1] + u2 * wall_n[2]
    ce = u0 * n_e[0] + u1 * n_e[1] + u2 * n_e[2]
    q = u0 * u0 + u1 * u1 + u2 * u2
    if abs(cw) <= _TINY or abs(ce) <= _TINY or q <= _TINY:
        return
    acc[x_at] += w * (wall_n[0] / cw + n_e[0] / ce - 4.0 * u0 / q)
    acc[x_at + 1] += w * (wall_n[1] / cw + n_e[1] / ce - 4.0 * u1 / q)
    acc[x_at + 2] += w * (wall_n[2] / cw + n_e[2] / ce - 4.0 * u2 / q)
    acc[3] += w * u0 / ce
    acc[4] += w * u1 / ce
    acc[5] += w * u2 / ce


@numba.njit(cache=True, fastmath=False)
def slope_adjoint(acc, f, s_e, tb, v0, v1, v2, amp, amp_s, i, e, a, b, tilt, tri, X0, nrm, p, S, wall_n):
    """Add the derivative of the element's slope (:func:`slope_of`, for pair ``i`` of element ``e`` and this spot:
    knots ``v0, v1, v2`` in vertex order, relative amplitudes ``amp[i, v] amp_s[e, v]``), weighted by the adjoint
    ``s_e`` of ``beta`` (per unit light; the pair's light ``f``), to the knots' adjoints ``tb`` (vertex order, per
    unit light: the caller scales them; these terms sum to 0, so the knots' common shift is unaffected) and to one
    element's accumulators ``acc`` (:func:`~._nlos_quadrature_geom.geometry_adjoint`'s layout: centroid 0:3, unit
    normal 3:6, vertices 7:16). A clamped slope has no derivative."""
    r0 = amp[i, 0] * amp_s[e, 0]
    r1 = amp[i, 1] * amp_s[e, 1]
    r2 = amp[i, 2] * amp_s[e, 2]
    beta, lim, d0, d1, d2, den, rm = _regression(v0, v1, v2, r0, r1, r2, a, b, tilt[i, 0], tilt[i, 1])
    if lim < 0.0 or abs(beta) >= lim:  # (no spread, or clamped: no derivative)
        return
    tb[0] += s_e * ((r0 - rm) - 2.0 * beta * d0) / den
    tb[1] += s_e * ((r1 - rm) - 2.0 * beta * d1) / den
    tb[2] += s_e * ((r2 - rm) - 2.0 * beta * d2) / den
    g = f * s_e / den
    w0 = g * d0 * r0
    w1 = g * d1 * r1
    w2 = g * d2 * r2
    # r_v = a(V_v) / a(X_0), a = a_cell a_spot: d r_v = r_v (d ln a(V_v) - d ln a(X_0)); the cell's parts here, the
    # spot's (the same for every cell of the element) summed per vertex in acc[16:19] (laser_slope_terms)
    _log_amplitude_grad(acc, 7, tri[e, 0], p, nrm[e], wall_n, w0)
    _log_amplitude_grad(acc, 10, tri[e, 1], p, nrm[e], wall_n, w1)
    _log_amplitude_grad(acc, 13, tri[e, 2], p, nrm[e], wall_n, w2)
    _log_amplitude_grad(acc, 0, X0[e], p, nrm[e], wall_n, -(w0 + w1 + w2))
    acc[16] += w0
    acc[17] += w1
    acc[18] += w2


@numba.njit(cache=True, fastmath=False)
def laser_slope_terms(acc, tri, X0, nrm, S, wall_n):
    """The laser side's part of :func:`slope_adjoint` for one element, once its weights per vertex are summed
    (``acc[16:19]``): each weight times the gradient of the spot's log-amplitude at its vertex, minus at the
    centroid, into ``acc``'s vertex, centroid and normal slots."""
    for v in range(3):
        w = acc[16 + v]
        if w != 0.0:
            _log_amplitude_grad(acc, 7 + 3 * v, tri[v], S, nrm, wall_n, w)
            _log_amplitude_grad(acc, 0, X0, S, nrm, wall_n, -w)
