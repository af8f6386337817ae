"""The exact engine: an event-by-event Monte Carlo of the detector over every pulse.

Chunk by chunk (a whole number of laser cycles holding about
:data:`EVENTS_PER_CHUNK` triggering events), vectorised over pixels:

1. For each pixel, the number of triggering events in the chunk's ``C``
   cycles is Poisson(``C * sum_j lam_j``); each event gets a uniformly random
   cycle, a slot drawn from ``lam / sum(lam)`` and a uniform time within the
   slot. This is exactly a Poisson process with the piecewise-constant
   periodic intensity ``lam`` (signal x PDE x gate + dark + ambient), but costs
   time per *event*, not per pulse.
2. All events are sorted by time (numpy's stable order, by radix:
   :mod:`._event_order`) and run through the detector's state machine
   (:mod:`._exact_kernel`, compiled with numba), in time order across all
   pixels of the spot:

   * a SPAD that is dead ignores the event (paralyzable: restarts its dead
     time); otherwise it avalanches and is dead for ``dead_time_ns``;
   * the avalanche is converted by the pixel's TCSPC if that is ready (then
     busy for ``1 / tcspc_max_count_rate_hz``), time-stamped with a jitter
     draw, and counted if the stamp falls in the histogram window;
   * with ``afterpulse_prob`` it schedules an afterpulse at re-arm +
     Exponential(``afterpulse_delay_ns``) (kept in a heap across chunks),
     which triggers with the gate's efficiency at that time;
   * with ``crosstalk_prob x gate`` it triggers each ready 4-neighbour at the
     same instant (cascading).

The detector starts ready at the first pulse. Everything is driven by one
numpy Generator, so the same seed gives the same counts.
"""

from __future__ import annotations

import math

import numpy as np

from ..model import DetectorModel
from ..noise import neighbour_csr
from ._event_order import event_slots, guide_table, time_order

#: Target number of triggering events per chunk (bounds memory: ~40 bytes per event).
EVENTS_PER_CHUNK = 1 << 20


def _kernel():
    from . import _exact_kernel

    return _exact_kernel.run_chunk


def run_exact(model: DetectorModel, ideal: np.ndarray, n_pulses: int, rng: np.random.Generator,
              spatial_shape: tuple[int, int], advance=None,
              events_per_chunk: int = EVENTS_PER_CHUNK) -> tuple[np.ndarray, dict]:
    """Counts for one spot with the exact engine.

    Parameters
    ----------
    ideal : ndarray, shape (n_pix, n_bins)
        Expected photons per pulse per bin (budget applied).
    spatial_shape : (height, width)
        Pixel grid (for crosstalk neighbours).
    advance : callable, optional
        Called with the number of pulses done after each chunk.

    Returns
    -------
    counts : ndarray of int64, shape (n_pix, n_bins)
    info : dict
    """
    run_chunk = _kernel()
    p = model.params
    grid = model.grid
    P = grid.period_ps
    T = grid.n_bins
    lam = model.intensity(ideal)
    n_pix, n_slots = lam.shape
    lam_tot = lam.sum(1)
    cdf = np.cumsum(lam, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cdf = np.where(lam_tot[:, None] > 0, cdf / lam_tot[:, None], 1.0)
    cdf[:, -1] = 1.0
    cdf_flat = (cdf + 2.0 * np.arange(n_pix)[:, None]).ravel()
    guide = guide_table(cdf_flat, n_slots)
    edges, widths = grid.edges, grid.widths

    H, W = spatial_shape
    if p.crosstalk_prob > 0:
        nbr_ptr, nbr_idx = neighbour_csr(H, W)
    else:
        nbr_ptr, nbr_idx = np.zeros(n_pix + 1, np.int64), np.zeros(1, np.int64)
    j = model.jitter
    if j.is_measured:
        jit_mode, irf_cdf = 2, np.cumsum(j.irf_w)
        irf_lo, irf_step = float(j.irf_t_ps[0] - 0.5 * j.irf_step_ps), j.irf_step_ps
    else:
        jit_mode = 0 if j.is_zero else 1
        irf_cdf, irf_lo, irf_step = np.ones(1), 0.0, 0.0
    gate_on = p.gate_open_ps is not None
    g_open = float(p.gate_open_ps) if gate_on else 0.0
    g_close = float(p.gate_close_ps) if gate_on else 0.0

    spad_ready = np.full(n_pix, -np.inf)
    tcspc_ready = np.full(n_pix, -np.inf)
    last_aval = np.full(n_pix, -np.inf)
    heap_t = np.empty(max(16, 2 * n_pix))
    heap_p = np.empty(max(16, 2 * n_pix), dtype=np.int64)
    heap_n = 0
    hist = np.zeros((n_pix, T), dtype=np.int64)
    stats = np.zeros(4, dtype=np.int64)
    total_rate = float(lam_tot.sum())
    done = 0
    n_events = 0
    N = int(n_pulses)
    # chunk times are float64 ps from the chunk start: keep their rounding (C P 2^-52) below 1e-3 bin
    max_cycles = max(1, int(1e-3 * min(grid.bin_width_ps, widths.min()) / (P * 2.0 ** -52)))
    while done < N:
        C = N - done if total_rate <= 0 else int(min(N - done, max(1, events_per_chunk // max(total_rate, 1e-300))))
        C = max(1, min(C, max_cycles))
        chunk_len = C * P
        k = rng.poisson(C * lam_tot)
        M = int(k.sum())
        n_events += M
        pix = np.repeat(np.arange(n_pix, dtype=np.int64), k)
        cyc = rng.integers(0, C, M)
        u = rng.random(M)
        slot = np.clip(event_slots(cdf_flat, n_slots, pix, u, guide), 0, n_slots - 1)  # (searchsorted, by guide table)
        t = cyc * P + edges[slot] + rng.random(M) * widths[slot]
        order = time_order(t)  # (argsort(t, kind="stable"), by radix)
        heap_t, heap_p, heap_n = run_chunk(
            t[order], pix[order], chunk_len, P, T, grid.bin_width_ps, grid.t0_ps,
            spad_ready, tcspc_ready, last_aval, heap_t, heap_p, heap_n,
            model.spad_dead_time_ps, model.tcspc_dead_time_ps, model.paralyzable,
            float(p.afterpulse_prob), p.afterpulse_delay_ns * 1e3, float(p.crosstalk_prob), nbr_ptr, nbr_idx,
            gate_on, g_open, g_close, model.gate_sigma_ps,
            jit_mode, j.sigma_ps, j.tail_fraction, j.tail_ps, irf_cdf, irf_lo, irf_step,
            rng, hist, stats)
        # move the carried state into the next chunk's time frame
        spad_ready -= chunk_len
        tcspc_ready -= chunk_len
        last_aval -= chunk_len
        heap_t[:heap_n] -= chunk_len
        done += C
        if advance is not None:
            advance(C)
    info = {"engine": "exact", "exact": True, "events": int(n_events), "avalanches": int(stats[0]),
            "recorded": int(stats[1]), "afterpulse_avalanches": int(stats[2]),
            "crosstalk_avalanches": int(stats[3])}
    return hist, info


def estimated_events(model: DetectorModel, ideal: np.ndarray, n_pulses: int) -> float:
    """Expected number of triggering events the exact engine would simulate (its cost driver)."""
    return float(model.intensity(ideal).sum()) * n_pulses * (1.0 + model.params.afterpulse_prob) * \
        (1.0 + 4.0 * model.params.crosstalk_prob) + math.sqrt(n_pulses)
