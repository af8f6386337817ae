"""Phasor-field reconstruction (Liu et al., Nature 2019; fast RSD propagation, Liu et al. 2020).

A virtual illumination pulse, a Gaussian-modulated wave of central wavelength
``lambda`` (``wavelength_m``) and envelope standard deviation ``sigma``
(``pulse_sigma_m``, both in metres of path length), is applied to every
histogram; the reconstruction is the field of a virtual confocal, time-gated
camera focused on each voxel ``v``::

    U(v) = sum_f w_f sum_{j,k} P_jk(f) exp(i 2 pi f (|v - S_j| + |v - P_k|))
    P_jk(f) = sum_b H_jk[b] exp(-i 2 pi f r_b)       (r_b: bin-centre path, first/last removed)
    w_f = exp(-(f - 1/lambda)^2 / (2 sigma_f^2)),     sigma_f = 1 / (2 pi sigma)

over frequencies ``f`` (cycles per metre of path) within 3 sigma_f of
``1/lambda``, spaced finely enough that the time window of the data does not
alias. ``raw = |U(v)|``. This is the backprojection of the histograms
filtered with the complex virtual pulse, evaluated exactly at voxel centres.

Fast path (the relay-wall pixels on a regular axis-aligned grid in the plane
z = 0, every depth slice parallel to it): the sum over pixels is, for each
frequency and depth, a 2-D convolution with the phase-only
Rayleigh-Sommerfeld kernel ``exp(i 2 pi f m sqrt(dx^2 + dy^2 + z^2))``
(``m = 1``; ``m = 2`` for confocal captures, whose paths go there and back),
evaluated with FFTs on a lateral grid aligned with the pixels and at most as
coarse as the voxels, then interpolated (bilinearly, complex) to the voxel
centres. The laser-spot leg ``exp(i 2 pi f |v - S_j|)`` multiplies each spot's
field before the coherent sum. First/last segments are removed exactly as a
phase ``exp(+i 2 pi f offset_jk)``.

Other geometries use the same formula through the complex backprojection
kernel (slower, same result up to discretisation).
"""

from __future__ import annotations

import math

import numpy as np

from transient_core.progress import progress_bar
from transient_core.errors import UserInputError
from .grid import VoxelGrid
from .result import Reconstruction
from .pixel_grid import regular_pixel_grid

__all__ = ["phasor_fields", "virtual_wave", "default_wavelength_m"]

#: Bytes allowed for the per-spot frequency-domain fields held at once.
_SPOT_CHUNK_BYTES = 256 * 2 ** 20


def default_wavelength_m(capture) -> float:
    """Four pixel spacings, and at least four bin widths of path length."""
    dx, dy = capture.pixel_pitch_m()
    d = max(v for v in (dx, dy, 0.0) if math.isfinite(v))
    return max(4 * d, 4 * capture.bin_width_m)


def _path_window_m(capture, grid: VoxelGrid | None) -> tuple[float, float]:
    """Range of path lengths that must not alias: the data's bins and every voxel's |v-S|+|v-P|."""
    offs = [capture.path_offsets_m(j) for j in range(capture.n_files)] if capture.include_first_last else [np.zeros(1)]
    lo = capture.t0_m - max(float(o.max()) for o in offs)
    hi = capture.t0_m + capture.n_bins * capture.bin_width_m - min(float(o.min()) for o in offs)
    if grid is not None:
        b = np.array(grid.bounds).reshape(3, 2)
        corners = np.array([[x, y, z] for x in b[0] for y in b[1] for z in b[2]])
        S = capture.spots
        P = capture.pixel_centers.reshape(-1, 3)

        def near(pts):  # distance from each point to the box
            return np.linalg.norm(pts - np.clip(pts, b[:, 0], b[:, 1]), axis=-1)

        def far(pts):
            return np.max(np.linalg.norm(pts[:, None] - corners[None], axis=-1), axis=1)

        lo = min(lo, float(near(S).min() + near(P).min()))
        hi = max(hi, float(far(S).max() + far(P).max()))
    return lo, hi


def virtual_wave(capture, wavelength_m: float | None, pulse_sigma_m: float | None, grid: VoxelGrid | None = None):
    """Frequencies (cycles/m) and weights of the virtual pulse for ``capture``.

    The frequency step is the inverse of the range of path lengths involved
    (the data's time axis and, with ``grid``, every voxel's path) plus six
    pulse widths, so the periodic sum over frequencies does not alias.

    Returns ``(freqs, weights, wavelength_m, pulse_sigma_m)``.
    """
    lam = default_wavelength_m(capture) if wavelength_m is None else float(wavelength_m)
    if not (math.isfinite(lam) and lam > 0):
        raise UserInputError(f"wavelength_m={wavelength_m!r} must be a positive number (metres)")
    sigma = lam if pulse_sigma_m is None else float(pulse_sigma_m)
    if not (math.isfinite(sigma) and sigma > 0):
        raise UserInputError(f"pulse_sigma_m={pulse_sigma_m!r} must be a positive number (metres)")
    fc = 1.0 / lam
    sf = 1.0 / (2 * math.pi * sigma)
    f_nyq = 1.0 / (2 * capture.bin_width_m)
    if fc + 3 * sf > f_nyq:
        lam_min = 1.0 / (f_nyq - 3 * sf) if f_nyq > 3 * sf else math.inf
        raise UserInputError(
            f"virtual wavelength {lam:.4g} m (pulse sigma {sigma:.4g} m) is too short for bins of "
            f"{capture.bin_width_m:.4g} m of path: the pulse's band exceeds the Nyquist frequency; "
            f"use a wavelength of at least {lam_min:.4g} m")
    lo, hi = _path_window_m(capture, grid)
    window = (hi - lo) + 6 * sigma
    df = 1.0 / window
    n_f = int(math.ceil(6 * sf / df)) + 1
    freqs = fc + (np.arange(n_f) - (n_f - 1) / 2) * df
    freqs = freqs[freqs > 0]
    weights = np.exp(-((freqs - fc) ** 2) / (2 * sf ** 2)) * df
    return freqs, weights, lam, sigma


def _phasors(capture, j: int, hist: np.ndarray, freqs: np.ndarray) -> np.ndarray:
    """``P[f, y, x] = sum_b H[y, x, b] exp(-i 2 pi f r_b) * exp(+i 2 pi f offset)``, complex64.

    ``freqs`` evenly spaced (:func:`virtual_wave`). The sum is :func:`recon._kernels.phasor_project`'s, not a BLAS
    product, so the bytes do not depend on the number of threads.
    """
    from . import _kernels

    H, W, T = hist.shape
    r = capture.t0_m + (np.arange(T) + 0.5) * capture.bin_width_m
    f0, df = _freq_step(freqs)
    P = np.empty((len(freqs), H * W), dtype=np.complex64)
    _kernels.phasor_project(np.ascontiguousarray(np.asarray(hist, dtype=np.float32).reshape(H * W, T)), r, f0, df, P)
    if capture.include_first_last:
        off = capture.path_offsets_m(j).reshape(H * W)
        P *= np.exp(2j * np.pi * np.outer(freqs, off)).astype(np.complex64)
    return P.reshape(len(freqs), H, W)


def _freq_step(freqs: np.ndarray) -> tuple[float, float]:
    """First frequency and step of evenly spaced ``freqs`` (ValueError otherwise)."""
    F = len(freqs)
    f0 = float(freqs[0])
    df = float(freqs[-1] - freqs[0]) / (F - 1) if F > 1 else 0.0
    if F > 2 and not np.allclose(np.diff(freqs), df, rtol=1e-9, atol=0.0):
        raise ValueError("phasor fields: the frequencies must be evenly spaced")
    return f0, df


def phasor_fields(capture, grid: VoxelGrid, wavelength_m: float | None = None,
                  pulse_sigma_m: float | None = None, method: str = "auto") -> Reconstruction:
    """Phasor-field reconstruction of any capture (see the module docstring).

    Parameters
    ----------
    capture : Capture
    grid : VoxelGrid
    wavelength_m : float, optional
        Central wavelength of the virtual wave (metres); default four pixel
        spacings (and at least four bin widths).
    pulse_sigma_m : float, optional
        Standard deviation of the virtual pulse envelope (metres of path);
        default one wavelength.
    method : {"auto", "rsd", "backprojection"}
        ``rsd`` (FFT convolution; needs a regular pixel grid in the plane
        z = 0), ``backprojection`` (any geometry), ``auto`` picks ``rsd`` when possible.

    Returns
    -------
    Reconstruction
        ``raw = |U|`` on ``grid``.
    """
    freqs, weights, lam, sigma = virtual_wave(capture, wavelength_m, pulse_sigma_m, grid)
    wall = regular_pixel_grid(capture, "phasor")
    if method not in ("auto", "rsd", "backprojection"):
        raise UserInputError(f"phasor method={method!r}: allowed auto, rsd, backprojection")
    if method == "rsd" and wall is None:
        raise UserInputError("phasor method='rsd' needs the pixels on a regular axis-aligned grid in the plane z = 0")
    use_rsd = method != "backprojection" and wall is not None
    params = {"wavelength_m": lam, "pulse_sigma_m": sigma, "n_frequencies": int(len(freqs)),
              "implementation": "rsd" if use_rsd else "backprojection"}
    if use_rsd:
        U = _rsd(capture, grid, wall, freqs, weights)
    else:
        U = _phasor_bp(capture, grid, freqs, weights, sigma)
    return Reconstruction(raw=np.abs(U).astype(np.float32), grid=grid, method="phasor", params=params)


# ------------------------------------------------------------------ backprojection form


def _phasor_bp(capture, grid, freqs, weights, sigma_m: float, upsample: int = 4) -> np.ndarray:
    """``U`` via the complex backprojection of the pulse-filtered histograms (any geometry).

    The filtered signal ``sum_b H[b] g(s - r_b)``, ``g(s) = sum_f w_f exp(i 2 pi f s)``,
    is evaluated on a time axis ``upsample`` times finer than the capture's
    (at the fine bins' centres) and extended by four pulse widths on both
    sides (the filtered signal outlasts the data), so the backprojection's
    nearest-bin lookup errs by at most 1/(2 upsample) of a bin.
    """
    from scipy.signal import fftconvolve

    from .backprojection import backproject

    T = capture.n_bins
    u = int(upsample)
    w = capture.bin_width_m
    pad = int(math.ceil(4 * sigma_m / w)) + 1
    Tn = u * (T + 2 * pad)
    half = u * (T + pad + 2)
    # fine sample q (centre t0 + (q + 1/2) w/u, q from -u pad) minus coarse centre b (t0 + (b + 1/2) w),
    # q = u b + n: offset = (n + 1/2 - u/2) w / u
    n = np.arange(-half, half + 1)
    s = (n + 0.5 - u / 2) * (w / u)
    # a sum, not a BLAS product: the same bytes whatever the number of threads
    g = np.sum(np.exp(2j * np.pi * np.outer(s, freqs)) * weights, axis=1).astype(np.complex64)
    start = half - u * pad  # full-convolution index of fine sample q = -u pad

    def transform(j, h):
        hh = np.asarray(h, dtype=np.float32)
        up = np.zeros(hh.shape[:-1] + (u * T,), dtype=np.float32)
        up[..., ::u] = hh
        full = fftconvolve(up, g[None, None, :], mode="full", axes=-1)
        return full[..., start: start + Tn].astype(np.complex64)

    fine = capture.derive(transform, None, bin_width_ps=capture.bin_width_ps / u, n_bins=Tn,
                          t0_ps=capture.t0_ps - pad * capture.bin_width_ps)
    return backproject(fine, grid, complex_values=True, description="phasor fields")


# ------------------------------------------------------------------ RSD form


def _axis_plan(p0: float, dp: float, n_pix: int, v: np.ndarray):
    """Plan one lateral axis of the RSD convolution.

    Input samples sit at ``p0 + i h`` (pixel k at ``i = k m``); output samples
    at ``v[0] + o h``, ``o = 0 .. n_out - 1``. ``h`` is the voxel spacing when
    it divides the pixel spacing (then the outputs are exactly the voxel
    centres), else ``dp / ceil(dp / dv)`` (outputs interpolated afterwards).

    Returns ``(m, h, n_in, n_out, exact)``.
    """
    dv = float(v[1] - v[0]) if len(v) > 1 else (dp if math.isfinite(dp) else 1.0)
    if n_pix > 1 and math.isfinite(dp):
        ratio = dp / dv
        m = int(round(ratio))
        exact = m >= 1 and abs(ratio - m) < 1e-6 * max(1.0, ratio)
        if not exact:
            m = max(1, int(math.ceil(ratio - 1e-9)))
        h = dp / m
    else:
        m, h, exact = 1, dv, True
    n_in = (n_pix - 1) * m + 1
    n_out = len(v) if exact else int(math.ceil((v[-1] - v[0]) / h - 1e-9)) + 2
    return m, h, n_in, n_out, exact


def _rsd(capture, grid, wall, freqs, weights) -> np.ndarray:
    import scipy.fft as sfft

    from . import _kernels

    confocal = capture.mode == "confocal"
    H, W = capture.height, capture.width
    mx, hx, nxi, nxo, ex_x = _axis_plan(wall.x_m[0], wall.dx_m, W, grid.x_m)
    my, hy, nyi, nyo, ex_y = _axis_plan(wall.y_m[0], wall.dy_m, H, grid.y_m)
    Lx = sfft.next_fast_len(nxi + nxo - 1)
    Ly = sfft.next_fast_len(nyi + nyo - 1)
    # circular index n <-> lateral offset (v0 - p0) + n' h with n' = n (n < n_out) or n - L
    nx_ = np.arange(Lx)
    ny_ = np.arange(Ly)
    offx = (grid.x_m[0] - wall.x_m[0]) + np.where(nx_ < nxo, nx_, nx_ - Lx) * hx
    offy = (grid.y_m[0] - wall.y_m[0]) + np.where(ny_ < nyo, ny_, ny_ - Ly) * hy
    rho2 = np.ascontiguousarray(offy[:, None] ** 2 + offx[None, :] ** 2)
    xo = grid.x_m[0] + np.arange(nxo) * hx   # output sample positions
    yo = grid.y_m[0] + np.arange(nyo) * hy
    F = len(freqs)
    wts = weights.astype(np.complex64)
    # evenly spaced (virtual_wave): the kernels' phases follow a recurrence over n (f_n = f0 + n df)
    f0, df = _freq_step(freqs)
    w64 = np.ascontiguousarray(weights, dtype=np.float64)
    factor = 2.0 if confocal else 1.0
    workers = max(1, __import__("os").cpu_count() or 1)
    nz = len(grid.z_m)
    U = np.zeros(grid.shape, dtype=np.complex64)
    ix, fx = _lin(xo, grid.x_m)
    iy, fy = _lin(yo, grid.y_m)
    exact = ex_x and ex_y

    spot_bytes = F * Ly * Lx * 8
    chunk = max(1, _SPOT_CHUNK_BYTES // spot_bytes)
    files = list(range(capture.n_files))
    Kf = np.empty((F, Ly, Lx), dtype=np.complex64)
    prod = np.empty((F, Ly, Lx), dtype=np.complex64)
    with progress_bar("phasor fields", capture.n_files * nz) as advance:
        for c0 in range(0, len(files), chunk):
            js = files[c0: c0 + chunk]
            spectra = []
            for j in js:
                P = _phasors(capture, j, capture.spot(j), freqs)
                if confocal:
                    P *= wts[:, None, None]
                fine = np.zeros((F, Ly, Lx), dtype=np.complex64)
                fine[:, 0:nyi:my, 0:nxi:mx] = P
                spectra.append(sfft.fft2(fine, workers=workers, overwrite_x=True))
            for iz, z in enumerate(grid.z_m):
                _kernels.rsd_kernels(rho2, float(z * z), f0, df, factor, Kf)
                Kspec = sfft.fft2(Kf, workers=workers, overwrite_x=False)
                if confocal:
                    spec = np.einsum("fyx,fyx->yx", spectra[0], Kspec)
                    plane = sfft.ifft2(spec, workers=workers, overwrite_x=True)[:nyo, :nxo]
                else:
                    plane = np.zeros((nyo, nxo), dtype=np.complex64)
                    for jj, j in enumerate(js):
                        np.multiply(spectra[jj], Kspec, out=prod)
                        # pruned inverse FFT: only the first nyo x nxo outputs are kept, so transform x on
                        # every row, keep nxo columns, then transform y on those columns only
                        field = sfft.ifft(prod, axis=-1, workers=workers, overwrite_x=True)[:, :, :nxo]
                        field = sfft.ifft(field, axis=-2, workers=workers)[:, :nyo]
                        S = capture.spots[j]
                        dS = np.sqrt((xo[None, :] - S[0]) ** 2 + (yo[:, None] - S[1]) ** 2 + (z - S[2]) ** 2)
                        _kernels.spot_leg_sum(field, w64, dS, f0, df, plane)
                U[iz] += plane if exact else _bilinear(plane, iy, fy, ix, fx)
                advance(len(js))
    return U


def _lin(src: np.ndarray, dst: np.ndarray):
    """Indices and fractions for linear interpolation from sorted ``src`` to ``dst``."""
    pos = np.interp(dst, src, np.arange(len(src)))
    i0 = np.clip(np.floor(pos).astype(np.int64), 0, max(len(src) - 2, 0))
    f = (pos - i0).astype(np.float32)
    return i0, f


def _bilinear(plane: np.ndarray, iy, fy, ix, fx) -> np.ndarray:
    if plane.shape[0] == 1 or plane.shape[1] == 1:
        return plane[np.clip(iy, 0, plane.shape[0] - 1)][:, np.clip(ix, 0, plane.shape[1] - 1)]
    a = plane[iy][:, ix]
    b = plane[iy][:, ix + 1]
    c = plane[iy + 1][:, ix]
    d = plane[iy + 1][:, ix + 1]
    fx_ = fx[None, :]
    fy_ = fy[:, None]
    return (a * (1 - fx_) + b * fx_) * (1 - fy_) + (c * (1 - fx_) + d * fx_) * fy_
