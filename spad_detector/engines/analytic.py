"""The fast analytic engine: per-cycle detection probabilities per bin, then one draw over all pulses.

For every pixel:

1. ``lam``: triggering events per cycle per slot (:meth:`DetectorModel.intensity`).
2. Regime (:func:`classify`, :mod:`..pileup` for the formulas):

   * ``none`` -- no dead time at all (``dead_time_ns = 0`` and no TCSPC
     limit): every event is recorded, counts per bin are independent
     Poisson(``N lam``). **Exact.**
   * ``clean`` -- the dead times blind whole cycles (``m >= 0``): Coates'
     first-photon probabilities ``p_j``, the renewal count ``K`` of avalanches
     in ``N`` cycles (``m = 0``: Binomial(N, p_det)), then
     ``Multinomial(K, p_j / p_det)``. **Exact** (up to a total-variation
     distance of 1e-6: intensity summing to less than ``1e-6 / N`` per side
     of the support is ignored). The SPAD and the TCSPC are combined
     exactly when the TCSPC dead time is the shorter one (it never misses a
     SPAD avalanche), when the SPAD is re-armed before every window (then
     only the TCSPC blinds cycles), or when both blind the same number of
     cycles. A paralyzable SPAD is exact in the cases where it is re-armed
     before the next window (its extensions then never reach it).
   * ``chain`` -- anything else: the stationary Markov chain of avalanche
     phases with one non-paralyzable dead time ``max(dead_time, TCSPC dead
     time)`` gives the **exact mean** rate per slot when the SPAD dead time is
     the longer one and the SPAD is non-paralyzable; otherwise the mean is
     **approximate** (the SPAD's own unrecorded avalanches during the TCSPC's
     dead time, or a paralyzable SPAD's extensions, are ignored). Counts are
     drawn as Multinomial(N, rates) (Poisson per bin when more than one
     avalanche per cycle is expected): the variance ignores the
     anticorrelation dead time causes between cycles (**approximate**).

3. Jitter: the per-avalanche bin probabilities are convolved with the jitter
   kernel (each avalanche is displaced independently, so a multinomial stays
   a multinomial with convolved probabilities; mass leaving the window is
   lost). **Exact.**
4. Afterpulsing and crosstalk (if enabled) enter as extra Poisson intensity
   computed from the stationary avalanche rates (first order, iterated three
   times): afterpulses at re-arm + exponential delay, crosstalk from the 4
   neighbours' avalanches at the same time. **Approximate** (they are really
   correlated with their parent avalanche); use the exact engine to check.
"""

from __future__ import annotations

import numpy as np

from ..model import DetectorModel, apply_jitter_kernel
from ..noise import afterpulse_release, neighbour_sum
from ..pileup import (blind_cycles, first_photon_probabilities, sample_renewal_counts,
                      stationary_avalanche_rates, support)
from ..sampling import distribute

#: Total-variation tolerance of the ``clean`` regime (probability that any ignored event occurs).
TV_TOLERANCE = 1e-6

NONE, CLEAN, CHAIN_MEAN_EXACT, CHAIN_APPROX = 0, 1, 2, 3
_NAMES = {NONE: "poisson_no_dead_time", CLEAN: "whole_blind_cycles",
          CHAIN_MEAN_EXACT: "markov_chain", CHAIN_APPROX: "markov_chain_approximate"}


def cycle_origin(model: DetectorModel) -> int:
    """Slot where the analysis starts the cycle: opposite the gate's centre (0 without a gate).

    A gate's smooth edges wrap around the period boundary; starting the
    cycle half a period away from the gate keeps its whole profile in one
    piece, so that "the part of the cycle holding the intensity" is an
    interval.
    """
    p = model.params
    if p.gate_open_ps is None:
        return 0
    g = model.grid
    centre = 0.5 * (p.gate_open_ps + p.gate_close_ps) - g.t0_ps
    phase = np.mod(centre + 0.5 * g.period_ps, g.period_ps)
    return int(np.clip(np.searchsorted(g.edges, phase, side="right") - 1, 0, g.n_slots - 1))


def _rotated_edges(model: DetectorModel, r: int) -> np.ndarray:
    e = model.grid.edges
    P = model.grid.period_ps
    return np.concatenate([e[r:-1], e[:r] + P, [e[r] + P]])


def classify(model: DetectorModel, lam: np.ndarray, n_pulses: int) -> dict:
    """Regime of every pixel (see the module docstring).

    Returns a dict with ``regime`` (int codes), ``blind`` (``m``), ``origin``
    (slot the cycle starts at, :func:`cycle_origin`) and ``ia``, ``ib``: the
    kept slot range counted from ``origin`` (for ``clean`` pixels).
    """
    grid = model.grid
    P = grid.period_ps
    tau_s, tau_c = model.spad_dead_time_ps, model.tcspc_dead_time_ps
    n_pix = lam.shape[0]
    r = cycle_origin(model)
    if tau_s == 0 and tau_c == 0:
        z = np.zeros(n_pix, dtype=np.int64)
        return {"regime": np.full(n_pix, NONE), "blind": z, "origin": r, "ia": z, "ib": z + grid.n_slots - 1}
    ia, ib = support(np.roll(lam, -r, axis=1), TV_TOLERANCE / (2.0 * n_pulses))
    empty = ib < ia
    e = _rotated_edges(model, r)
    a = e[np.clip(ia, 0, grid.n_slots - 1)]
    b = e[np.clip(ib + 1, 1, grid.n_slots)]
    para = model.paralyzable
    m_s = blind_cycles(a, b, tau_s, P)
    if tau_c <= tau_s:
        clean = (m_s >= 0) & ((m_s == 0) | (not para))
        m = m_s
    else:
        m_c = blind_cycles(a, b, tau_c, P)
        rearmed = b + tau_s <= P + a + 1e-9 * P
        ca = rearmed & (m_c >= 0)
        cb = (m_s >= 0) & (m_c == m_s) & ((m_s == 0) | (not para))
        clean = ca | cb
        m = np.where(ca, m_c, m_s)
    clean |= empty
    mean_exact = (tau_c <= tau_s) and not para
    regime = np.where(clean, CLEAN, CHAIN_MEAN_EXACT if mean_exact else CHAIN_APPROX)
    return {"regime": regime, "blind": np.where(clean, np.maximum(m, 0), -1), "origin": r, "ia": ia, "ib": ib}


def _clean_first_photon(lam: np.ndarray, c: dict, sel: np.ndarray) -> np.ndarray:
    """Coates' probabilities of the ``clean`` pixels ``sel``, the cycle starting at ``c['origin']``,
    intensity outside the kept range dropped; returned in the original slot order."""
    r = c["origin"]
    L = np.roll(lam[sel], -r, axis=1)
    idx = np.arange(L.shape[1])[None, :]
    L[(idx < c["ia"][sel, None]) | (idx > c["ib"][sel, None])] = 0.0
    return np.roll(first_photon_probabilities(L), r, axis=1)


def is_exact(model: DetectorModel, ideal: np.ndarray, n_pulses: int) -> bool:
    """Whether the analytic engine samples the exact distribution for these inputs."""
    p = model.params
    if p.afterpulse_prob > 0 or p.crosstalk_prob > 0:
        return False
    c = classify(model, model.intensity(ideal), n_pulses)
    return bool(np.all((c["regime"] == NONE) | (c["regime"] == CLEAN)))


def _avalanche_rates(model: DetectorModel, lam: np.ndarray, c: dict) -> np.ndarray:
    """SPAD avalanches per cycle per slot (first order; used for afterpulsing and crosstalk)."""
    out = np.zeros_like(lam)
    reg = c["regime"]
    sel = reg == NONE
    out[sel] = lam[sel]
    sel = reg == CLEAN
    if np.any(sel):
        p = _clean_first_photon(lam, c, sel)
        pdet = p.sum(1)
        # cycles the SPAD itself is blind (0 if it re-arms before the next window)
        e = _rotated_edges(model, c["origin"])
        a = e[np.clip(c["ia"][sel], 0, model.grid.n_slots - 1)]
        b = e[np.clip(c["ib"][sel] + 1, 1, model.grid.n_slots)]
        ms = np.maximum(blind_cycles(a, b, model.spad_dead_time_ps, model.grid.period_ps), 0)
        out[sel] = p / (1.0 + ms * pdet)[:, None]
    sel = reg >= CHAIN_MEAN_EXACT
    if np.any(sel):
        out[sel], _ = stationary_avalanche_rates(lam[sel], model.grid, max(model.spad_dead_time_ps,
                                                                           model.tcspc_dead_time_ps))
    return out


def run_analytic(model: DetectorModel, ideal: np.ndarray, n_pulses: int, rng: np.random.Generator,
                 spatial_shape: tuple[int, int]) -> tuple[np.ndarray, dict]:
    """Counts for one spot with the analytic engine.

    Parameters
    ----------
    ideal : ndarray, shape (n_pix, n_bins)
        Expected photons per pulse per bin at each pixel (budget applied).
    spatial_shape : (height, width)
        Pixel grid of the spot (``height * width == n_pix``), for crosstalk.

    Returns
    -------
    counts : ndarray of int64, shape (n_pix, n_bins)
    info : dict
        Engine name, pixels per regime, whether the draw is exact.
    """
    p = model.params
    grid = model.grid
    T = grid.n_bins
    N = int(n_pulses)
    lam0 = model.intensity(ideal)
    lam = lam0
    c = classify(model, lam, N)
    if p.afterpulse_prob > 0 or p.crosstalk_prob > 0:
        H, W = spatial_shape
        for _ in range(3):
            D = _avalanche_rates(model, lam, c)
            extra = np.zeros_like(lam)
            if p.afterpulse_prob > 0:
                extra += p.afterpulse_prob * afterpulse_release(D, grid, model.spad_dead_time_ps,
                                                                p.afterpulse_delay_ns * 1e3)
            if p.crosstalk_prob > 0:
                extra += p.crosstalk_prob * neighbour_sum(D, H, W)
            lam = lam0 + extra * model.gate_slots[None, :]
            c = classify(model, lam, N)
    reg = c["regime"]
    counts = np.zeros((lam.shape[0], T), dtype=np.int64)
    chain_info = {"iterations": 0, "residual": 0.0}
    jit = (model.kernel_first, model.kernel)

    # -- no dead time: independent Poisson bins
    sel = np.nonzero(reg == NONE)[0]
    if sel.size:
        mu = apply_jitter_kernel(lam[sel, :T], *jit) * N
        counts[sel] = rng.poisson(mu)

    # -- whole blind cycles: exact renewal count, then multinomial over bins
    sel = np.nonzero(reg == CLEAN)[0]
    if sel.size:
        pr = _clean_first_photon(lam, c, sel)
        pdet = pr.sum(1)
        K = sample_renewal_counts(rng, N, pdet, c["blind"][sel])
        with np.errstate(invalid="ignore", divide="ignore"):
            q = np.where(pdet[:, None] > 0, pr[:, :T] / pdet[:, None], 0.0)
        counts[sel] = distribute(rng, K, apply_jitter_kernel(q, *jit))

    # -- Markov chain: stationary mean, multinomial (or Poisson) draw
    sel = np.nonzero(reg >= CHAIN_MEAN_EXACT)[0]
    if sel.size:
        tau = max(model.spad_dead_time_ps, model.tcspc_dead_time_ps)
        rates, chain_info = stationary_avalanche_rates(lam[sel], grid, tau)
        s = rates.sum(1)
        win = apply_jitter_kernel(rates[:, :T], *jit)
        single = s <= 1.0
        if np.any(single):
            i = np.nonzero(single)[0]
            K = rng.binomial(N, s[i])
            with np.errstate(invalid="ignore", divide="ignore"):
                q = np.where(s[i, None] > 0, win[i] / s[i, None], 0.0)
            counts[sel[i]] = distribute(rng, K, q)
        if np.any(~single):
            i = np.nonzero(~single)[0]
            counts[sel[i]] = rng.poisson(win[i] * N)

    n_reg = {name: int(np.sum(reg == code)) for code, name in _NAMES.items()}
    approx = p.afterpulse_prob > 0 or p.crosstalk_prob > 0 or bool(np.any(reg >= CHAIN_MEAN_EXACT))
    info = {"engine": "analytic", "exact": not approx, "pixels_by_regime": n_reg,
            "chain_iterations": int(chain_info["iterations"]), "chain_residual": float(chain_info["residual"])}
    return counts, info
