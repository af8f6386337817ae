"""Wave-based reconstructions of confocal captures: LCT (light-cone transform) and f-k migration.

Both need a confocal capture on a regular square pixel grid in the plane
z = 0 (:func:`recon.pixel_grid.require_regular_confocal`) and a time axis that
starts at zero path length; captures are resampled onto it (first/last
segments removed, a start ``t0`` that is not a whole number of bins shifted
by an exact fractional-bin split, :func:`recon.preprocess.resample_time_axis`).
Along the round trip a bin's half path length is the radius
``r = c t / 2`` of the sphere around the pixel's patch.

LCT (O'Toole, Lindell and Wetzstein, Nature 2018)
    For a confocal measurement ``tau(x', y', r) = int rho(x, y, z) / r^4
    delta(r - |(x', y', 0) - (x, y, z)|)``, substituting ``v = r^2``,
    ``u = z^2`` gives a 3-D convolution
    ``v^{3/2} tau(x', y', sqrt v) = h * [rho(x, y, sqrt u) / sqrt u]`` with the
    shift-invariant kernel ``h(dx, dy, dv) = delta(dx^2 + dy^2 - dv)``. We
    resample the data onto a uniform ``v`` grid (linear interpolation in
    ``r``), deconvolve with a Wiener filter in the Fourier domain (zero-padded
    to twice the size on every axis), and map ``u`` back to ``z``
    (``rho = sqrt(u) * R(u)``). ``raw`` is the real part (signed).

f-k migration (Lindell, Wetzstein and O'Toole, SIGGRAPH 2019)
    The exploding-reflector model: the field ``psi = r * sqrt(tau)``
    (amplitude with the 1/r^2 radiometric fall-off of each leg undone down to
    a spherical wave's 1/r) recorded on the wall at z = 0 is a solution of
    the wave equation (unit speed in ``r``) started by ``rho`` at ``r = 0``.
    In the Fourier domain the Stolt mapping gives
    ``rho^(kx, ky, kz) = kz / k * Psi(kx, ky, k)``, ``k = sqrt(kx^2 + ky^2 + kz^2)``,
    for upgoing waves (kz > 0), with linear interpolation along ``k``.
    ``raw = |rho|^2``.

Results are computed on the pixel grid (lateral) and the method's own depth
samples, then interpolated (linearly) onto the requested voxel grid; voxels
more than half a pixel outside the scanned area are zero.
"""

from __future__ import annotations

import math

import numpy as np

from transient_core.errors import UserInputError
from .grid import VoxelGrid
from .preprocess import resample_time_axis
from .result import Reconstruction
from .pixel_grid import require_regular_confocal

__all__ = ["lct", "fk_migration", "confocal_time_volume"]

#: Wiener filter regularisation for LCT: the inverse signal-to-noise ratio is ``1/snr``.
LCT_DEFAULT_SNR = 1e2
_WORKERS = None  # scipy.fft workers: None -> os.cpu_count()


def _workers() -> int:
    import os

    return _WORKERS or max(1, os.cpu_count() or 1)


def confocal_time_volume(capture, grid: VoxelGrid, method: str):
    """Confocal data as ``tau[r, y, x]`` on a time axis from path 0, cropped to what ``grid`` needs.

    Returns
    -------
    tau : ndarray float32 (M, H, W)
        Bin ``b`` holds half path lengths (radii) ``r`` in ``[b dr, (b+1) dr)``.
    dr : float
        Radius step (half the bin's path width), metres.
    wall : RegularGrid
        Pixel coordinates.
    """
    wall = require_regular_confocal(capture, method)
    w_m = capture.bin_width_m
    # deepest radius the volume needs: the farthest voxel from any pixel
    xs = np.array([grid.x_m[0], grid.x_m[-1]])
    ys = np.array([grid.y_m[0], grid.y_m[-1]])
    lat = max(float(np.max(np.abs(xs[:, None] - wall.x_m[None, [0, -1]]))),
              float(np.max(np.abs(ys[:, None] - wall.y_m[None, [0, -1]]))))
    r_need = math.sqrt(grid.z_m[-1] ** 2 + 2 * lat ** 2) + max(grid.voxel_size_m)
    n_need = int(math.ceil(2 * r_need / w_m)) + 2
    cap = resample_time_axis(capture, 0.0, n_bins=None, remove_offsets=True)
    n_keep = min(cap.n_bins, n_need)
    if n_keep < 2:
        raise UserInputError(f"--method {method}: the time axis holds no bin for the requested depths")
    tau = np.asarray(cap.spot(0), dtype=np.float32)[..., :n_keep]
    return np.ascontiguousarray(np.moveaxis(tau, -1, 0)), w_m / 2, wall


def _to_voxels(vol: np.ndarray, z_samples: np.ndarray, wall, grid: VoxelGrid, z_is_u: bool = False) -> np.ndarray:
    """Interpolate ``vol[depth, y_pixel, x_pixel]`` (depth samples ``z_samples``, increasing) onto ``grid``."""
    from scipy.ndimage import map_coordinates

    zq = grid.z_m ** 2 if z_is_u else grid.z_m
    iz = np.interp(zq, z_samples, np.arange(len(z_samples)), left=-1.0, right=-1.0)
    ix = (grid.x_m - wall.x_m[0]) / wall.dx_m
    iy = (grid.y_m - wall.y_m[0]) / wall.dy_m
    nx, ny = len(wall.x_m), len(wall.y_m)
    ok_x = (ix >= -0.5) & (ix <= nx - 0.5)
    ok_y = (iy >= -0.5) & (iy <= ny - 0.5)
    ok_z = iz >= 0
    Z, Y, X = np.meshgrid(iz, np.clip(iy, 0, ny - 1), np.clip(ix, 0, nx - 1), indexing="ij")
    out = map_coordinates(vol, [Z, Y, X], order=1, mode="nearest", prefilter=False)
    mask = ok_z[:, None, None] & ok_y[None, :, None] & ok_x[None, None, :]
    return np.where(mask, out, 0).astype(np.float32)


# ----------------------------------------------------------------------------- LCT


def _padded(n: int) -> int:
    """A fast FFT length of at least ``2 n`` (zero padding against wrap-around)."""
    import scipy.fft as sfft

    return sfft.next_fast_len(2 * n, real=True)


def _lct_psf(shape: tuple[int, int, int], spacing2_over_dv: float, n_v: int) -> np.ndarray:
    """The kernel ``delta(dv - (dx^2 + dy^2))`` on the padded grid ``shape = (Lv, Ly, Lx)``, float32.

    Lateral offsets wrap around (negative offsets at the end); each offset's
    unit weight is split linearly between the two nearest ``v`` samples.
    Offsets ``dv >= n_v`` are left out: in the linear convolution they only
    reach outputs beyond the ``n_v`` kept samples (and would wrap around).
    """
    Lv, Ly, Lx = shape
    psf = np.zeros(shape, dtype=np.float32)
    oy = np.fft.fftfreq(Ly, 1.0 / Ly)  # integer offsets with wrap
    ox = np.fft.fftfreq(Lx, 1.0 / Lx)
    s = (oy[:, None] ** 2 + ox[None, :] ** 2) * spacing2_over_dv  # in v samples
    i0 = np.floor(s).astype(np.int64)
    f = (s - i0).astype(np.float32)
    Y, X = np.nonzero(i0 < n_v - 1)
    np.add.at(psf, (i0[Y, X], Y, X), 1 - f[Y, X])
    np.add.at(psf, (i0[Y, X] + 1, Y, X), f[Y, X])
    return psf


def lct(capture, grid: VoxelGrid, snr: float = LCT_DEFAULT_SNR) -> Reconstruction:
    """Light-cone transform reconstruction of a confocal capture (see the module docstring).

    Parameters
    ----------
    capture : Capture
        Confocal, regular square pixel grid in the plane z = 0.
    grid : VoxelGrid
    snr : float
        Wiener filter signal-to-noise ratio (the regulariser is ``1/snr``
        relative to the kernel's peak spectral power); lower it for noisy data.

    Returns
    -------
    Reconstruction
        ``raw``: the recovered albedo (real part, signed) on ``grid``.
    """
    import scipy.fft as sfft

    if not (isinstance(snr, (int, float)) and math.isfinite(snr) and snr > 0):
        raise UserInputError(f"snr={snr!r} must be a positive number")
    tau, dr, wall = confocal_time_volume(capture, grid, "lct")
    M, ny, nx = tau.shape
    r_max = M * dr
    n_v = M
    dv = r_max ** 2 / n_v
    v = (np.arange(n_v) + 0.5) * dv
    # R_t: v^{3/2} tau(sqrt v), linear interpolation between bin centres (b + 1/2) dr
    pos = np.sqrt(v) / dr - 0.5
    i0 = np.clip(np.floor(pos).astype(np.int64), 0, M - 1)
    i1 = np.clip(i0 + 1, 0, M - 1)
    f = np.clip(pos - np.floor(pos), 0, 1).astype(np.float32)
    f[pos < 0] = 0
    from . import _kernels

    shape = (_padded(n_v), _padded(ny), _padded(nx))
    Lv, Ly, Lx = shape
    data = ((1 - f)[:, None, None] * tau[i0] + f[:, None, None] * tau[i1]) \
        * (v ** 1.5).astype(np.float32)[:, None, None]
    w = _workers()
    # Pruned FFTs: the data fill only [:n_v, :ny, :nx] of the padded grid and the kernel only [:n_v],
    # so transform the small axes first and pad as each axis is transformed.
    D = sfft.fft(sfft.fft(sfft.rfft(data, n=Lx, axis=2, workers=w), n=Ly, axis=1, workers=w, overwrite_x=True),
                 n=Lv, axis=0, workers=w, overwrite_x=True)
    del data
    psf = _lct_psf((n_v, Ly, Lx), wall.dx_m ** 2 / dv, n_v)
    K = sfft.fft(sfft.fft(sfft.rfft(psf, axis=2, workers=w), axis=1, workers=w, overwrite_x=True),
                 n=Lv, axis=0, workers=w, overwrite_x=True)
    del psf
    _kernels.wiener_apply(D, K, 1.0 / snr)                      # D <- D conj(K') / (|K'|^2 + 1/snr), K' = K / max|K|
    del K
    R = sfft.ifft(D, axis=0, workers=w, overwrite_x=True)[:n_v]
    del D
    R = sfft.ifft(R, axis=1, workers=w)[:, :ny]
    R = sfft.irfft(R, n=Lx, axis=2, workers=w)[:, :, :nx]
    rho = (R * np.sqrt(v).astype(np.float32)[:, None, None]).astype(np.float32)
    raw = _to_voxels(rho, v, wall, grid, z_is_u=True)
    return Reconstruction(raw=raw, grid=grid, method="lct",
                          params={"snr": float(snr), "n_v": int(n_v), "r_max_m": float(r_max)})


# ----------------------------------------------------------------------------- f-k


def fk_migration(capture, grid: VoxelGrid) -> Reconstruction:
    """f-k (Stolt) migration of a confocal capture (see the module docstring).

    Returns
    -------
    Reconstruction
        ``raw`` = ``|rho|^2`` on ``grid``.
    """
    import scipy.fft as sfft

    from . import _kernels

    tau, dr, wall = confocal_time_volume(capture, grid, "fk")
    M, ny, nx = tau.shape
    r = ((np.arange(M) + 0.5) * dr).astype(np.float32)
    Lr = 2 * sfft.next_fast_len(M)   # even: the real transform along r has Lr/2 + 1 rows
    Ly, Lx = sfft.next_fast_len(2 * ny), sfft.next_fast_len(2 * nx)
    psi = np.sqrt(np.maximum(tau, 0)) * r[:, None, None]
    w = _workers()
    # pruned FFTs (zero padding applied axis by axis): real transform along r, then y and x
    S = sfft.rfft(psi, n=Lr, axis=0, workers=w)                        # (Lr/2 + 1, ny, nx)
    del psi
    S = sfft.fft(sfft.fft(S, n=Ly, axis=1, workers=w, overwrite_x=True), n=Lx, axis=2, workers=w,
                 overwrite_x=True)
    dk = 1.0 / (Lr * dr)             # cycles per metre along r and z
    ky = sfft.fftfreq(Ly, wall.dy_m)
    kx = sfft.fftfreq(Lx, wall.dx_m)
    out = np.zeros(S.shape, dtype=np.complex64)                        # kz = i dk >= 0 only
    _kernels.stolt(S, ky, kx, dk, out)
    del S
    rho = sfft.ifft(out, axis=2, workers=w, overwrite_x=True)[:, :, :nx]
    rho = sfft.ifft(rho, axis=1, workers=w)[:, :ny]
    rho = sfft.ifft(rho, n=Lr, axis=0, workers=w)[:M]
    raw = (rho.real ** 2 + rho.imag ** 2).astype(np.float32)
    z = (np.arange(M) + 0.5) * dr
    vol = _to_voxels(raw, z, wall, grid)
    return Reconstruction(raw=vol, grid=grid, method="fk", params={"n_r": int(M)})
