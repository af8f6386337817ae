"""Time gate: the SPAD's detection efficiency over the laser cycle.

Shape
-----
A gated SPAD is armed (biased above breakdown) between ``gate_open_ps`` and
``gate_close_ps``. Its bias cannot switch instantly, so the efficiency ramps
up and down. We model the efficiency as the ideal rectangular gate smoothed by
a Gaussian of standard deviation ``s``::

    g(t) = Phi((t - t_open) / s) - Phi((t - t_close) / s)

with ``Phi`` the standard normal CDF. Each edge is then an error-function
step whose 10-90 % time is ``2 * 1.28155 * s``, so

    s = gate_transition_ps / 2.563103

makes the 10-90 % transition equal to ``gate_transition_ps``.
``gate_open_ps`` and ``gate_close_ps`` are the 50 % points. ``g`` is between
0 and 1; for a gate shorter than a few ``s`` it never reaches 1.
``gate_transition_ps = 0`` gives the ideal rectangle. The gate repeats every
laser period (sum of the shifted copies, still <= 1 because the gate is
shorter than the period). Times are on the capture's time axis (the one its
bins are on, see ``include_first_last``).

The gate multiplies every avalanche source: signal photons (after the PDE),
ambient light and dark counts (the SPAD is not armed outside the gate), and
the triggering of afterpulses and crosstalk.

Automatic gate
--------------
:func:`auto_gate` opens the gate for the three-bounce light of a hidden
volume, as the reference experiment does, which blocks the wall's own
first-bounce return: with ``t_early``/``t_late`` the earliest/latest arrival
over every (laser spot, pixel) pair and every point of the hidden volume,
``t_open = t_early - gate_transition_ps`` and ``t_close = t_late +
gate_transition_ps`` (at ``t_early`` the gate is then 99.5 % open).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import ndtr

from transient_core.errors import UserInputError
from transient_core.units import C_M_PER_PS

#: 10-90 % time of an error-function edge in units of its sigma: 2 * Phi^-1(0.9).
TEN_NINETY_PER_SIGMA = 2.0 * 1.2815515655446004


def gate_sigma_ps(gate_transition_ps: float) -> float:
    """Gaussian sigma (ps) of a gate edge whose 10-90 % time is ``gate_transition_ps``."""
    return gate_transition_ps / TEN_NINETY_PER_SIGMA


def _shifts(period_ps):
    return (0.0,) if period_ps is None else tuple(k * period_ps for k in (-2, -1, 0, 1, 2))


def gate_efficiency(t_ps, gate_open_ps: float | None, gate_close_ps: float | None,
                    gate_transition_ps: float, period_ps: float | None = None) -> np.ndarray:
    """Gate efficiency ``g(t)`` in [0, 1] at times ``t_ps`` (capture time axis).

    ``gate_open_ps=None`` means no gate (``g = 1``). With ``period_ps`` the gate
    repeats every period.
    """
    t = np.asarray(t_ps, dtype=np.float64)
    if gate_open_ps is None:
        return np.ones_like(t)
    s = gate_sigma_ps(gate_transition_ps)
    g = np.zeros_like(t)
    for sh in _shifts(period_ps):
        if s > 0:
            g += ndtr((t - gate_open_ps - sh) / s) - ndtr((t - gate_close_ps - sh) / s)
        else:
            g += ((t >= gate_open_ps + sh) & (t < gate_close_ps + sh)).astype(np.float64)
    return np.clip(g, 0.0, 1.0)


def _edge_integral(a, b, t_edge, s):
    """Integral over [a, b] of Phi((t - t_edge) / s) dt (a step for s = 0)."""
    if s <= 0:
        return np.maximum(b, t_edge) - np.maximum(a, t_edge)

    def H(x):  # antiderivative of Phi: x Phi(x) + phi(x)
        return x * ndtr(x) + np.exp(-0.5 * x * x) / math.sqrt(2.0 * math.pi)

    return s * (H((b - t_edge) / s) - H((a - t_edge) / s))


def gate_mean(edges_ps, gate_open_ps: float | None, gate_close_ps: float | None,
              gate_transition_ps: float, period_ps: float | None = None) -> np.ndarray:
    """Mean gate efficiency over each interval ``[edges[i], edges[i+1])`` (exact).

    Parameters
    ----------
    edges_ps : ndarray, shape (n + 1,)
        Increasing interval boundaries on the capture's time axis, ps.

    Returns
    -------
    ndarray, shape (n,)
    """
    e = np.asarray(edges_ps, dtype=np.float64)
    a, b = e[:-1], e[1:]
    if gate_open_ps is None:
        return np.ones(len(a))
    s = gate_sigma_ps(gate_transition_ps)
    tot = np.zeros(len(a))
    for sh in _shifts(period_ps):
        tot += _edge_integral(a, b, gate_open_ps + sh, s) - _edge_integral(a, b, gate_close_ps + sh, s)
    return np.clip(tot / (b - a), 0.0, 1.0)


def transition_10_90_ps(t_ps, g) -> tuple[float, float]:
    """Measured 10-90 % rise and 90-10 % fall times of a sampled gate profile.

    Linear interpolation between samples; for checks and plots.
    """
    t = np.asarray(t_ps, float)
    g = np.asarray(g, float)
    k = int(np.argmax(g))
    top = g[k]

    def cross(ts, gs, level):
        i = int(np.argmax(gs >= level))
        if i == 0:
            return ts[0]
        return ts[i - 1] + (level - gs[i - 1]) * (ts[i] - ts[i - 1]) / (gs[i] - gs[i - 1])

    rise = cross(t[:k + 1], g[:k + 1], 0.9 * top) - cross(t[:k + 1], g[:k + 1], 0.1 * top)
    tr, gr = t[k:][::-1], g[k:][::-1]
    fall = cross(tr, gr, 0.1 * top) - cross(tr, gr, 0.9 * top)
    return float(rise), float(fall)


# ------------------------------------------------------------------- automatic


def _wall_frame(geo: dict):
    centers = np.asarray(geo["pixel_centers"], float).reshape(-1, 3)
    spots = np.asarray(geo["spots"], float).reshape(-1, 3)
    n = geo.get("wall_normal")
    if n is None:
        n = np.asarray(geo["pixel_normals"], float).reshape(-1, 3).mean(0)
    n = np.asarray(n, float)
    if not np.linalg.norm(n) > 0:
        raise UserInputError(f"geometry.wall_normal={geo.get('wall_normal')!r} has zero length")
    n = n / np.linalg.norm(n)
    ref = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = ref - n * (ref @ n)
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    pts = np.concatenate([centers, spots])
    c = 0.5 * (pts.min(0) + pts.max(0))
    c = c - n * ((c - centers.mean(0)) @ n)  # on the wall plane
    return c, n, u, v, centers, spots


def hidden_volume_corners(geo: dict, depth_min_m: float, depth_max_m: float) -> np.ndarray:
    """Corners (8, 3) of the hidden volume used by :func:`auto_gate`.

    ``geometry.hidden_volume = {"min_m": [x, y, z], "max_m": [x, y, z]}`` (an
    axis-aligned box in the world frame) wins when the manifest has it.
    Otherwise: the relay wall's extent (``geometry.wall_size_m`` around the
    centre of the pixel patches and laser spots, or their bounding box plus one
    pixel footprint) times the depth range ``[depth_min_m, depth_max_m]``
    along the wall normal.
    """
    hv = geo.get("hidden_volume")
    if isinstance(hv, dict) and "min_m" in hv and "max_m" in hv:
        lo, hi = np.asarray(hv["min_m"], float), np.asarray(hv["max_m"], float)
        if lo.shape != (3,) or hi.shape != (3,) or not np.all(hi > lo):
            raise UserInputError(f"geometry.hidden_volume={hv!r}: need min_m < max_m, 3 numbers each")
        return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    c, n, u, v, centers, spots = _wall_frame(geo)
    size = geo.get("wall_size_m")
    if size is not None and len(size) == 2 and all(float(s) > 0 for s in size):
        hu, hv_ = 0.5 * float(size[0]), 0.5 * float(size[1])
    else:
        pts = np.concatenate([centers, spots]) - c
        fp = float(geo.get("pixel_footprint_m") or 0.0)
        hu = np.abs(pts @ u).max() + 0.5 * fp
        hv_ = np.abs(pts @ v).max() + 0.5 * fp
    return np.array([c + a * hu * u + b * hv_ * v + d * n
                     for a in (-1, 1) for b in (-1, 1) for d in (depth_min_m, depth_max_m)])


def three_bounce_range_ps(manifest: dict, depth_min_m: float = 0.1, depth_max_m: float = 1.5,
                          spot: int | None = None) -> tuple[float, float]:
    """Earliest and latest three-bounce arrival (capture time axis, ps) for the hidden volume.

    Paths laser -> S_j -> o -> P_k -> detector with o in the hidden volume
    (:func:`hidden_volume_corners`), over every (laser spot, pixel) pair of
    the capture (spot k with pixel k for confocal captures), or over the
    pixels of laser spot ``spot`` alone. The laser->wall and wall->detector
    segments count only when ``include_first_last``.

    The latest arrival is exact (a sum of distances is convex, so its maximum
    over a box is at a corner). The earliest is a lower bound: the larger of
    ``|S - P|`` and the mirror-image (Heron) distance to the volume's nearest
    plane parallel to the wall; it is exact when the mirror point lies inside
    the volume's face, and otherwise opens the gate slightly early, never late.
    """
    geo = manifest.get("geometry")
    if not isinstance(geo, dict) or "spots" not in geo or "pixel_centers" not in geo:
        raise UserInputError("auto_gate needs the capture geometry (laser spots and pixel patches) in its "
                             "manifest; this capture has none: give gate_open_ps and gate_close_ps instead")
    corners = hidden_volume_corners(geo, depth_min_m, depth_max_m)
    c, n, _, _, centers, spots = _wall_frame(geo)
    H, W = manifest["height"], manifest["width"]
    if manifest.get("capture") == "confocal":
        S = spots.reshape(H * W, 3)
        P = centers.reshape(H * W, 3)
    elif spot is not None:
        S = np.repeat(spots[int(spot)][None], len(centers), axis=0)
        P = centers
    else:
        S = np.repeat(spots, len(centers), axis=0)
        P = np.tile(centers, (len(spots), 1))
    first_last = np.zeros(len(S))
    if manifest.get("include_first_last"):
        lo = np.asarray(geo["laser_origin"], float)
        de = np.asarray(geo["detector_origin"], float)
        first_last = np.linalg.norm(S - lo, axis=1) + np.linalg.norm(P - de, axis=1)
    # latest: maximum over the corners (convexity)
    d_max = np.max(np.linalg.norm(S[:, None] - corners[None], axis=2)
                   + np.linalg.norm(P[:, None] - corners[None], axis=2), axis=1)
    # earliest: lower bound via the nearest plane of the volume (mirror image of S)
    depth_near = float(np.min((corners - c) @ n))
    dS, dP = (S - c) @ n, (P - c) @ n
    mirror = S + (2.0 * (depth_near - dS))[:, None] * n
    heron = np.linalg.norm(mirror - P, axis=1)
    same_side = (dS < depth_near) & (dP < depth_near)
    d_min = np.maximum(np.linalg.norm(S - P, axis=1), np.where(same_side, heron, 0.0))
    t_early = float(np.min(d_min + first_last)) / C_M_PER_PS
    t_late = float(np.max(d_max + first_last)) / C_M_PER_PS
    return t_early, t_late


def auto_gate(manifest: dict, gate_transition_ps: float, depth_min_m: float = 0.1,
              depth_max_m: float = 1.5, spot: int | None = None) -> tuple[float, float]:
    """Gate times ``(gate_open_ps, gate_close_ps)`` passing the three-bounce light of the hidden volume.

    See :func:`three_bounce_range_ps`; the 50 % points are placed one
    transition time outside ``[t_early, t_late]``. ``spot``: the gate for
    that laser spot only (array captures gate every laser position
    separately, as a gated SPAD array is re-timed for each acquisition).
    """
    t_early, t_late = three_bounce_range_ps(manifest, depth_min_m, depth_max_m, spot=spot)
    return t_early - gate_transition_ps, t_late + gate_transition_ps
