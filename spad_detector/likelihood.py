"""The detector model as a differentiable layer, and the Poisson likelihood of observed counts.

For fitting a scene to a capture by gradients (analysis by synthesis), the detector must turn the
renderer's ideal histograms into *expected* counts with a derivative, and the counts must be scored.
numpy with explicit vector-Jacobian products (no autodiff framework: the detector model stays
Mitsuba- and drjit-free); a renderer's adjoint (``transient_path.render_backward``) takes the result.

Expected counts, per pixel (``ideal[pixel, bin]`` photons per pulse; ``n_pulses`` cycles):

1. triggering events per cycle per slot ``lam = pde x gate x ideal + background`` (dark counts and
   ambient light; :meth:`~spad_detector.model.DetectorModel.intensity`);
2. first-photon pile-up (Coates): the detector records at most one event per cycle, the first,
   ``p_j = exp(-sum_{i<j} lam_i) (1 - exp(-lam_j))``; this is exact when it is ready at each cycle's
   start (dead time longer than the window, shorter than the rest of the period) and the low-flux
   limit of every regime;
3. timing jitter: ``p`` convolved with the jitter's bin kernel;
4. ``mean = n_pulses x jitter(p)`` over the film's bins.

Vector-Jacobian product (the adjoint of the chain above), for an upstream gradient ``g`` of the mean:
``g_p = n_pulses x jitter^T(g)`` (correlation with the kernel);
``g_lam_k = g_p_k S_k e^{-lam_k} - sum_{j>k} g_p_j p_j`` (``S_k = exp(-sum_{i<k} lam_i)``);
``g_ideal = pde x gate x g_lam`` over the film's bins.

The Poisson negative log-likelihood of counts ``k`` given means ``mu``:
``NLL = sum (mu - k log mu + log k!)``, gradient ``1 - k / mu``.
"""

from __future__ import annotations

import numpy as np
from scipy.special import gammaln

from .model import DetectorModel, apply_jitter_kernel


def _jitter_adjoint(g: np.ndarray, first: int, kernel: np.ndarray) -> np.ndarray:
    """Adjoint of :func:`~spad_detector.model.apply_jitter_kernel`: ``out[i] = sum_j g[i + first + j] kernel[j]``
    over the window (signed values: no clipping, unlike the forward, whose inputs are probabilities)."""
    from scipy.signal import fftconvolve

    T, K = g.shape[-1], len(kernel)
    full = fftconvolve(g, kernel[None, ::-1], mode="full", axes=-1) if K > 1 else g * kernel[0]
    if K == 1:
        out = np.zeros_like(g)
        s = first
        if 0 <= s < T:
            out[:, :T - s] = full[:, s:]
        elif -T < s < 0:
            out[:, -s:] = full[:, :T + s]
        return out
    idx = np.arange(T) + first + K - 1  # full[n] = sum_j g[n - K + 1 + j] kernel[j]
    ok = (idx >= 0) & (idx < full.shape[-1])
    out = np.zeros_like(g)
    out[:, ok] = full[:, idx[ok]]
    return out


class ExpectedCounts:
    """``ideal[P, T] -> mean counts[P, T]`` with its vector-Jacobian product.

    Parameters
    ----------
    model : DetectorModel
        From :func:`~spad_detector.model.build_model` for the capture's time axis (gate resolved).
    n_pulses : int
        Laser cycles (pulses) per spot.
    """

    def __init__(self, model: DetectorModel, n_pulses: int):
        self.model = model
        self.n_pulses = float(n_pulses)

    def probabilities(self, ideal: np.ndarray) -> tuple:
        """``(lam, survive, p)``, each ``[P, slots]`` float64: the detected intensity per slot, the chance of no
        event before the slot, and of the cycle's first event in it. :meth:`__call__` and :meth:`vjp` compute them
        from ``ideal``; a caller that needs both for one ``ideal`` (a fit's iteration) passes them in once made."""
        lam = self.model.intensity(np.asarray(ideal, dtype=np.float64))  # [P, slots]
        before = np.cumsum(lam, axis=-1) - lam
        survive = np.exp(-before)  # S_j: no event before slot j
        p = survive * -np.expm1(-lam)
        return lam, survive, p

    def __call__(self, ideal: np.ndarray, probabilities: tuple | None = None) -> np.ndarray:
        """Mean counts ``[P, T]`` (float64); ``probabilities``: :meth:`probabilities` of ``ideal``, if made."""
        T = self.model.grid.n_bins
        _, _, p = probabilities or self.probabilities(ideal)
        m = self.model
        return self.n_pulses * apply_jitter_kernel(p[:, :T], m.kernel_first, m.kernel)

    def vjp(self, ideal: np.ndarray, grad_mean: np.ndarray, probabilities: tuple | None = None) -> np.ndarray:
        """``d<grad_mean, mean(ideal)> / d ideal``, shape ``[P, T]`` (float64); ``probabilities``: as
        :meth:`__call__`."""
        m = self.model
        T = m.grid.n_bins
        g = np.asarray(grad_mean, dtype=np.float64)
        g_p = np.zeros((g.shape[0], m.grid.n_slots))
        g_p[:, :T] = self.n_pulses * _jitter_adjoint(g, m.kernel_first, m.kernel)
        lam, survive, p = probabilities or self.probabilities(ideal)
        gp_p = g_p * p
        later = np.cumsum(gp_p[:, ::-1], axis=-1)[:, ::-1] - gp_p  # sum_{j > k} g_p_j p_j
        g_lam = g_p * survive * np.exp(-lam) - later
        return m.params.pde * m.gate_slots[None, :T] * g_lam[:, :T]


class RenewalExpectedCounts(ExpectedCounts):
    """:class:`ExpectedCounts` with the dead time that blinds whole cycles after a detection (the detector's
    ``clean`` regime, :mod:`spad_detector.engines.analytic`), and its derivative.

    After a recorded avalanche the detector (SPAD or TCSPC, whichever the analytic engine's
    :func:`~spad_detector.engines.analytic.classify` finds) is blind for ``m`` whole cycles; in a ready cycle
    it records with probability ``P = sum_j p_j`` (Coates). Over ``N`` cycles the renewal count has the mean
    ``N P / (1 + m P)`` (to ``O(1)`` cycles at the start), shared among the bins as ``p_j / P``:

    ``mean_j = N jitter(p)_j / (1 + m P)``.

    This is the mean the analytic engine samples from, exactly where its regime is ``clean``; pixels of
    another regime (``m = -1``: the dead time does not blind whole cycles) get the first-order factor
    ``1 / (1 + P D)`` (``D`` the longer dead time in periods, beyond the first), held constant in the
    derivative. The vector-Jacobian product adds the factor's own derivative,
    ``d/dp_k [1 / (1 + m P)] = -m / (1 + m P)^2`` for every slot ``k``: at ``P`` near 1 (a bright pixel at
    a long exposure) it is as large as the rest (the total count ``N P / (1 + m P)`` saturates at ``N / m``).
    """

    def blind(self, ideal: np.ndarray, lam: np.ndarray | None = None) -> np.ndarray:
        """``[P]`` whole cycles blinded after a detection (-1 where the regime is not ``clean``); ``lam``: the
        detected intensity of ``ideal`` (:meth:`probabilities`' first), if made."""
        from .engines.analytic import CLEAN, NONE, classify

        if lam is None:
            lam = self.model.intensity(np.asarray(ideal, dtype=np.float64))
        c = classify(self.model, lam, int(self.n_pulses))
        return np.where(c["regime"] == NONE, 0, np.where(c["regime"] == CLEAN, c["blind"], -1))

    def _factor(self, p: np.ndarray, m: np.ndarray) -> np.ndarray:
        P = p.sum(axis=-1)
        mod = self.model
        D = max(mod.spad_dead_time_ps, mod.tcspc_dead_time_ps) / mod.grid.period_ps - 1.0
        return np.where(m >= 0, 1.0 / (1.0 + np.maximum(m, 0) * P), 1.0 / (1.0 + max(D, 0.0) * P))

    def __call__(self, ideal: np.ndarray, probabilities: tuple | None = None) -> np.ndarray:
        """Mean counts ``[P, T]`` (float64); ``probabilities``: :meth:`probabilities` of ``ideal``, if made."""
        pr = probabilities or self.probabilities(ideal)
        return super().__call__(ideal, pr) * self._factor(pr[2], self.blind(ideal, pr[0]))[:, None]

    def vjp(self, ideal: np.ndarray, grad_mean: np.ndarray, probabilities: tuple | None = None) -> np.ndarray:
        """``d<grad_mean, mean(ideal)> / d ideal``, shape ``[P, T]`` (float64); ``probabilities``: as
        :meth:`__call__`."""
        pr = probabilities or self.probabilities(ideal)
        m = self.blind(ideal, pr[0])
        p = pr[2]
        s = self._factor(p, m)
        g = np.asarray(grad_mean, dtype=np.float64)
        base = super().__call__(ideal, pr)  # N jitter(p)
        # d mean_j / d p_k = s (N jitter)_jk - N jitter(p)_j m s^2: the second term is the same for every
        # slot k, i.e. a constant added to dL/dp; ExpectedCounts.vjp takes dL/d(N jitter(p)), so the constant
        # enters as a per-slot gradient c, carried through the Coates chain by _vjp_p.
        c = -np.where(m >= 0, np.maximum(m, 0), 0) * s * s * np.sum(g * base, axis=-1)
        return self._vjp_p(ideal, s[:, None] * g, c, pr)

    def _vjp_p(self, ideal: np.ndarray, g: np.ndarray, c: np.ndarray, probabilities: tuple) -> np.ndarray:
        """``d/d ideal`` of ``<g, N jitter(p)> + sum_k c p_k`` (``c [P]`` per pixel, over every slot)."""
        mod = self.model
        T = mod.grid.n_bins
        g_p = np.zeros((g.shape[0], mod.grid.n_slots))
        g_p[:, :T] = self.n_pulses * _jitter_adjoint(g, mod.kernel_first, mod.kernel)
        g_p += c[:, None]
        lam, survive, p = probabilities
        gp_p = g_p * p
        later = np.cumsum(gp_p[:, ::-1], axis=-1)[:, ::-1] - gp_p
        g_lam = g_p * survive * np.exp(-lam) - later
        return mod.params.pde * mod.gate_slots[None, :T] * g_lam[:, :T]


def poisson_nll(mean: np.ndarray, counts: np.ndarray) -> float:
    """``sum(mean - counts log mean + log counts!)``; bins with ``mean = 0`` and ``counts > 0`` give inf."""
    mu = np.asarray(mean, dtype=np.float64)
    k = np.asarray(counts, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        term = np.where(k > 0, k * np.log(mu), 0.0)
    return float(np.sum(mu - term + gammaln(k + 1.0)))


def poisson_nll_grad(mean: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """``d NLL / d mean = 1 - counts / mean`` (0 where both are 0)."""
    mu = np.asarray(mean, dtype=np.float64)
    k = np.asarray(counts, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(k > 0, 1.0 - k / mu, 1.0)


__all__ = ["ExpectedCounts", "RenewalExpectedCounts", "poisson_nll", "poisson_nll_grad"]
