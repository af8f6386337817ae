"""Array (non-confocal) captures as approximately confocal ones: the midpoint conversion.

For laser spot ``S`` and wall patch ``P`` (both in the plane z = 0), a hidden
point ``o`` on the plane through the midpoint ``M = (S + P) / 2`` normal to
``S - P`` (the bisector plane) has ``|o - S| = |o - P| = sqrt(r^2 + d^2 / 4)``,
``r = |o - M|``, ``d = |S - P|``, so its three-bounce path length ``L`` and
the round-trip path ``Lc = 2 r`` of a confocal measurement at ``M`` satisfy
exactly (the normal-moveout relation of seismic common-midpoint stacking)::

    Lc^2 = L^2 - d^2.

For points off the bisector plane the relation is an approximation whose
path error is second order in ``d`` times the lateral offset over the depth;
it is the *midpoint approximation*. Each histogram ``(S_j, P_k)`` is moved to
its midpoint and its time axis is remapped from ``L`` to ``Lc`` by that
relation. The remapping integrates: the histogram's cumulative sum
(piecewise linear in ``L``) is evaluated at the images
``L_e = sqrt(Lc_e^2 + d^2)`` of the output bin edges ``Lc_e`` and
differenced, so photons are kept (apart from paths shorter than ``d``, which
no hidden point produces) and an output bin coarser than the input's
integrates rather than samples. Optionally (``radiometric=True``, the
default) each output bin is multiplied by ``(L / Lc)^6`` at its centre, which
makes the three-bounce amplitude of a point on the bisector plane,
``cos_S cos_P / (|o - S|^2 |o - P|^2) = 64 z^2 / L^6``, equal to the confocal
``cos^2 / r^4 = 64 z^2 / Lc^6`` at ``M`` (Lambertian wall cosines, ``z`` the
point's depth): the fall-off the confocal methods assume.

The midpoints of every (spot, pixel) pair are binned onto a regular square
grid (default spacing: half the pixel pitch, the spacing of one spot's
midpoints); pairs falling in the same cell are averaged, and cells no pair
reaches stay zero. The result is a confocal capture (laser spot k on patch
k) that :func:`recon.confocal.lct` and :func:`recon.confocal.fk_migration`
accept. Note the geometry: midpoints cover the wall area the pixels span
scaled by one half about each spot, so the confocal aperture is about half
the array's (plus the spread of the spots).

Memory: one laser spot's histograms at a time plus the output
``[H_c, W_c, n_bins_c]`` float64 sums.
"""

from __future__ import annotations

import math

import numpy as np

from .capture import Capture
from transient_core.errors import UserInputError
from transient_core.units import C_M_PER_PS
from .pixel_grid import regular_pixel_grid

__all__ = ["midpoint_confocal", "default_midpoint_bin_width_ps"]


def default_midpoint_bin_width_ps(capture: Capture, grid=None) -> float:
    """Output bin width: the capture's, or half the smallest voxel side of path if coarser (ps).

    A confocal bin of path width ``w`` spans a radius ``w / 2``; with ``w`` at
    most the smallest voxel side the depth sampling stays finer than the voxels.
    """
    w = capture.bin_width_ps
    if grid is not None:
        w = max(w, 0.5 * min(grid.voxel_size_m) / C_M_PER_PS)
    return float(w)


def midpoint_confocal(capture: Capture, pitch_m: float | None = None, bin_width_ps: float | None = None,
                      n_bins: int | None = None, radiometric: bool = True) -> Capture:
    """Convert an array capture to an approximately confocal one (see the module docstring).

    Parameters
    ----------
    capture : Capture
        Array capture; pixels on a regular axis-aligned grid and laser spots,
        both in the plane z = 0 with normal +z.
    pitch_m : float, optional
        Spacing of the output (midpoint) grid, metres; default half the pixel
        pitch (the smaller of x and y).
    bin_width_ps : float, optional
        Output bin width (round-trip path), ps; default the capture's.
    n_bins : int, optional
        Output bins from ``t = 0``; default: up to the longest confocal path the
        capture's time axis can hold.
    radiometric : bool
        Multiply by ``(L / Lc)^6`` (exact fall-off for points on the bisector plane).

    Returns
    -------
    Capture
        ``mode = "confocal"``, ``t0_ps = 0``, first/last segments excluded,
        ``kind = "ideal"`` (averaged values are not whole counts; the manifest's
        ``quantity`` says ``midpoint_<original quantity>``), pixels on the
        midpoint grid ``[H_c, W_c]``.

    Raises
    ------
    UserInputError
        For a confocal capture, pixels off a regular grid in the plane z = 0,
        or spots off that plane.
    """
    if capture.mode != "array":
        raise UserInputError(f"midpoint conversion needs an array capture, got a {capture.mode} capture")
    wall = regular_pixel_grid(capture, "midpoint")
    if wall is None or not capture.wall_is_z0(atol=1e-6):
        raise UserInputError("midpoint conversion needs the pixels on a regular axis-aligned grid and the laser "
                             "spots in the relay-wall plane z = 0 with normal +z; use bp, fbp or phasor")
    dx, dy = (wall.dx_m, wall.dy_m)
    pitch_pix = min(v for v in (dx, dy) if math.isfinite(v)) if any(math.isfinite(v) for v in (dx, dy)) else None
    if pitch_m is None:
        if pitch_pix is None:
            raise UserInputError("midpoint conversion of a single-pixel capture needs pitch_m")
        pitch_m = pitch_pix / 2
    pitch_m = float(pitch_m)
    if not (math.isfinite(pitch_m) and pitch_m > 0):
        raise UserInputError(f"pitch_m={pitch_m!r} must be a positive number (metres)")
    w_ps = capture.bin_width_ps if bin_width_ps is None else float(bin_width_ps)
    if not (math.isfinite(w_ps) and w_ps > 0):
        raise UserInputError(f"bin_width_ps={bin_width_ps!r} must be a positive number (ps)")
    w_out = w_ps * C_M_PER_PS
    w_in = capture.bin_width_m
    t0_in = capture.t0_m

    P = capture.pixel_centers.reshape(-1, 3)
    S = capture.spots
    mids = (S[:, None, :2] + P[None, :, :2]) / 2                          # (n_spots, K, 2)
    lo = mids.reshape(-1, 2).min(axis=0)
    hi = mids.reshape(-1, 2).max(axis=0)
    # grid aligned with spot 0's first midpoint, covering every midpoint
    origin = mids[0, 0]
    i_lo = np.floor((lo - origin) / pitch_m + 0.5 - 1e-9).astype(int)
    i_hi = np.floor((hi - origin) / pitch_m + 0.5 + 1e-9).astype(int)
    nxc, nyc = int(i_hi[0] - i_lo[0] + 1), int(i_hi[1] - i_lo[1] + 1)
    xc = origin[0] + (np.arange(nxc) + i_lo[0]) * pitch_m
    yc = origin[1] + (np.arange(nyc) + i_lo[1]) * pitch_m
    if nxc * nyc > 4096 ** 2:
        raise UserInputError(f"pitch_m={pitch_m:g} gives a {nyc}x{nxc} midpoint grid; choose a coarser pitch")

    d_max = float(np.max(np.linalg.norm(S[:, None, :2] - P[None, :, :2], axis=-1)))
    L_max = t0_in + capture.n_bins * w_in     # longest recorded path (before removing first/last)
    if n_bins is None:
        n_bins = max(1, int(math.ceil(max(L_max ** 2 - 0.0, 0.0) ** 0.5 / w_out)))
    n_bins = int(n_bins)
    if n_bins < 1:
        raise UserInputError(f"n_bins={n_bins!r} must be >= 1")
    Lc_edges = w_out * np.arange(n_bins + 1, dtype=np.float64)
    Lc_mid = w_out * (np.arange(n_bins, dtype=np.float64) + 0.5)

    sums = np.zeros((nyc * nxc, n_bins), dtype=np.float64)
    hits = np.zeros(nyc * nxc, dtype=np.int64)
    K = P.shape[0]
    T = capture.n_bins
    for j in range(capture.n_files):
        h = np.asarray(capture.spot(j), dtype=np.float64).reshape(K, T)
        cum = np.zeros((K, T + 1))
        np.cumsum(h, axis=1, out=cum[:, 1:])
        off = capture.path_offsets_m(j).reshape(K)
        d2 = np.sum((P[:, :2] - S[j, :2]) ** 2, axis=1)                  # (K,)
        L_e = np.sqrt(Lc_edges[None, :] ** 2 + d2[:, None]) + off[:, None]  # recorded path of each output edge
        pos = np.clip((L_e - t0_in) / w_in, 0.0, float(T))                # fractional input edge index
        i0 = np.minimum(np.floor(pos).astype(np.int64), T - 1)
        fr = pos - i0
        rows = np.arange(K)[:, None]
        c = cum[rows, i0] * (1 - fr) + cum[rows, i0 + 1] * fr             # cumulative at each output edge
        out = np.diff(c, axis=1)                                           # (K, n_bins)
        if radiometric:
            Lm = np.sqrt(Lc_mid[None, :] ** 2 + d2[:, None])
            out *= (Lm / Lc_mid[None, :]) ** 6
        cell_x = np.floor((mids[j, :, 0] - xc[0]) / pitch_m + 0.5).astype(np.int64)
        cell_y = np.floor((mids[j, :, 1] - yc[0]) / pitch_m + 0.5).astype(np.int64)
        cell = np.clip(cell_y, 0, nyc - 1) * nxc + np.clip(cell_x, 0, nxc - 1)
        np.add.at(sums, cell, out)
        np.add.at(hits, cell, 1)
    data = np.where(hits[:, None] > 0, sums / np.maximum(hits, 1)[:, None], 0.0)
    Xc, Yc = np.meshgrid(xc, yc, indexing="xy")
    centres = np.stack([Xc, Yc, np.zeros_like(Xc)], axis=-1)
    q = capture.manifest.get("quantity") or ("counts" if capture.kind == "counts" else "photons_per_pulse")
    extra = {
        "midpoint": {"pitch_m": pitch_m, "radiometric": bool(radiometric), "max_separation_m": d_max,
                     "pairs_per_cell_max": int(hits.max()), "empty_cells": int(np.count_nonzero(hits == 0)),
                     "source_capture": capture.source, "source_kind": capture.kind},
        "detector": capture.manifest.get("detector"),
    }
    cap = Capture.from_arrays(
        data.reshape(nyc, nxc, n_bins).astype(np.float32), mode="confocal", spots=centres.reshape(-1, 3),
        pixel_centers=centres, laser_origin=capture.laser_origin, detector_origin=capture.detector_origin,
        t0_ps=0.0, bin_width_ps=w_ps, include_first_last=False, kind="ideal", quantity=f"midpoint_{q}",
        manifest_extra=extra, source=f"midpoint({capture.source or 'capture'})")
    import dataclasses

    step = f"midpoint_confocal(pitch_m={pitch_m:g}, bin_width_ps={w_ps:g}, radiometric={bool(radiometric)})"
    return dataclasses.replace(cap, processing=capture.processing + (step,))
