"""numba kernels for ellipsoidal backprojection and phasor fields (compiled on first use, cached on disk).

Backprojection distances use the separable squared differences of a regular voxel grid:
``|v - P_k|^2 = dx[k, ix] + dy[k, iy] + dz[k, iz]`` with
``dx[k, ix] = ((x_ix - P_k.x) / w)^2`` etc. (``w`` the bin width in metres, so
distances come out in bins), so no per-voxel coordinate arrays are needed.

A voxel receives bin ``b = floor((|v - S| + |v - P| + c_k) / w)`` of pair
``k`` when ``0 <= b < n_bins``, where ``c_k = (first+last segments) - c*t0``:
exactly the ellipsoid (foci S and P) of the bin whose interval contains the
voxel's path length. The caller (:func:`recon.backprojection.backproject`)
pads each histogram with zero bins so that every index a voxel of the grid
can produce (nearest and farthest voxel of the box from S and P, plus a
margin) is inside the array, and adds the padding to ``c_k``: the kernels
index without a bounds check, and a bin outside the capture reads a zero,
exactly as skipping it. Loop order: parallel over blocks of ``ROW_BLOCK``
voxel rows of one depth, pixels outside, voxels inside, so one pixel's
histogram stays in L1 while the block's voxels read it.

Rounding: path lengths are float32, in bins, with fast-math (vectorised square roots); values
are accumulated in float64 (complex128), in the same pixel order as before. float32 path lengths
of up to ~1e4 bins err by ~1e-3 bin at most, so a voxel-pair whose float64 path lies that close
to a bin edge may take the neighbouring bin (tests/test_recon_bp_kernels.py bounds exactly this);
on the 64^3 benchmark capture 6488 of 262144 bp voxels differ from the float64 kernels, by at most
7.8e-5 of the maximum. Results are deterministic run to run on one machine (each voxel is summed
by one thread in a fixed order); they may differ in the last bits between CPUs (vectorisation).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange


#: Rows of voxels (along y) per parallel task of the backprojection kernels.
ROW_BLOCK = 16


@njit(parallel=True, cache=True, fastmath=True, nogil=True)
def bp_one_spot(hist, ck, dxp, dyp, dzp, dxs, dys, dzs, out):  # pragma: no cover - compiled
    """Accumulate one laser spot's padded histograms into ``out``.

    hist : (K, Tp) float32 or complex64, one row per pixel, padded with zero bins so that
        every index a voxel of the grid can produce lies in ``[0, Tp)`` (see module docstring)
    ck : (K,) float32, per-pixel path offset minus c*t0, in bins, plus the padding offset
    dxp, dyp, dzp : (K, nx), (K, ny), (K, nz) float32 squared pixel-voxel differences in bins^2
    dxs, dys, dzs : (nx,), (ny,), (nz,) float32 squared spot-voxel differences in bins^2
    out : (nz, ny, nx) float64 or complex128, accumulated in place
    """
    K, Tp = hist.shape
    nz, ny, nx = out.shape
    nby = (ny + ROW_BLOCK - 1) // ROW_BLOCK
    for task in prange(nz * nby):
        iz = task // nby
        y0 = (task - iz * nby) * ROW_BLOCK
        y1 = min(ny, y0 + ROW_BLOCK)
        ds = np.empty((y1 - y0, nx), dtype=np.float32)
        for iy in range(y0, y1):
            syz = dys[iy] + dzs[iz]
            for ix in range(nx):
                ds[iy - y0, ix] = math.sqrt(dxs[ix] + syz)
        acc = np.zeros((y1 - y0, nx), dtype=out.dtype)
        idx = np.empty(nx, dtype=np.uint32)
        for k in range(K):  # one pixel's histogram stays in L1 over the block
            c = ck[k]
            dz = dzp[k, iz]
            h = hist[k]
            dx = dxp[k]
            for iy in range(y0, y1):
                dyz = dyp[k, iy] + dz
                d = ds[iy - y0]
                for ix in range(nx):  # vectorises (float32 sqrt)
                    idx[ix] = np.uint32(d[ix] + math.sqrt(dx[ix] + dyz) + c)
                a = acc[iy - y0]
                for ix in range(nx):  # gather; unsigned index: no negative-index wrap-around code
                    a[ix] += h[idx[ix]]
        for iy in range(y0, y1):
            for ix in range(nx):
                out[iz, iy, ix] += acc[iy - y0, ix]


@njit(parallel=True, cache=True, fastmath=True, nogil=True)
def bp_confocal(hist, ck, dxp, dyp, dzp, out):  # pragma: no cover - compiled
    """Accumulate padded confocal histograms (spot k = pixel k's patch) into ``out``: the path is ``2 |v - P_k|``.

    Arguments as :func:`bp_one_spot` without the spot tables.
    """
    K, Tp = hist.shape
    nz, ny, nx = out.shape
    nby = (ny + ROW_BLOCK - 1) // ROW_BLOCK
    for task in prange(nz * nby):
        iz = task // nby
        y0 = (task - iz * nby) * ROW_BLOCK
        y1 = min(ny, y0 + ROW_BLOCK)
        acc = np.zeros((y1 - y0, nx), dtype=out.dtype)
        idx = np.empty(nx, dtype=np.uint32)
        for k in range(K):
            c = ck[k]
            dz = dzp[k, iz]
            h = hist[k]
            dx = dxp[k]
            for iy in range(y0, y1):
                dyz = dyp[k, iy] + dz
                for ix in range(nx):
                    d = math.sqrt(dx[ix] + dyz)
                    idx[ix] = np.uint32(d + d + c)
                a = acc[iy - y0]
                for ix in range(nx):
                    a[ix] += h[idx[ix]]
        for iy in range(y0, y1):
            for ix in range(nx):
                out[iz, iy, ix] += acc[iy - y0, ix]


@njit(parallel=True, cache=True, fastmath=True, nogil=True)
def bp_paired(hist, ck, dxp, dyp, dzp, dxs, dys, dzs, out):  # pragma: no cover - compiled
    """Accumulate padded paired (spot k, pixel k) histograms into ``out`` when spot k is not pixel k's patch.

    As :func:`bp_one_spot` but the spot tables are per pair: ``dxs`` (K, nx),
    ``dys`` (K, ny), ``dzs`` (K, nz).
    """
    K, Tp = hist.shape
    nz, ny, nx = out.shape
    nby = (ny + ROW_BLOCK - 1) // ROW_BLOCK
    for task in prange(nz * nby):
        iz = task // nby
        y0 = (task - iz * nby) * ROW_BLOCK
        y1 = min(ny, y0 + ROW_BLOCK)
        acc = np.zeros((y1 - y0, nx), dtype=out.dtype)
        idx = np.empty(nx, dtype=np.uint32)
        for k in range(K):
            c = ck[k]
            dz = dzp[k, iz]
            sz = dzs[k, iz]
            h = hist[k]
            dx = dxp[k]
            sx = dxs[k]
            for iy in range(y0, y1):
                dyz = dyp[k, iy] + dz
                syz = dys[k, iy] + sz
                for ix in range(nx):
                    idx[ix] = np.uint32(math.sqrt(sx[ix] + syz) + math.sqrt(dx[ix] + dyz) + c)
                a = acc[iy - y0]
                for ix in range(nx):
                    a[ix] += h[idx[ix]]
        for iy in range(y0, y1):
            for ix in range(nx):
                out[iz, iy, ix] += acc[iy - y0, ix]


@njit(parallel=True, cache=True, nogil=True)
def rsd_kernels(rho2, z2, f0, df, factor, out):  # pragma: no cover - compiled
    """Phase-only Rayleigh-Sommerfeld kernels ``exp(i 2 pi f_n factor sqrt(rho2 + z2))``, ``f_n = f0 + n df``.

    rho2 : (Ly, Lx) float64 squared lateral offsets (m^2)
    z2 : float, squared depth (m^2)
    f0, df : first frequency and frequency step (cycles per metre of path); ``n = 0 .. F-1``
    factor : 1 (one wall-voxel leg) or 2 (confocal: there and back)
    out : (F, Ly, Lx) complex64

    The frequencies are evenly spaced, so ``exp(i 2 pi f_n d) = exp(i 2 pi f0 d) exp(i 2 pi df d)^n``:
    two sin/cos per lateral offset and one complex128 product per frequency (relative error about
    ``F`` units of 1e-16, far below the complex64 output's 6e-8), instead of a sin/cos per frequency.
    """
    F, Ly, Lx = out.shape
    for y in prange(Ly):
        cur = np.empty(Lx, dtype=np.complex128)
        step = np.empty(Lx, dtype=np.complex128)
        for x in range(Lx):
            d = factor * math.sqrt(rho2[y, x] + z2)
            a = 2.0 * math.pi * f0 * d
            b = 2.0 * math.pi * df * d
            cur[x] = complex(math.cos(a), math.sin(a))
            step[x] = complex(math.cos(b), math.sin(b))
        for f in range(F):
            for x in range(Lx):
                out[f, y, x] = cur[x]
                cur[x] = cur[x] * step[x]


@njit(parallel=True, cache=True, nogil=True)
def phasor_project(hist, r_m, f0, df, out):  # pragma: no cover - compiled
    """``out[n, k] = sum_b hist[k, b] exp(-i 2 pi f_n r_m[b])``, ``f_n = f0 + n df``: each pixel's phasors.

    hist : (K, T) float32, histograms (K pixels, T bins)
    r_m : (T,) float64, path length of each bin's centre (m)
    f0, df : first frequency and frequency step (cycles per metre of path)
    out : (F, K) complex64

    The phase factors follow the recurrence of :func:`rsd_kernels` (a table of ``T x F``, complex128); each
    pixel's sum runs over its non-zero bins in order, in complex128, on one thread, so the result does not
    depend on the number of threads (a BLAS product's summation order does).
    """
    K, T = hist.shape
    F = out.shape[0]
    E = np.empty((T, F), dtype=np.complex128)
    for b in prange(T):
        a = -2.0 * math.pi * f0 * r_m[b]
        s = -2.0 * math.pi * df * r_m[b]
        cur = complex(math.cos(a), math.sin(a))
        step = complex(math.cos(s), math.sin(s))
        for n in range(F):
            E[b, n] = cur
            cur = cur * step
    for k in prange(K):
        acc = np.zeros(F, dtype=np.complex128)
        for b in range(T):
            v = hist[k, b]
            if v != 0.0:
                for n in range(F):
                    acc[n] += v * E[b, n]
        for n in range(F):
            out[n, k] = acc[n]


@njit(parallel=True, cache=True, nogil=True)
def spot_leg_sum(field, wts, dS, f0, df, plane):  # pragma: no cover - compiled
    """``plane[y, x] += sum_n field[n, y, x] wts[n] exp(i 2 pi f_n dS[y, x])``, ``f_n = f0 + n df``.

    field : (F, Ny, Nx) complex64, the wall-to-voxel field of one laser spot at one depth (any strides)
    wts : (F,) float64 frequency weights
    dS : (Ny, Nx) float64 spot-to-voxel distances (m)
    f0, df : first frequency and step (cycles per metre of path)
    plane : (Ny, Nx) complex64, accumulated in place

    The phase factors follow the recurrence of :func:`rsd_kernels`; the sum over
    frequencies is accumulated in complex128 and rounded once to complex64.
    """
    F, Ny, Nx = field.shape
    for y in prange(Ny):
        cur = np.empty(Nx, dtype=np.complex128)
        step = np.empty(Nx, dtype=np.complex128)
        acc = np.zeros(Nx, dtype=np.complex128)
        for x in range(Nx):
            a = 2.0 * math.pi * f0 * dS[y, x]
            b = 2.0 * math.pi * df * dS[y, x]
            cur[x] = complex(math.cos(a), math.sin(a))
            step[x] = complex(math.cos(b), math.sin(b))
        for f in range(F):
            w = wts[f]
            for x in range(Nx):
                v = field[f, y, x]
                acc[x] += complex(v.real, v.imag) * (w * cur[x])
                cur[x] = cur[x] * step[x]
        for x in range(Nx):
            plane[y, x] += acc[x]


@njit(parallel=True, cache=True, nogil=True)
def shift_rows(hist, shift_bins, out):  # pragma: no cover - compiled
    """Shift each row of ``hist`` later by ``shift_bins[k]`` (fractional) bins into ``out``.

    The histogram is a piecewise-constant density; bin ``b`` of width 1 moved
    to ``[b + u, b + u + 1)`` overlaps new bins ``floor(b + u)`` and the next
    one by ``1 - frac(u)`` and ``frac(u)``: the exact integral of the shifted
    density (mass conserving). Content moved outside ``out`` is dropped.

    hist : (K, T) float32; shift_bins : (K,) float64; out : (K, T') float32 (zeroed)
    """
    K, T = hist.shape
    Tn = out.shape[1]
    for k in prange(K):
        u = shift_bins[k]
        i = int(math.floor(u))
        f = u - i
        g = 1.0 - f
        for b in range(T):
            v = hist[k, b]
            if v == 0.0:
                continue
            n = b + i
            if 0 <= n < Tn:
                out[k, n] += g * v
            if 0 <= n + 1 < Tn and f > 0.0:
                out[k, n + 1] += f * v


@njit(parallel=True, cache=True, nogil=True)
def stolt(S, ky, kx, dk, out):  # pragma: no cover - compiled
    """Stolt mapping for f-k migration.

    S : (M+1, NY, NX) complex64, spectrum of the wall field, real FFT along r
        (sample i at k_r = i * dk cycles/m), full FFT along y, x.
    ky, kx : (NY,), (NX,) lateral frequencies (cycles/m).
    out : (M+1, NY, NX) complex64, zeroed; row i is kz = i * dk, filled for
        i = 1..M with ``S(k, ky, kx) * kz / k``, ``k = sqrt(kx^2 + ky^2 + kz^2)``
        (linear interpolation in k).
    """
    M1, NY, NX = S.shape
    M = M1 - 1
    for i in prange(1, M + 1):
        kz = i * dk
        for y in range(NY):
            kyz2 = ky[y] * ky[y] + kz * kz
            for x in range(NX):
                k = math.sqrt(kyz2 + kx[x] * kx[x])
                p = k / dk
                j = int(p)
                if j >= M:
                    continue
                f = p - j
                out[i, y, x] = (S[j, y, x] * (1.0 - f) + S[j + 1, y, x] * f) * (kz / k)


@njit(parallel=True, cache=True, nogil=True)
def wiener_apply(D, K, inv_snr):  # pragma: no cover - compiled
    """In place ``D <- D conj(K') / (|K'|^2 + inv_snr)`` with ``K' = K / max|K|`` (complex64 arrays, same shape)."""
    Kf = K.ravel()
    Df = D.ravel()
    n = Kf.shape[0]
    m2 = 0.0
    for i in range(n):
        a = Kf[i].real * Kf[i].real + Kf[i].imag * Kf[i].imag
        if a > m2:
            m2 = a
    m = math.sqrt(m2)
    reg = inv_snr * m2
    for i in prange(n):
        k = Kf[i]
        p = k.real * k.real + k.imag * k.imag
        Df[i] = Df[i] * (k.conjugate() * (m / (p + reg)))

