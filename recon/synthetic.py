"""Closed-form synthetic NLOS captures of point reflectors.

For a point reflector at ``o`` with albedo ``rho``, laser spot ``S_j`` (normal
``n_S``) and wall patch ``P_k`` (normal ``n_P``), the three-bounce signal is
(PAPER.md, Section 1, for a point target that scatters isotropically)::

    v_jk = rho * cos(o - S_j, n_S) * cos(o - P_k, n_P) / (|o - S_j|^2 |o - P_k|^2)

arriving at path length ``L_jk = |S_j - o| + |o - P_k|`` (plus
``|laser - S_j| + |P_k - detector|`` when the first and last segments are
included). A Gaussian temporal blur of standard deviation ``sigma_ps`` (the
detector's timing resolution) spreads it over bins exactly: bin ``b`` gets
``v_jk * [Phi((e_{b+1} - t)/sigma) - Phi((e_b - t)/sigma)]`` with ``e_b`` the
bin edges and ``t = L_jk / c``. With ``sigma_ps = 0`` the whole ``v_jk`` lands in
the bin containing ``t``.

These captures are the ground truth for the reconstruction tests: the
reflector position is known exactly.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from scipy.special import ndtr

from .capture import Capture
from transient_core.errors import UserInputError
from transient_core.units import C_M_PER_PS

__all__ = ["wall_grid", "point_capture", "to_counts", "default_time_axis"]

#: Default laser and detector origins: in front of the wall (z > 0 side, as the
#: hidden space, but occluded from it), about 1.2 m away.
LASER_ORIGIN = (-0.6, 0.0, 1.0)
DETECTOR_ORIGIN = (-0.6, 0.15, 1.0)


def wall_grid(nx: int, ny: int | None = None, size_m: float | Sequence[float] = 1.0,
              center: Sequence[float] = (0.0, 0.0, 0.0)) -> np.ndarray:
    """Centres of an ``ny x nx`` grid of square-ish patches tiling a wall area in the plane z = const.

    Parameters
    ----------
    nx, ny : int
        Columns (x) and rows (y); ``ny`` defaults to ``nx``.
    size_m : float or (sx, sy)
        Side lengths of the tiled area, metres.
    center : 3 floats
        Centre of the area, metres.

    Returns
    -------
    ndarray, shape (ny, nx, 3)
        Patch centres; ``[0, 0]`` has the smallest x and y.
    """
    ny = nx if ny is None else ny
    sx, sy = (float(size_m), float(size_m)) if np.isscalar(size_m) else map(float, size_m)
    if nx < 1 or ny < 1 or not sx > 0 or not sy > 0:
        raise UserInputError(f"wall_grid: nx={nx}, ny={ny}, size_m={size_m!r} must be positive")
    x = (np.arange(nx) + 0.5) / nx * sx - sx / 2 + center[0]
    y = (np.arange(ny) + 0.5) / ny * sy - sy / 2 + center[1]
    X, Y = np.meshgrid(x, y, indexing="xy")
    return np.stack([X, Y, np.full_like(X, center[2])], axis=-1)


def default_time_axis(paths_m: np.ndarray, bin_width_ps: float, n_bins: int | None, margin_bins: int = 8):
    """``(t0_ps, n_bins)`` covering ``paths_m`` with a margin, t0 a whole number of bins."""
    t_min = float(np.min(paths_m)) / C_M_PER_PS
    t_max = float(np.max(paths_m)) / C_M_PER_PS
    t0 = (math.floor(t_min / bin_width_ps) - margin_bins) * bin_width_ps
    t0 = max(t0, 0.0)
    if n_bins is None:
        n_bins = int(math.ceil((t_max - t0) / bin_width_ps)) + margin_bins
    return t0, int(n_bins)


def point_capture(
    points: Sequence[Sequence[float]] | np.ndarray,
    *,
    albedo: Sequence[float] | float = 1.0,
    mode: str = "array",
    pixels: int | tuple[int, int] = 16,
    wall_size_m: float | tuple[float, float] = 1.0,
    spots: Sequence[Sequence[float]] | np.ndarray | None = None,
    spot_grid: tuple[int, int] | None = None,
    laser_origin: Sequence[float] = LASER_ORIGIN,
    detector_origin: Sequence[float] = DETECTOR_ORIGIN,
    include_first_last: bool = False,
    bin_width_ps: float = 10.0,
    t0_ps: float | None = None,
    n_bins: int | None = None,
    sigma_ps: float = 0.0,
    photons_scale: float = 1.0,
) -> Capture:
    """Ideal capture of point reflectors behind a relay wall in the plane z = 0.

    Parameters
    ----------
    points : array_like, shape (n_points, 3)
        Reflector positions, metres (hidden space z > 0).
    albedo : float or sequence
        Reflectance per point.
    mode : {"array", "confocal"}
        ``array``: every pixel for every laser spot (``spots``; default one
        spot at the wall centre, i.e. a single-spot capture); ``confocal``:
        the laser on each pixel's patch.
    pixels : int or (ny, nx)
        SPAD array size; the patches tile ``wall_size_m`` centred on the origin.
    wall_size_m : float or (sx, sy)
        Wall area seen by the array, metres.
    spots : array_like, shape (n_spots, 3), optional
        Laser spots for ``array`` mode (default ``[[0, 0, 0]]``).
    spot_grid : (ny, nx), optional
        Scan grid of ``spots`` (row-major).
    laser_origin, detector_origin : 3 floats
        Laser and detector positions, metres.
    include_first_last : bool
        Add ``|laser - S_j| + |P_k - detector|`` to every path.
    bin_width_ps : float
        Bin width, ps.
    t0_ps, n_bins : optional
        Time axis; by default it covers every path with a margin of 8 bins.
    sigma_ps : float
        Standard deviation of the Gaussian timing blur, ps (0: none).
    photons_scale : float
        Multiplies every value (e.g. photons per pulse of the laser).

    Returns
    -------
    Capture
        ``kind = "ideal"``, float32 data ``[n_files, H, W, n_bins]``.
    """
    pts = np.atleast_2d(np.asarray(points, dtype=np.float64))
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise UserInputError(f"points has shape {pts.shape}: expected (n_points, 3)")
    if np.any(pts[:, 2] <= 0):
        raise UserInputError("points must lie in the hidden space z > 0")
    rho = np.broadcast_to(np.asarray(albedo, dtype=np.float64), (pts.shape[0],))
    ny, nx = (pixels, pixels) if np.isscalar(pixels) else tuple(pixels)
    P = wall_grid(int(nx), int(ny), wall_size_m)
    n_P = np.array([0.0, 0.0, 1.0])
    lo = np.asarray(laser_origin, dtype=np.float64)
    do = np.asarray(detector_origin, dtype=np.float64)
    if sigma_ps < 0:
        raise UserInputError(f"sigma_ps={sigma_ps!r} must be >= 0")
    if mode == "confocal":
        S = P.reshape(-1, 3)
        # one file: pixel k with spot k
        S_per = P[None]  # (1, H, W, 3): the spot used by each pixel
    elif mode == "array":
        S = np.array([[0.0, 0.0, 0.0]]) if spots is None else np.atleast_2d(np.asarray(spots, dtype=np.float64))
        S_per = np.broadcast_to(S[:, None, None, :], (S.shape[0], int(ny), int(nx), 3))
    else:
        raise UserInputError(f"mode={mode!r}: allowed array, confocal")
    # geometry per (file, pixel, point)
    dS_vec = pts[None, None, None] - S_per[..., None, :]           # (F, H, W, n, 3)
    dP_vec = pts[None, None, None] - P[None, :, :, None, :]        # (1, H, W, n, 3)
    dS = np.linalg.norm(dS_vec, axis=-1)
    dP = np.linalg.norm(dP_vec, axis=-1)
    cosS = np.clip(dS_vec @ n_P / dS, 0.0, None)
    cosP = np.clip(dP_vec @ n_P / dP, 0.0, None)
    amp = photons_scale * rho * cosS * cosP / (dS ** 2 * dP ** 2)   # (F, H, W, n)
    path = dS + dP
    if include_first_last:
        path = path + (np.linalg.norm(S_per - lo, axis=-1) + np.linalg.norm(P - do, axis=-1)[None])[..., None]
    if t0_ps is None:
        t0_ps, n_bins = default_time_axis(path, bin_width_ps, n_bins)
    elif n_bins is None:
        _, n_bins = default_time_axis(path, bin_width_ps, None)
        n_bins = max(1, int(math.ceil((float(np.max(path)) / C_M_PER_PS - t0_ps) / bin_width_ps)) + 8)
    t = path / C_M_PER_PS                                            # ps
    edges = t0_ps + bin_width_ps * np.arange(n_bins + 1)
    data = np.zeros(path.shape[:3] + (n_bins,), dtype=np.float64)
    if sigma_ps > 0:
        for i in range(pts.shape[0]):
            cdf = ndtr((edges[None, None, None, :] - t[..., i, None]) / sigma_ps)
            data += amp[..., i, None] * np.diff(cdf, axis=-1)
    else:
        b = np.floor((t - t0_ps) / bin_width_ps).astype(np.int64)
        ok = (b >= 0) & (b < n_bins)
        F, H, W, n = b.shape
        f, h, w, i = np.nonzero(ok)
        np.add.at(data, (f, h, w, b[f, h, w, i]), amp[f, h, w, i])
    return Capture.from_arrays(
        data.astype(np.float32), mode=mode, spots=S, pixel_centers=P, laser_origin=lo, detector_origin=do,
        t0_ps=float(t0_ps), bin_width_ps=float(bin_width_ps), include_first_last=include_first_last,
        spot_grid=spot_grid if mode == "array" else None,
        manifest_extra={"geometry": {"wall_size_m": list(np.broadcast_to(np.asarray(wall_size_m, float), (2,))),
                                     "pixel_footprint_m": float(np.broadcast_to(np.asarray(wall_size_m, float), (2,))[0] / nx)},
                        "synthetic": {"points": pts.tolist(), "albedo": rho.tolist(), "sigma_ps": float(sigma_ps)}},
        source="synthetic",
    )


def to_counts(capture: Capture, n_pulses: int, seed: int, detector: dict | None = None) -> Capture:
    """Poisson photon counts for ``n_pulses`` pulses of an ideal capture (no pile-up, no noise).

    ``counts ~ Poisson(n_pulses * expected)`` per bin, drawn with
    ``numpy.random.default_rng(seed)``; the manifest's ``detector`` section
    records ``pulses`` (plus ``detector``'s keys).
    """
    if capture.kind != "ideal":
        raise UserInputError(f"to_counts needs an ideal capture, got kind={capture.kind!r}")
    if not n_pulses > 0:
        raise UserInputError(f"n_pulses={n_pulses!r} must be > 0")
    rng = np.random.default_rng(seed)
    lam = capture.data.astype(np.float64) * n_pulses
    if lam.size and lam.max() > 2 ** 31:
        raise UserInputError(f"n_pulses={n_pulses!r}: expected counts up to {lam.max():.3g} overflow uint32 counts")
    counts = rng.poisson(lam).astype(np.uint32)
    det = {"model": "poisson", "pulses": int(n_pulses), "seed": int(seed)}
    det.update(detector or {})
    m = capture.manifest
    return Capture.from_arrays(
        counts, mode=capture.mode, spots=capture.spots, pixel_centers=capture.pixel_centers,
        pixel_normals=capture.pixel_normals, spot_normals=capture.spot_normals,
        laser_origin=capture.laser_origin, detector_origin=capture.detector_origin, t0_ps=capture.t0_ps,
        bin_width_ps=capture.bin_width_ps, include_first_last=capture.include_first_last, kind="counts",
        spot_grid=capture.spot_grid if capture.mode == "array" else None,
        manifest_extra={"detector": det, "synthetic": m.get("synthetic")}, source="synthetic",
    )
