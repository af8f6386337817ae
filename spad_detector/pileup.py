"""Dead time and pile-up: closed forms, first-photon probabilities and the detector's Markov chain.

Notation: a laser cycle (period ``P``) is cut into slots (:mod:`.cycle`);
``lam[..., j]`` is the mean number of *avalanche-triggering* events (photons
after PDE and gate, dark counts, ambient) per cycle in slot ``j``. They form a
Poisson process with piecewise-constant intensity.

First photon (Coates)
---------------------
A detector that is ready at the start of a cycle and dead for the rest of it
after one avalanche records slot ``j`` with probability
``p_j = exp(-sum_{i<j} lam_i) (1 - exp(-lam_j))`` (:func:`first_photon_probabilities`);
it records nothing with probability ``exp(-sum lam)``.

Whole blind cycles
------------------
Let ``[a, b)`` be the part of the cycle holding (all but a negligible part of)
the intensity. A non-paralyzable dead time ``tau`` with

* ``tau >= b - a`` (at most one avalanche per cycle) and
* ``m P + b <= a + tau`` and ``b + tau <= (m + 1) P + a`` for an integer ``m >= 0``

makes the detector blind for exactly ``m`` whole cycles after every avalanche,
wherever in ``[a, b)`` it fell, and ready again at the start of the next
cycle (:func:`blind_cycles`). ``m = 0`` is Coates' setting (dead time longer
than the window, shorter than the rest of the period); ``m >= 1`` is dead time
longer than the period (e.g. 50 MHz with a 50 ns dead time: ``m = 2`` for a
short gated window). Then the avalanches form a renewal process whose
interval, in cycles, is ``m + G`` with ``G ~ Geometric(p_det)``,
``p_det = 1 - exp(-sum lam)``; each avalanche falls in slot ``j`` with
probability ``p_j / p_det``, independently. Counts over ``N`` cycles are
sampled exactly (:func:`sample_renewal_counts`); the mean rate per cycle is
``p_det / (1 + m p_det)`` (:func:`pulsed_rate_per_cycle`).

General case: the detector's Markov chain
-----------------------------------------
Otherwise (e.g. an ungated SPAD whose dark counts between windows carry dead
time into the next window, or a dead time shorter than the window) the phases
of successive avalanches form a Markov chain: from an avalanche at phase
``phi`` the detector is ready at ``phi + tau`` (mod ``P``), and the next
avalanche is the first photon after that. :func:`stationary_avalanche_rates`
finds the chain's stationary distribution ``pi`` (power iteration on slots,
ready phases rounded to the nearest slot boundary) and the mean interval
between avalanches, which give the expected avalanches per cycle in every slot.
This is the model of Rapp, Ma and Goyal (IEEE Trans. Signal Process. 2019)
and Isbaner et al. (Opt. Express 2016) for dead times spanning cycles.

Continuous sources
------------------
For a constant rate ``n`` (counts/s) and dead time ``tau`` (s), the recorded
rate is ``n / (1 + n tau)`` (non-paralyzable) or ``n exp(-n tau)``
(paralyzable) (:func:`nonparalyzable_rate`, :func:`paralyzable_rate`).
"""

from __future__ import annotations

import numpy as np
from scipy.special import nbdtr


from .cycle import CycleGrid

# ----------------------------------------------------------------- closed forms


def nonparalyzable_rate(true_rate, dead_time):
    """Recorded rate ``n / (1 + n tau)`` of a non-paralyzable detector (same time units)."""
    n = np.asarray(true_rate, dtype=np.float64)
    return n / (1.0 + n * dead_time)


def paralyzable_rate(true_rate, dead_time):
    """Recorded rate ``n exp(-n tau)`` of a paralyzable detector (same time units)."""
    n = np.asarray(true_rate, dtype=np.float64)
    return n * np.exp(-n * dead_time)


def pulsed_rate_per_cycle(p_det, blind_cycles):
    """Mean avalanches per cycle ``p / (1 + m p)`` for ``m`` whole blind cycles after each one."""
    p = np.asarray(p_det, dtype=np.float64)
    return p / (1.0 + np.asarray(blind_cycles) * p)


# -------------------------------------------------------------- first photon


def first_photon_probabilities(lam: np.ndarray) -> np.ndarray:
    """Coates' per-cycle first-avalanche probabilities ``p[..., j]`` (slot axis last)."""
    lam = np.asarray(lam, dtype=np.float64)
    before = np.cumsum(lam, axis=-1) - lam
    return np.exp(-before) * -np.expm1(-lam)


def support(lam: np.ndarray, negligible: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """Slot range ``[ia, ib]`` outside of which the intensity sums to at most ``negligible`` per side.

    Returns ``ia, ib`` (int arrays over the leading axes); ``ib < ia`` when
    the whole intensity is negligible.
    """
    lam = np.asarray(lam, dtype=np.float64)
    cum = np.cumsum(lam, axis=-1)
    tot = cum[..., -1:].copy()  # (cum is modified below)
    neg = np.asarray(negligible, dtype=np.float64)
    neg = neg[..., None] if neg.ndim else neg
    ia = np.argmax(cum > neg, axis=-1)
    # the intensity from slot j to the end exceeds neg iff cum_before_j < tot - neg (monotone in j)
    cum -= lam
    ib = np.count_nonzero(cum < tot - neg, axis=-1) - 1
    empty = (tot <= 2 * neg)[..., 0]
    n = lam.shape[-1]
    ia = np.where(empty, n, ia)
    ib = np.where(empty, -1, ib)
    return ia, ib


def blind_cycles(a_ps, b_ps, dead_time_ps: float, period_ps: float) -> np.ndarray:
    """Whole cycles ``m`` a dead time blinds after any avalanche in ``[a, b)``; -1 if not whole.

    See the module docstring for the conditions. ``a_ps``/``b_ps`` are phases
    (arrays allowed); an empty support (``b <= a``) gives 0.
    """
    a = np.asarray(a_ps, dtype=np.float64)
    b = np.asarray(b_ps, dtype=np.float64)
    tau, P = float(dead_time_ps), float(period_ps)
    tol = 1e-9 * P
    width = np.maximum(b - a, 0.0)
    m = np.floor((a + tau - b + tol) / P)
    ok = (tau + tol >= width) & (b + tau <= (m + 1) * P + a + tol) & (m >= 0)
    out = np.where(ok, m, -1).astype(np.int64)
    return np.where(width <= 0, 0, out)


# ----------------------------------------------------------- renewal sampling


def sample_renewal_counts(rng: np.random.Generator, n_cycles: int, p_det, blind) -> np.ndarray:
    """Exact number of avalanches in ``n_cycles`` cycles for the whole-blind-cycles renewal model.

    The detector is ready in cycle 1; after each avalanche it is blind for
    ``blind`` cycles; in a ready cycle it fires with probability ``p_det``.
    ``K >= k`` iff the ``k``-th avalanche happens by cycle ``N``, i.e. iff at
    most ``N - (k - 1) m - k`` failures precede the ``k``-th success, a
    negative-binomial probability; ``K`` is drawn by inverting that survival
    function (one uniform per pixel, binary search).

    Parameters
    ----------
    p_det, blind : array_like, same shape
        Per-cycle firing probability and whole blind cycles ``m >= 0``.

    Returns
    -------
    ndarray of int64, same shape
    """
    p = np.clip(np.asarray(p_det, dtype=np.float64), 0.0, 1.0)
    m = np.asarray(blind, dtype=np.int64)
    p, m = np.broadcast_arrays(p, m)
    N = int(n_cycles)
    out = np.zeros(p.shape, dtype=np.int64)
    zero_m = m == 0
    if np.any(zero_m):
        out[zero_m] = rng.binomial(N, p[zero_m])
    rest = ~zero_m
    if np.any(rest):
        pr, mr = p[rest], m[rest].astype(np.float64)
        u = rng.random(pr.shape)
        lo = np.zeros(pr.shape)
        hi = np.floor((N + mr) / (mr + 1.0)) + 1.0  # S_hi > N always
        while np.any(hi - lo > 1):
            mid = np.floor(0.5 * (lo + hi))
            x = N - (mid - 1) * mr - mid
            with np.errstate(invalid="ignore"):
                g = np.where(x >= 0, nbdtr(np.maximum(x, 0), np.maximum(mid, 1), pr), 0.0)
            ok = g >= u
            lo = np.where(ok, mid, lo)
            hi = np.where(ok, hi, mid)
        out[rest] = lo.astype(np.int64)
    return out


# ------------------------------------------------------------- Markov chain


def ready_shift(grid: CycleGrid, dead_time_ps: float) -> tuple[np.ndarray, np.ndarray]:
    """Where the detector is ready again after an avalanche in each slot.

    The avalanche is placed at the slot centre; ``centre + dead_time`` (mod
    ``P``) is rounded to the nearest slot boundary.

    Returns
    -------
    target : ndarray of int, shape (n_slots,)
        Boundary (= slot index whose start it is; boundary ``n_slots`` is
        slot 0 of the next cycle).
    delay_ps : ndarray, shape (n_slots,)
        Exact time from the avalanche to that boundary (>= 0 up to rounding).
    """
    e = grid.edges
    P = grid.period_ps
    ready = grid.centres + dead_time_ps
    phase = np.mod(ready, P)
    k = np.searchsorted(e, phase)  # e[k-1] < phase <= e[k]
    k = np.clip(k, 1, len(e) - 1)
    near = np.where(phase - e[k - 1] < e[k] - phase, k - 1, k)
    delay = (ready - phase) + e[near] - grid.centres
    target = np.where(near == len(e) - 1, 0, near)
    return target.astype(np.int64), delay


def stationary_avalanche_rates(lam: np.ndarray, grid: CycleGrid, dead_time_ps: float,
                               tol: float = 1e-12, max_iter: int = 5000) -> tuple[np.ndarray, dict]:
    """Expected avalanches per cycle in every slot for a non-paralyzable dead time (Markov chain).

    Parameters
    ----------
    lam : ndarray, shape (n_pix, n_slots)
        Mean triggering events per cycle per slot.
    grid : CycleGrid
    dead_time_ps : float
        Non-paralyzable dead time (> 0).

    Returns
    -------
    rates : ndarray, shape (n_pix, n_slots)
        Stationary expected avalanches per cycle in each slot.
    info : dict
        ``iterations`` and ``residual`` (largest L1 change of the last step).

    Notes
    -----
    The chain's state is the slot of the last avalanche; the detector is
    ready again at the boundary nearest to ``slot centre + dead time``
    (:func:`ready_shift`), then waits for the first photon. One step of the
    chain and the mean waiting times are periodic first-order recurrences
    (:mod:`._chain_kernel`). The lazy step ``pi <- (pi + pi Q) / 2`` has the
    same fixed point and cannot oscillate; iteration stops when the L1 change
    is below ``tol`` for every pixel. The mean time between avalanches is
    ``sum_i pi_i (delay_i + W(ready_i))``, so the avalanches per cycle in
    slot ``i`` are ``pi_i P / mean``.
    """
    from ._chain_kernel import chain_terms, mean_wait, rates_per_cycle, stationary

    lam = np.asarray(lam, dtype=np.float64)
    n_pix, n = lam.shape
    rates = np.zeros_like(lam)
    live = lam.sum(1) > 0
    info = {"iterations": 0, "residual": 0.0}
    if not np.any(live):
        return rates, info
    L = np.ascontiguousarray(lam[live])
    target, delay = ready_shift(grid, dead_time_ps)
    neg = np.negative(L)
    decay = np.exp(neg)
    onem = np.negative(np.expm1(neg, out=neg), out=neg)  # (the temporary reused: 1 - exp(-lam))
    within, pi = np.empty_like(L), np.empty_like(L)
    one_minus_e = np.empty(len(L))
    # exp(-lam), 1 - exp(-lam), the time within each slot and the fresh detector's first photon (Coates), normalised
    chain_terms(L, np.ascontiguousarray(grid.widths, dtype=np.float64), decay, onem, within, pi, one_minus_e)
    iters = np.zeros(len(L), dtype=np.int64)
    resid = np.zeros(len(L))
    stationary(pi, target, decay, onem, one_minus_e, tol, max_iter, iters, resid)
    it, res = int(iters.max()), float(resid.max())
    W = np.empty_like(L)
    mean_wait(decay, within, one_minus_e, W)
    out = np.empty_like(L)
    rates_per_cycle(pi, np.ascontiguousarray(target, dtype=np.int64), np.ascontiguousarray(delay, dtype=np.float64),
                    W, float(grid.period_ps), out)
    rates[live] = out
    info.update(iterations=it, residual=res)
    return rates, info
