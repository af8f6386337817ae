"""numba kernel of the exact engine: the detector's event loop for one chunk of pulses.

Times are ps from the start of the chunk's first cycle (cycle phase 0 =
the histogram's ``t0``). State carried between chunks (shifted by the chunk
length by the caller): per-pixel SPAD re-arm time, TCSPC ready time, last
avalanche time, and the heap of pending afterpulses.
"""

from __future__ import annotations

import math

import numba
import numpy as np

_INV_SQRT2 = 1.0 / math.sqrt(2.0)


@numba.njit(cache=True)
def _phi(x):
    return 0.5 * math.erfc(-x * _INV_SQRT2)


@numba.njit(cache=True)
def _gate(t, gate_on, t0, g_open, g_close, g_sigma, period):
    if not gate_on:
        return 1.0
    ta = t0 + (t - math.floor(t / period) * period)
    g = 0.0
    for k in range(-2, 3):
        sh = k * period
        if g_sigma > 0:
            g += _phi((ta - g_open - sh) / g_sigma) - _phi((ta - g_close - sh) / g_sigma)
        elif ta >= g_open + sh and ta < g_close + sh:
            g += 1.0
    return min(max(g, 0.0), 1.0)


@numba.njit(cache=True)
def _heap_push(ht, hp, n, t, p):
    if n == ht.shape[0]:
        nt = np.empty(2 * n, np.float64)
        npx = np.empty(2 * n, np.int64)
        nt[:n] = ht
        npx[:n] = hp
        ht, hp = nt, npx
    i = n
    ht[i] = t
    hp[i] = p
    while i > 0:
        parent = (i - 1) // 2
        if ht[parent] <= ht[i]:
            break
        ht[parent], ht[i] = ht[i], ht[parent]
        hp[parent], hp[i] = hp[i], hp[parent]
        i = parent
    return ht, hp, n + 1


@numba.njit(cache=True)
def _heap_pop(ht, hp, n):
    t, p = ht[0], hp[0]
    n -= 1
    ht[0], hp[0] = ht[n], hp[n]
    i = 0
    while True:
        left = 2 * i + 1
        right = left + 1
        small = i
        if left < n and ht[left] < ht[small]:
            small = left
        if right < n and ht[right] < ht[small]:
            small = right
        if small == i:
            break
        ht[small], ht[i] = ht[i], ht[small]
        hp[small], hp[i] = hp[i], hp[small]
        i = small
    return t, p, n


@numba.njit(cache=True)
def _jitter(rng, mode, sigma, tail_f, tail_tau, irf_cdf, irf_lo, irf_step):
    if mode == 0:
        return 0.0
    if mode == 1:
        j = 0.0
        if sigma > 0:
            j = sigma * rng.standard_normal()
        if tail_f > 0 and rng.random() < tail_f:
            j += rng.exponential(tail_tau)
        return j
    u = rng.random() * irf_cdf[-1]
    i = np.searchsorted(irf_cdf, u, side="right")
    if i >= irf_cdf.shape[0]:
        i = irf_cdf.shape[0] - 1
    return irf_lo + (i + rng.random()) * irf_step


@numba.njit(cache=True)
def run_chunk(ev_t, ev_p, chunk_len, period, n_bins, bin_w, t0,
              spad_ready, tcspc_ready, last_aval, heap_t, heap_p, heap_n,
              tau_s, tau_c, paralyzable, p_ap, ap_delay, p_xt, nbr_ptr, nbr_idx,
              gate_on, g_open, g_close, g_sigma,
              jit_mode, jit_sigma, jit_tail_f, jit_tail_tau, irf_cdf, irf_lo, irf_step,
              rng, hist, stats):
    """Process one chunk of time-sorted triggering events.

    ``hist[pixel, bin]`` is incremented for every recorded avalanche.
    ``stats``: [avalanches, recorded, afterpulse avalanches, crosstalk avalanches].
    Returns the (possibly grown) heap arrays and the heap size.
    """
    n_ev = ev_t.shape[0]
    n_pix = spad_ready.shape[0]
    stack = np.empty(4 * n_pix + 4, np.int64)
    window = n_bins * bin_w
    i = 0
    while True:
        # next event: primary photon or pending afterpulse, whichever is earlier
        t_prim = ev_t[i] if i < n_ev else np.inf
        if heap_n > 0 and heap_t[0] < t_prim and heap_t[0] < chunk_len:
            t, k, heap_n = _heap_pop(heap_t, heap_p, heap_n)
            if rng.random() >= _gate(t, gate_on, t0, g_open, g_close, g_sigma, period):
                continue
            kind = 1
        elif i < n_ev:
            t = t_prim
            k = ev_p[i]
            i += 1
            kind = 0
        else:
            break
        # trigger pixel k at time t, with the crosstalk cascade (the root is popped first)
        top = 0
        stack[top] = k
        top += 1
        root = True
        while top > 0:
            top -= 1
            q = stack[top]
            is_root = root
            root = False
            if t <= last_aval[q]:
                continue  # already avalanched at this instant
            if t < spad_ready[q]:
                if paralyzable:
                    spad_ready[q] = t + tau_s
                continue
            # avalanche
            last_aval[q] = t
            spad_ready[q] = t + tau_s
            stats[0] += 1
            if not is_root:
                stats[3] += 1
            elif kind == 1:
                stats[2] += 1
            if t >= tcspc_ready[q]:
                tcspc_ready[q] = t + tau_c
                cyc = math.floor(t / period)
                stamp = t - cyc * period + _jitter(rng, jit_mode, jit_sigma, jit_tail_f, jit_tail_tau,
                                                   irf_cdf, irf_lo, irf_step)
                if stamp >= 0.0 and stamp < window:
                    b = int(stamp / bin_w)
                    if b >= n_bins:
                        b = n_bins - 1
                    hist[q, b] += 1
                    stats[1] += 1
            if p_ap > 0 and rng.random() < p_ap:
                heap_t, heap_p, heap_n = _heap_push(heap_t, heap_p, heap_n,
                                                    t + tau_s + rng.exponential(ap_delay), q)
            if p_xt > 0:
                gx = p_xt * _gate(t, gate_on, t0, g_open, g_close, g_sigma, period)
                for jj in range(nbr_ptr[q], nbr_ptr[q + 1]):
                    if rng.random() < gx:
                        stack[top] = nbr_idx[jj]
                        top += 1
    return heap_t, heap_p, heap_n
