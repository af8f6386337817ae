"""The path length's curvature across a wall cell, as the deterministic NLOS estimator's one-cell spread takes it
(:mod:`~._nlos_pair_kernels`, :func:`cell_curvature`), and its derivative with respect to the element's centroid
for reverse mode (:mod:`~._nlos_quadrature_geom`, :func:`curvature_gradient`): the same expressions in both, so the
primal's knots and tilts and the adjoint's agree to rounding (docs/quadrature.md, *Curvature across a cell*)."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, fastmath=False, inline="always")
def edge_width_m(x, p, D, h, fl, r, rd):
    """The path length's linear width along the cell's edge ``h`` (m, signed): ``(fl u_D - d) . h`` with ``u_D``
    the unit vector ``D -> p`` (``rd = |p - D|``) and ``d`` the unit vector ``p -> x`` (``r = |x - p|``)."""
    s = 0.0
    for q in range(3):
        s += (fl * (p[q] - D[q]) / rd - (x[q] - p[q]) / r) * h[q]
    return s


@numba.njit(cache=True, fastmath=False, inline="always")
def _faded(a, w):
    """``(shift_m, tilt)`` of :func:`cell_curvature` for the curvature ``a`` and the width ``w = |s|`` (m): the
    correction in full up to ``|a| = w / 2``, faded linearly to nothing at ``|a| = w``."""
    if not abs(a) < w:
        return 0.0, 0.0
    rho = abs(a) / w
    phi = 1.0 if rho <= 0.5 else 2.0 * (1.0 - rho)
    return a * phi / 12.0, -a * phi / w


@numba.njit(cache=True, fastmath=False, inline="always")
def cell_curvature(x, p0, p1, p2, D0, D1, D2, l0, h0, h1, h2, fl, s_m):
    """The path length's curvature across a cell along one of its edges ``h`` (m), as the one-cell spread takes
    it: ``(shift_m, tilt)``.

    Along the edge, ``l(u) = l0 + s u + a u^2 / 2`` (``u`` in ``[-1/2, 1/2]``, ``s`` the linear width ``s_m``, m;
    ``a = 4 (l(1/2) + l(-1/2) - 2 l0)`` from the edge midpoints; ``l`` the detector leg ``fl |q - D|`` plus
    ``|x - q|``). To first order in ``a / s`` the arrival times of a uniform ``u`` are uniform over ``s``, centred
    ``a / 8`` late, with a density falling as ``1 - (a / |s|) v`` (``v`` in ``[-1/2, 1/2]``, growing with arrival
    time): the mean ``a / 24`` is the same as the cell's shift alone gives. The correction is taken in full up to
    ``|a| = |s| / 2`` and faded linearly to nothing at ``|a| = |s|`` (a near-stationary path length, where a linear
    density is no model of it): ``phi``. Returns the centre's shift beyond the mean, ``a phi / 12`` (m), and the
    density's relative slope ``-a phi / |s|``."""
    acc = 0.0
    for sg in (0.5, -0.5):
        q0 = p0 + sg * h0
        q1 = p1 + sg * h1
        q2 = p2 + sg * h2
        acc += fl * np.sqrt((q0 - D0) * (q0 - D0) + (q1 - D1) * (q1 - D1) + (q2 - D2) * (q2 - D2)) \
            + np.sqrt((x[0] - q0) * (x[0] - q0) + (x[1] - q1) * (x[1] - q1) + (x[2] - q2) * (x[2] - q2))
    return _faded(4.0 * (acc - 2.0 * l0), abs(s_m))


@numba.njit(cache=True, fastmath=False)
def curvature_gradient(x, p, D, h, fl, r, d, dsh, dtl):
    """:func:`cell_curvature` along the cell's edge ``h`` for the centroid ``x`` (cell centre
    ``p``, detector ``D``, ``r = |x - p|``, ``d`` the unit vector ``p -> x``) and its derivatives with respect to
    ``x``: returns ``(shift_m, tilt)`` and writes ``d shift / dx`` to ``dsh[3]`` and ``d tilt / dx`` to ``dtl[3]``
    (0 where the correction is off). ``a``'s derivative: the edge midpoints' and the centre's unit vectors to ``x``
    (the detector leg does not move); the width ``|s|``'s: ``s = (fl u_D - d) . h``, ``ds/dx = -(h - (h.d) d) / r``."""
    for q in range(3):
        dsh[q] = 0.0
        dtl[q] = 0.0
    rd = np.sqrt((p[0] - D[0]) ** 2 + (p[1] - D[1]) ** 2 + (p[2] - D[2]) ** 2)
    l0 = fl * rd + r
    acc = 0.0
    da0 = da1 = da2 = 0.0
    for sg in (0.5, -0.5):
        q0 = p[0] + sg * h[0]
        q1 = p[1] + sg * h[1]
        q2 = p[2] + sg * h[2]
        rq = np.sqrt((x[0] - q0) * (x[0] - q0) + (x[1] - q1) * (x[1] - q1) + (x[2] - q2) * (x[2] - q2))
        acc += fl * np.sqrt((q0 - D[0]) * (q0 - D[0]) + (q1 - D[1]) * (q1 - D[1]) + (q2 - D[2]) * (q2 - D[2])) + rq
        da0 += 4.0 * (x[0] - q0) / rq
        da1 += 4.0 * (x[1] - q1) / rq
        da2 += 4.0 * (x[2] - q2) / rq
    a = 4.0 * (acc - 2.0 * l0)
    da0 -= 8.0 * d[0]
    da1 -= 8.0 * d[1]
    da2 -= 8.0 * d[2]
    s = edge_width_m(x, p, D, h, fl, r, rd)
    w = abs(s)
    if not abs(a) < w:
        return 0.0, 0.0
    hd = h[0] * d[0] + h[1] * d[1] + h[2] * d[2]
    sg_s = 1.0 if s > 0.0 else -1.0
    dw = np.empty(3)
    da = np.empty(3)
    da[0], da[1], da[2] = da0, da1, da2
    for q in range(3):
        dw[q] = -sg_s * (h[q] - hd * d[q]) / r
    aa = abs(a)
    if aa <= 0.5 * w:
        for q in range(3):
            dsh[q] = da[q] / 12.0
            dtl[q] = -da[q] / w + a * dw[q] / (w * w)
        return _faded(a, w)
    # the fade, phi = 2 (1 - |a| / w): shift (2 a - 2 a |a| / w) / 12, tilt -2 a / w + 2 a |a| / w^2
    for q in range(3):
        dsh[q] = (2.0 * da[q] - 4.0 * aa * da[q] / w + 2.0 * a * aa * dw[q] / (w * w)) / 12.0
        dtl[q] = (-2.0 * da[q] / w + 2.0 * a * dw[q] / (w * w) + 4.0 * aa * da[q] / (w * w)
                  - 4.0 * a * aa * dw[q] / (w * w * w))
    return _faded(a, w)

