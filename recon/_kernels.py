"""numba kernels for ellipsoidal backprojection (compiled on first use, cached on disk).

Distances use the separable squared differences of a regular voxel grid:
``|v - P_k|^2 = dx[k, ix] + dy[k, iy] + dz[k, iz]`` with
``dx[k, ix] = (x_ix - P_k.x)^2`` etc., so no per-voxel coordinate arrays are
needed. Arithmetic is IEEE float64 (no fast-math), so results do not depend
on vectorisation and agree with a plain numpy reference to rounding.

A voxel receives bin ``b = floor((|v - S| + |v - P| + c_k) / w)`` of pair
``k`` when ``0 <= b < n_bins``, where ``c_k = (first+last segments) - c*t0`` and
``w`` is the bin width in metres: exactly the ellipsoid (foci S and P) of the
bin whose interval contains the voxel's path length.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange


@njit(parallel=True, cache=True, nogil=True)
def bp_one_spot(hist, ck, dxp, dyp, dzp, dxs, dys, dzs, inv_w, out):  # pragma: no cover - compiled
    """Accumulate one laser spot's histograms into ``out``.

    hist : (K, T) float32 or complex64, one row per pixel
    ck : (K,) float64, per-pixel path offset minus c*t0 (metres)
    dxp, dyp, dzp : (K, nx), (K, ny), (K, nz) squared pixel-voxel differences
    dxs, dys, dzs : (nx,), (ny,), (nz,) squared spot-voxel differences
    inv_w : 1 / bin width (1/metres)
    out : (nz, ny, nx) float64 or complex128, accumulated in place
    """
    K, T = hist.shape
    nz, ny, nx = out.shape
    Tf = float(T)
    for row in prange(nz * ny):
        iz = row // ny
        iy = row - iz * ny
        ds = np.empty(nx)
        syz = dys[iy] + dzs[iz]
        for ix in range(nx):
            ds[ix] = math.sqrt(dxs[ix] + syz)
        acc = np.zeros(nx, dtype=out.dtype)  # local: no aliasing with hist, so the loop vectorises
        for k in range(K):
            dyz = dyp[k, iy] + dzp[k, iz]
            c = ck[k]
            for ix in range(nx):
                r = (ds[ix] + math.sqrt(dxp[k, ix] + dyz) + c) * inv_w
                if r >= 0.0 and r < Tf:
                    acc[ix] += hist[k, int(r)]
        for ix in range(nx):
            out[iz, iy, ix] += acc[ix]


@njit(parallel=True, cache=True, nogil=True)
def bp_confocal(hist, ck, dxp, dyp, dzp, inv_w, out):  # pragma: no cover - compiled
    """Accumulate confocal histograms (spot k = pixel k's patch) into ``out``: the path is ``2 |v - P_k|``.

    Arguments as :func:`bp_one_spot` without the spot tables.
    """
    K, T = hist.shape
    nz, ny, nx = out.shape
    Tf = float(T)
    for row in prange(nz * ny):
        iz = row // ny
        iy = row - iz * ny
        acc = np.zeros(nx, dtype=out.dtype)
        for k in range(K):
            dyz = dyp[k, iy] + dzp[k, iz]
            c = ck[k]
            for ix in range(nx):
                d = math.sqrt(dxp[k, ix] + dyz)
                r = (d + d + c) * inv_w
                if r >= 0.0 and r < Tf:
                    acc[ix] += hist[k, int(r)]
        for ix in range(nx):
            out[iz, iy, ix] += acc[ix]


@njit(parallel=True, cache=True, nogil=True)
def bp_paired(hist, ck, dxp, dyp, dzp, dxs, dys, dzs, inv_w, out):  # pragma: no cover - compiled
    """Accumulate paired (spot k, pixel k) histograms into ``out`` when spot k is not pixel k's patch.

    As :func:`bp_one_spot` but the spot tables are per pair: ``dxs`` (K, nx),
    ``dys`` (K, ny), ``dzs`` (K, nz).
    """
    K, T = hist.shape
    nz, ny, nx = out.shape
    Tf = float(T)
    for row in prange(nz * ny):
        iz = row // ny
        iy = row - iz * ny
        acc = np.zeros(nx, dtype=out.dtype)
        for k in range(K):
            dyz = dyp[k, iy] + dzp[k, iz]
            syz = dys[k, iy] + dzs[k, iz]
            c = ck[k]
            for ix in range(nx):
                r = (math.sqrt(dxs[k, ix] + syz) + math.sqrt(dxp[k, ix] + dyz) + c) * inv_w
                if r >= 0.0 and r < Tf:
                    acc[ix] += hist[k, int(r)]
        for ix in range(nx):
            out[iz, iy, ix] += acc[ix]


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

