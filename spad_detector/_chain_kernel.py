"""numba kernels of the detector's Markov chain (:func:`..pileup.stationary_avalanche_rates`).

Both are periodic first-order recurrences over the slots of a cycle, solved
exactly in two passes (one to find the value carried around the period, one
with it), in the linear domain: every quantity is a probability or a time,
bounded, so nothing overflows however strong the intensity.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def stationary(pi, target, decay, onem, one_minus_e, tol, max_iter, iters, resid):
    """Iterate the lazy chain ``pi <- (pi + pi Q) / 2`` per pixel until the L1 change is < ``tol``.

    ``pi`` is updated in place; ``iters[p]``/``resid[p]`` receive the number
    of steps and the last L1 change. See :func:`chain_step` for one step.
    """
    n_pix, n = pi.shape
    # serial on purpose: numba's default (workqueue) threading layer is unsafe when callers run
    # detection from several threads (e.g. a threaded Dask worker)
    for p in range(n_pix):
        beta = np.empty(n)
        out = np.empty(n)
        it = 0
        change = np.inf
        while it < max_iter and change > tol:
            it += 1
            _step(pi[p], target, decay[p], onem[p], one_minus_e[p], beta, out)
            tot = out.sum()
            change = 0.0
            for j in range(n):
                v = 0.5 * (pi[p, j] + out[j] / tot)
                change += abs(v - pi[p, j])
                pi[p, j] = v
        iters[p] = it
        resid[p] = change


@numba.njit(cache=True)
def _step(pi, target, decay, onem, one_minus_e, beta, out):
    n = pi.shape[0]
    beta[:] = 0.0
    for i in range(n):
        beta[target[i]] += pi[i]
    x = beta[0]
    for j in range(1, n):
        x = x * decay[j - 1] + beta[j]
    x = (x * decay[n - 1]) / one_minus_e + beta[0]  # slot 0 also receives mass from earlier cycles
    out[0] = onem[0] * x
    for j in range(1, n):
        x = x * decay[j - 1] + beta[j]
        out[j] = onem[j] * x


@numba.njit(cache=True)
def chain_step(pi, target, decay, onem, one_minus_e, out):
    """One step ``out = pi Q`` of the avalanche-phase chain, for every pixel.

    ``pi[p, i]``: probability of an avalanche in slot ``i``; ``target[i]``:
    slot whose start is the ready time after it; ``decay = exp(-lam)``,
    ``onem = 1 - exp(-lam)``, ``one_minus_e = 1 - exp(-lam_total)``.

    With ``beta`` the ready-boundary distribution, ``X_j`` (the probability
    that the detector is ready and has seen no photon at the start of slot
    ``j``, summed over all later cycles) obeys ``X_j = X_{j-1} decay_{j-1} +
    beta_j`` around the period, and ``out_j = onem_j X_j``.
    """
    n_pix, n = pi.shape
    beta = np.empty(n)
    for p in range(n_pix):
        _step(pi[p], target, decay[p], onem[p], one_minus_e[p], beta, out[p])


@numba.njit(cache=True)
def mean_wait(decay, within, one_minus_e, out):
    """Expected time from each slot start to the next photon, periodic.

    ``within[p, s]``: expected time spent in slot ``s`` before a photon or
    its end (``width (1 - e^-lam) / lam``). ``W_s = within_s + decay_s
    W_{s+1}`` around the period.
    """
    n_pix, n = decay.shape
    for p in range(n_pix):
        w = 0.0
        for s in range(n - 1, -1, -1):
            w = within[p, s] + decay[p, s] * w
        w0 = w / one_minus_e[p]
        w = w0
        for s in range(n - 1, -1, -1):
            w = within[p, s] + decay[p, s] * w
            out[p, s] = w


@numba.njit(cache=True)
def chain_terms(lam, widths, decay, onem, within, pi, one_minus_e):
    """The rest of what the chain reads of the intensity, one pass per pixel (in place of numpy's whole-array
    temporaries: on a 32 x 32 array of 20,000 slots each of them was a 160 MB pass), given ``decay = exp(-lam)`` and
    ``onem = 1 - exp(-lam)`` (numpy's vectorised ``exp`` and ``expm1``: a scalar ``exp`` per slot here cost more
    than all the passes it saved).

    Per pixel ``p`` and slot ``j``: ``within = width onem / lam`` (``width`` where ``lam`` is 0: the expected time
    spent in the slot before a photon or its end); ``pi`` Coates' first-avalanche probabilities of a detector fresh
    at the cycle start, ``exp(-sum_{i<j} lam_i) onem_j`` with the survival taken as the running product of
    ``decay`` (relative rounding about ``n_slots`` ulps, as the cumulative sum's), normalised to 1 (the chain's
    starting point); ``one_minus_e[p] = 1 - exp(-sum_j lam_j)`` (the sum in slot order). A pixel whose ``pi`` sums
    to 0 is left unnormalised (the caller passes pixels with light only).
    """
    n_pix, n = lam.shape
    for p in range(n_pix):
        tot_lam = 0.0
        surv = 1.0
        tot = 0.0
        for j in range(n):
            x = lam[p, j]
            om = onem[p, j]
            within[p, j] = widths[j] * om / x if x > 0.0 else widths[j]
            v = surv * om
            pi[p, j] = v
            tot += v
            surv *= decay[p, j]
            tot_lam += x
        one_minus_e[p] = -np.expm1(-tot_lam)
        if tot > 0.0:
            inv = 1.0 / tot
            for j in range(n):
                pi[p, j] *= inv


@numba.njit(cache=True)
def rates_per_cycle(pi, target, delay, W, period, out):
    """Avalanches per cycle in each slot from the chain's stationary ``pi``: the mean time between avalanches is
    ``sum_i pi_i delay_i + sum_j beta_j W_j`` (``beta``: ``pi`` moved to each slot's ready boundary ``target``,
    ``W``: :func:`mean_wait`), and ``out = pi period / mean`` (sums in slot order)."""
    n_pix, n = pi.shape
    beta = np.empty(n)
    for p in range(n_pix):
        beta[:] = 0.0
        mean = 0.0
        for i in range(n):
            beta[target[i]] += pi[p, i]
            mean += pi[p, i] * delay[i]
        for j in range(n):
            mean += beta[j] * W[p, j]
        s = period / mean
        for j in range(n):
            out[p, j] = pi[p, j] * s
