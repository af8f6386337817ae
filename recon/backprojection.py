"""Ellipsoidal backprojection (PAPER.md, Section 4) and filtered backprojection.

Backprojection
    Each histogram bin of the pair (laser spot S_j, wall patch P_k) holds the
    photons whose path length ``R_all = c t`` lies in the bin. Removing the
    known first and last segments ``R_a = |laser - S_j|`` and
    ``R_b = |P_k - detector|`` (when the capture includes them) leaves
    ``R_c + R_d = |S_j - o| + |o - P_k|``: an ellipsoid with foci S_j and P_k.
    The confidence map ``C(v)`` sums, over every pair, the value of the bin
    whose path interval contains voxel ``v``'s path length: each bin's counts
    are spread over its ellipsoid. No radiometric weighting is applied.

    Array captures stream one laser spot (file) at a time; confocal captures
    pair spot k with pixel k (a spot within 1e-6 m of its pixel's patch centre,
    as rendered float32 positions are, is taken to be on it). Memory: the volume, one file, and per-pixel
    distance tables and zero-padded histograms (chunked over pixels, about 64 MiB a chunk), never a
    pairs x voxels array.

Filtered backprojection (``fbp``)
    Each histogram is first filtered in time with the negative second
    derivative of a Gaussian (a band-limited ramp filter, width ``sigma_m`` of
    path length), which sharpens the ellipsoids' intersections, then
    backprojected as above. The output is signed; negative values are
    ringing, not objects.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from transient_core.progress import progress_bar
from transient_core.errors import UserInputError
from .grid import VoxelGrid
from .result import Reconstruction
from .pixel_grid import SAME_SPOT_TOLERANCE_M

__all__ = ["backprojection", "filtered_backprojection", "backproject", "fbp_time_filter"]

#: Bytes of per-pixel distance tables per chunk of pixels.
_TABLE_BYTES = 64 * 2 ** 20
#: Voxel-pair updates per kernel call (about a second on one core): the progress bar's tick.
_SLAB_WORK = 2e9


def _tables(points: np.ndarray, grid: VoxelGrid, scale: float = 1.0, dtype=np.float64):
    """Squared coordinate differences ``(K, nx), (K, ny), (K, nz)`` between points (K, 3) and the grid.

    Differences are multiplied by ``scale`` before squaring (``1 / bin width``: squared distances in
    bins^2), computed in float64 and returned as ``dtype``.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    dx = ((grid.x_m[None, :] - p[:, 0:1]) * scale) ** 2
    dy = ((grid.y_m[None, :] - p[:, 1:2]) * scale) ** 2
    dz = ((grid.z_m[None, :] - p[:, 2:3]) * scale) ** 2
    return tuple(np.ascontiguousarray(t, dtype=dtype) for t in (dx, dy, dz))


def _distance_range_m(points: np.ndarray, grid: VoxelGrid) -> tuple[np.ndarray, np.ndarray]:
    """Nearest and farthest distance (metres) from each point (K, 3) to the box of the grid's voxel centres."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    lo = np.array([grid.x_m.min(), grid.y_m.min(), grid.z_m.min()])
    hi = np.array([grid.x_m.max(), grid.y_m.max(), grid.z_m.max()])
    near = np.linalg.norm(p - np.clip(p, lo, hi), axis=-1)
    far = np.linalg.norm(np.maximum(np.abs(p - lo), np.abs(p - hi)), axis=-1)
    return near, far


#: Zero bins added beyond the computed index range on each side: float32 path lengths in bins round
#: across the bounds by far less than this (float32 spacing is 1/8 bin at 2^20 bins, a few operations).
_PAD_MARGIN = 2
#: Largest padded time axis (bins): beyond it float32 path lengths in bins would be too coarse.
_MAX_PADDED_BINS = 2 ** 20


def _bin_range(capture, grid: VoxelGrid, j: int, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lowest and highest fractional bin index (K,) that any voxel of ``grid`` reaches for the pairs of file ``j``."""
    inv_w = 1.0 / capture.bin_width_m
    ck = (capture.path_offsets_m(j).reshape(-1) - capture.t0_m) * inv_w
    pn, pf = _distance_range_m(P, grid)
    if capture.mode == "confocal":
        sn, sf = _distance_range_m(capture.spots, grid)
    else:
        sn, sf = (np.full(len(P), v[0]) for v in _distance_range_m(capture.spots[j][None], grid))
    return (sn + pn) * inv_w + ck, (sf + pf) * inv_w + ck


def backproject(capture, grid: VoxelGrid, transform: Callable[[int, np.ndarray], np.ndarray] | None = None,
                complex_values: bool = False, description: str = "backprojection") -> np.ndarray:
    """Backproject a capture's (optionally transformed) histograms onto ``grid``.

    Parameters
    ----------
    capture : Capture
    grid : VoxelGrid
    transform : callable ``(j, hist[H, W, T]) -> hist'[H, W, T]``, optional
        Applied to each file's histograms before backprojection (same time axis).
    complex_values : bool
        Backproject complex histograms (``transform`` returns complex values).
    description : str
        Progress bar text.

    Returns
    -------
    ndarray, shape (nz, ny, nx), float64 (complex128 with ``complex_values``)
        Sum over pairs of the bin containing each voxel's path length.

    Each chunk of histograms is copied into a zero-padded float32 (complex64) array whose time axis
    covers every bin index a voxel of ``grid`` can produce (nearest and farthest voxel of the box from
    each spot and pixel), so the kernels need no bounds check: bins outside the capture read zeros,
    exactly as skipping them. Path lengths are computed in float32 bin units (see :mod:`recon._kernels`).
    """
    from . import _kernels

    H, W, T = capture.height, capture.width, capture.n_bins
    K = H * W
    hdtype = np.complex64 if complex_values else np.float32
    out = np.zeros(grid.shape, dtype=np.complex128 if complex_values else np.float64)
    nz = grid.shape[0]
    inv_w = 1.0 / capture.bin_width_m
    P = capture.pixel_centers.reshape(K, 3)
    paired = capture.mode == "confocal"
    # padded time axis: index b + pad for bin b, every reachable index of every file within [0, Tp)
    ranges = [_bin_range(capture, grid, j, P) for j in range(capture.n_files)]
    lo_b = min(int(math.floor(r[0].min())) for r in ranges)
    hi_b = max(int(math.floor(r[1].max())) for r in ranges)
    pad = max(0, -lo_b) + _PAD_MARGIN
    Tp = pad + max(T, hi_b + 1) + _PAD_MARGIN
    if Tp > _MAX_PADDED_BINS:
        raise UserInputError(f"backprojection: the volume's path lengths and the capture's time axis span {Tp} bins of "
                             f"{capture.bin_width_m:.4g} m; at most {_MAX_PADDED_BINS} are supported: use smaller bounds "
                             f"or wider bins (preprocess.downsample_time)")
    per_pixel = 4 * (len(grid.x_m) + len(grid.y_m) + len(grid.z_m)) * (2 if paired else 1) \
        + Tp * np.dtype(hdtype).itemsize
    chunk = max(1, _TABLE_BYTES // per_pixel)
    n_chunks = math.ceil(K / chunk)
    # z slabs: progress ticks of about _SLAB_WORK voxel-pair updates each
    n_slabs = int(min(nz, max(1, round(min(K, chunk) * out.size / _SLAB_WORK))))
    slabs = np.linspace(0, nz, n_slabs + 1).round().astype(int)
    with progress_bar(description, capture.n_files * n_chunks * n_slabs) as advance:
        pix_tables = _tables(P, grid, inv_w, np.float32) if (n_chunks == 1) else None
        if paired:
            S = capture.spots
            same = bool(np.max(np.abs(S - P)) <= SAME_SPOT_TOLERANCE_M)
        for j in range(capture.n_files):
            hist = capture.spot(j)
            if transform is not None:
                hist = transform(j, hist)
            hist = np.asarray(hist).reshape(K, T)
            ck = (capture.path_offsets_m(j).reshape(K) - capture.t0_m) * inv_w + pad
            if not paired:
                dxs, dys, dzs = (t[0] for t in _tables(capture.spots[j][None], grid, inv_w, np.float32))
            for k0 in range(0, K, chunk):
                sl = slice(k0, min(K, k0 + chunk))
                h = np.zeros((sl.stop - sl.start, Tp), dtype=hdtype)
                h[:, pad:pad + T] = hist[sl]
                c = np.ascontiguousarray(ck[sl], dtype=np.float32)
                dxp, dyp, dzp = pix_tables if pix_tables is not None else _tables(P[sl], grid, inv_w, np.float32)
                if paired and not same:
                    sx, sy, sz = _tables(S[sl], grid, inv_w, np.float32)
                for z0, z1 in zip(slabs[:-1], slabs[1:]):
                    o = out[z0:z1]
                    dzp_s = np.ascontiguousarray(dzp[:, z0:z1])
                    if paired and same:
                        _kernels.bp_confocal(h, c, dxp, dyp, dzp_s, o)
                    elif paired:
                        _kernels.bp_paired(h, c, dxp, dyp, dzp_s, sx, sy, np.ascontiguousarray(sz[:, z0:z1]), o)
                    else:
                        _kernels.bp_one_spot(h, c, dxp, dyp, dzp_s, dxs, dys, dzs[z0:z1], o)
                    advance(1)
    return out


def voxel_path_bins(capture, grid: VoxelGrid) -> int:
    """Bins spanned by the path-length range across one voxel (``2 * max voxel side``), at least 1."""
    return max(1, int(round(2 * max(grid.voxel_size_m) / capture.bin_width_m)))


def box_sum(hist: np.ndarray, n: int) -> np.ndarray:
    """Centred moving sum of ``n`` bins along the last axis (float32).

    ``out[b] = sum(hist[b - (n-1)//2 : b + n//2 + 1])`` (bins outside the axis count as 0).
    """
    h = np.asarray(hist, dtype=np.float32)
    if n <= 1:
        return h
    T = h.shape[-1]
    c = np.zeros(h.shape[:-1] + (T + 1,), dtype=np.float64)
    np.cumsum(h, axis=-1, out=c[..., 1:])
    lo = np.clip(np.arange(T) - (n - 1) // 2, 0, T)
    hi = np.clip(np.arange(T) + n // 2 + 1, 0, T)
    return (c[..., hi] - c[..., lo]).astype(np.float32)


def backprojection(capture, grid: VoxelGrid, voxel_integration: bool = True) -> Reconstruction:
    """Ellipsoidal backprojection (the paper's confidence map ``C``) of any capture.

    Parameters
    ----------
    capture : Capture
        Array (one or many spots) or confocal; first/last segments are
        removed exactly from the geometry when included.
    grid : VoxelGrid
    voxel_integration : bool
        Each voxel collects every bin whose ellipsoid passes through the voxel,
        not only the bin at its centre: histograms are summed over a centred
        window of :func:`voxel_path_bins` bins (the path-length range across a
        voxel) before backprojection. Without it, bins much finer than the
        voxels alias (thin shells miss the voxel centres). ``False`` gives the
        pure centre-sampled sum.

    Returns
    -------
    Reconstruction
        ``raw`` = C on ``grid`` (``[z, y, x]``).
    """
    n = voxel_path_bins(capture, grid) if voxel_integration else 1
    transform = (lambda j, h: box_sum(h, n)) if n > 1 else None
    vol = backproject(capture, grid, transform=transform, description="backprojection")
    return Reconstruction(raw=vol.astype(np.float32), grid=grid, method="bp",
                          params={"voxel_integration": bool(voxel_integration), "window_bins": n})


def fbp_time_filter(hist: np.ndarray, sigma_bins: float) -> np.ndarray:
    """Negative second derivative of a Gaussian along the last (time) axis.

    ``-d^2/dt^2 (G_sigma * h)``, in units of 1/bin^2, float32.
    """
    from scipy.ndimage import gaussian_filter1d

    h = np.asarray(hist, dtype=np.float32)
    return -gaussian_filter1d(h, float(sigma_bins), axis=-1, order=2, mode="constant", truncate=4.0)


def filtered_backprojection(capture, grid: VoxelGrid, sigma_m: float | None = None) -> Reconstruction:
    """Backprojection of time-filtered histograms (``-G''`` ramp-like filter).

    Parameters
    ----------
    capture : Capture
    grid : VoxelGrid
    sigma_m : float, optional
        Width (standard deviation, metres of path length) of the Gaussian whose
        negative second derivative filters each histogram; default the larger
        of the voxel size and two bin widths.

    Returns
    -------
    Reconstruction
        ``raw`` = backprojection of the filtered histograms (signed).
    """
    w = capture.bin_width_m
    if sigma_m is None:
        sigma_m = max(max(grid.voxel_size_m), 2 * w)
    if not (isinstance(sigma_m, (int, float)) and math.isfinite(sigma_m) and sigma_m > 0):
        raise UserInputError(f"sigma_m={sigma_m!r} must be a positive number (metres of path length)")
    sigma_bins = sigma_m / w
    if sigma_bins < 1.0:
        raise UserInputError(f"fbp sigma_m={sigma_m:g} m is {sigma_bins:.2f} bins: it must span at least one bin "
                             f"({w:g} m of path)")
    vol = backproject(capture, grid, transform=lambda j, h: fbp_time_filter(h, sigma_bins),
                      description="filtered backprojection")
    return Reconstruction(raw=vol.astype(np.float32), grid=grid, method="fbp", params={"sigma_m": float(sigma_m)})
