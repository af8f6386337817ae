"""Signal-to-noise ratio over repeated detections, and what the detector model expects of it.

A photon-budget study detects one ideal capture with ``S`` seeds for every
detector setting and budget. Over the seeds, each time bin ``b`` of each
histogram (laser spot, pixel) has a mean ``x_b`` and an unbiased variance
``s2_b``; each histogram's total count (the pixel's counts over the whole
window) has a mean ``K`` and variance ``s2_K``.

**Per bin** (the *signal region*: bins where the gate is at least half open
and the render deposited light, ``ideal_b > 0``), bins are pooled into classes
of equal expected counts (4 per decade of the low-flux expectation
``mu_b = N (pde g_b ideal_b + background_b)``, convolved with the jitter,
see :func:`spad_detector.expected_counts_low_flux`). Per class:
``mean = <x_b>``, ``var = <s2_b>``, ``SNR = mean / sqrt(var)``. Counts in a
bin are Poisson to a very good approximation when the per-cycle probability of
a count in that bin is small (always, for bins much narrower than the window):
then ``SNR = sqrt(mean)`` (the shot-noise limit). The Fano factor
``F = var / mean`` is 1, with standard error (delta method; for Poisson bins
the mean's fluctuation cancels the kurtosis term)::

    sd(F) = sqrt(2 sum_b mu_b^2 / (S - 1)) / sum_b mu_b

which depends only on the relative sizes of the ``mu_b`` in the class, taken
from the model (a plug-in estimate from the counts is too noisy when most
bins hold no count; pile-up scales the ``mu_b`` of a class together). When
bins hold far less than one count, ``F - 1`` is decided by the few bins where
two seeds both counted; the Gaussian standard error is reliable when the
expected number of such coincidences, ``coincidences = S (S - 1) / 2 sum_b
mu_b^2``, is at least :data:`MIN_COINCIDENCES` (the summary and the tests
check those classes). The same detection seeds serve every detector setting
(common random numbers), so classes of different settings are correlated;
within one setting they are independent. The *signal* SNR counts only the
scene's photons: a bin's counts split into signal and background (dark counts,
ambient light) in the ratio of their intensities in that bin, whatever the dead
time does (it cannot tell a signal avalanche from a dark one), so the signal
counts are ``N_s = sum_b x_b sig_b / mu_b`` (exact up to the jitter's mixing of
neighbouring bins) and the signal SNR is ``N_s / sd``. Its shot-noise limit
(no background) is ``sqrt(N_s)``; with background, Poisson counts give
``N_s / sqrt(N_s + N_bg)``.

**Per pixel** (total counts of one histogram), dead time matters: every count
blinds the detector, so counts are more regular than Poisson. Where the
detector model's *whole blind cycles* regime holds (docs/detector.md, section
5: each count blinds exactly ``m`` whole cycles), the counts form a renewal
process with interval ``m + Geometric(p)`` cycles, ``p`` the per-cycle
detection probability, so for ``N`` cycles (asymptotically in ``N``)::

    E[K] = N p / (1 + m p),    Var[K] / E[K] = (1 - p) / (1 + m p)^2

(the recorded counts are a binomial thinning of these with the fraction ``q``
of avalanches whose time stamp lands in the window: ``F = q F_K + 1 - q``).
The per-pixel SNR is then ``sqrt(E[K] / F)``, above ``sqrt(E[K])``. The
standard error of a class's measured Fano factor is
``sqrt(2 sum_k (F mean_k)^2 / (S - 1)) / sum_k mean_k`` (pooled variance of
nearly Gaussian totals, ``F`` the predicted value where there is one, else the
measured one). The prediction is
shown for pixels with at least :data:`MIN_RENEWAL_COUNTS` expected counts
(the asymptotic formula's relative error is of order ``1 / E[K]``); pixels in
other regimes (dead time shorter than the window, or not a whole number of
cycles) have no closed form and are reported without it. Without any dead
time the counts are Poisson (``F = 1``).
"""

from __future__ import annotations

import math

import numpy as np

#: Per-bin statistics use at most this many histograms (spot, pixel), evenly spread over the capture.
MAX_HISTOGRAMS = 256
#: Classes of expected counts per decade.
CLASSES_PER_DECADE = 4
#: A class needs at least this many bins (or pixels) to be reported.
MIN_PER_CLASS = 20
#: ... and its bins must hold at least this many counts over all seeds (else the variance is not measurable).
MIN_COUNTS_PER_CLASS = 100
#: Classes with fewer expected same-bin coincidences between seeds have a skewed Fano estimate (see above).
MIN_COINCIDENCES = 20.0
#: The asymptotic renewal prediction is reported for pixels with at least this many expected counts.
MIN_RENEWAL_COUNTS = 100.0
#: A bin belongs to the signal region when the gate efficiency is at least this.
GATE_OPEN = 0.5


def _class_index(x: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore"):
        return np.floor(CLASSES_PER_DECADE * np.log10(x) + 1e-9).astype(np.int64)


def _class_bounds(k: int) -> tuple[float, float]:
    return 10.0 ** (k / CLASSES_PER_DECADE), 10.0 ** ((k + 1) / CLASSES_PER_DECADE)


class SpotExpectation:
    """What the detector model expects for one laser spot (see the module docstring).

    Attributes
    ----------
    signal : ndarray, shape (n_selected, T)
        Expected signal counts per bin (low flux) of the selected histograms.
    rendered : ndarray of bool, shape (n_selected, T)
        Bins of the selected histograms that received rendered light (ideal > 0).
    background : ndarray, shape (T,)
        Expected background counts per bin (dark counts, ambient light; low flux).
    signal_fraction : ndarray of float32, shape (n_pix, T)
        Fraction of each bin's avalanches that come from the scene (signal / (signal + background)).
    gate : ndarray, shape (T,)
        Gate efficiency per bin.
    total : ndarray, shape (n_pix,)
        Low-flux expected counts of every pixel (sum over bins).
    p_det : ndarray, shape (n_pix,)
        Per-cycle avalanche probability of every pixel.
    regime : ndarray of str, shape (n_pix,)
        ``none`` (no dead time), ``whole_blind_cycles`` or ``other``.
    renewal_mean, renewal_fano : ndarray, shape (n_pix,)
        The closed-form mean and Fano factor of the pixel's total counts
        (NaN where no closed form applies).
    """

    def __init__(self, detection, j: int, selected: np.ndarray):
        # (_clean_first_photon: the analytic engine's Coates probabilities of the whole-blind-cycles regime)
        from spad_detector.engines.analytic import CLEAN, NONE, _clean_first_photon, classify
        from spad_detector.model import apply_jitter_kernel

        model = detection.model(j)
        N = detection.n_pulses
        arr = detection.scaled_ideal(j)
        T = arr.shape[1]
        jit = (model.kernel_first, model.kernel)
        pde = model.params.pde
        gate = model.gate_slots[:T]
        lam = model.intensity(arr)
        self.gate = np.asarray(gate, dtype=np.float64)
        self.rendered = arr[selected] > 0
        sig_all = apply_jitter_kernel(pde * gate[None, :] * arr, *jit) * N
        mu_all = apply_jitter_kernel(lam[:, :T], *jit) * N
        self.signal = sig_all[selected]
        self.background = apply_jitter_kernel(model.background[None, :T], *jit)[0] * N
        self.total = mu_all.sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            self.signal_fraction = np.where(mu_all > 0, np.clip(sig_all / mu_all, 0.0, 1.0), 0.0).astype(np.float32)
        del sig_all, mu_all
        self.p_det = -np.expm1(-lam.sum(axis=1))
        c = classify(model, lam, N)
        reg = c["regime"]
        self.regime = np.where(reg == NONE, "none", np.where(reg == CLEAN, "whole_blind_cycles", "other"))
        self.renewal_mean = np.full(lam.shape[0], np.nan)
        self.renewal_fano = np.full(lam.shape[0], np.nan)
        none = reg == NONE
        self.renewal_mean[none] = self.total[none]
        self.renewal_fano[none] = 1.0
        clean = reg == CLEAN
        if np.any(clean):
            pr = _clean_first_photon(lam, c, clean)
            p = pr.sum(axis=1)
            m = c["blind"][clean].astype(np.float64)
            with np.errstate(invalid="ignore", divide="ignore"):
                q = np.where(p > 0, apply_jitter_kernel(pr[:, :T] / np.where(p > 0, p, 1.0)[:, None], *jit).sum(1),
                             0.0)
            mean_k = N * p / (1.0 + m * p)
            fano_k = (1.0 - p) / (1.0 + m * p) ** 2
            self.renewal_mean[clean] = q * mean_k
            self.renewal_fano[clean] = q * fano_k + (1.0 - q)


class SnrStats:
    """Accumulates counts over detection seeds for one detector setting and budget.

    Call :meth:`add` with every spot of every seed (duplicates are ignored),
    then :meth:`bin_rows` and :meth:`pixel_rows`. Integer sums keep the
    moments exact (and the tables byte-reproducible).
    """

    def __init__(self, detection, seeds):
        self.detection = detection
        self.seeds = tuple(int(s) for s in seeds)
        n_files, H, W, T = detection.ideal.shape
        self.n_pix = H * W
        self.T = T
        total = n_files * self.n_pix
        flat = np.unique(np.round(np.linspace(0, total - 1, min(total, MAX_HISTOGRAMS))).astype(np.int64))
        self.selected = [flat[flat // self.n_pix == j] % self.n_pix for j in range(n_files)]
        self._rows = {j: (np.searchsorted(flat, j * self.n_pix + self.selected[j])) for j in range(n_files)}
        self.S1 = np.zeros((len(flat), T), dtype=np.int64)
        self.S2 = np.zeros((len(flat), T), dtype=np.int64)
        self.K1 = np.zeros((n_files, self.n_pix), dtype=np.int64)
        self.K2 = np.zeros((n_files, self.n_pix), dtype=np.int64)
        self.expect: dict[int, SpotExpectation] = {}
        self.signal_counts: dict[tuple[int, int], float] = {}
        self._seen: set = set()

    def add(self, j: int, seed: int, counts: np.ndarray) -> None:
        """Add spot ``j``'s counts ``[H, W, T]`` of detection seed ``seed``."""
        if (j, seed) in self._seen:
            return
        self._seen.add((j, seed))
        if j not in self.expect:
            self.expect[j] = SpotExpectation(self.detection, j, self.selected[j])
        c = counts.reshape(self.n_pix, self.T).astype(np.int64)
        self.signal_counts[(j, seed)] = float((c * self.expect[j].signal_fraction).sum(dtype=np.float64))
        rows = self._rows[j]
        sel = c[self.selected[j]]
        self.S1[rows] += sel
        self.S2[rows] += sel * sel
        k = c.sum(axis=1)
        self.K1[j] += k
        self.K2[j] += k * k

    # ------------------------------------------------------------------ summaries

    def expected_background_per_pixel(self) -> float:
        """Expected background counts per pixel per spot without dead time (sum over bins, mean over spots)."""
        return float(np.mean([e.background.sum() for e in self.expect.values()]))

    def signal_counts_per_pixel(self, seed: int) -> float:
        """Signal counts (the scene's photons) per pixel per spot of one seed (see the module docstring)."""
        return sum(v for (j, s), v in self.signal_counts.items() if s == seed) / (len(self.expect) * self.n_pix)

    def has(self, j: int, seed: int) -> bool:
        """Whether spot ``j`` of seed ``seed`` was added."""
        return (j, seed) in self._seen

    def p_det(self) -> np.ndarray:
        """Per-cycle avalanche probability of every (spot, pixel)."""
        return np.concatenate([self.expect[j].p_det for j in sorted(self.expect)])

    def _moments(self, s1: np.ndarray, s2: np.ndarray):
        S = len(self.seeds)
        mean = s1 / S
        var = (s2 - s1.astype(np.float64) * s1 / S) / (S - 1)
        return mean, np.maximum(var, 0.0)

    def bin_rows(self) -> list[dict]:
        """Per-bin SNR classes over the signal region (see the module docstring)."""
        S = len(self.seeds)
        mu, bg, sig, mean, var, smean = [], [], [], [], [], []
        for j in sorted(self.expect):
            e = self.expect[j]
            rows = self._rows[j]
            if not len(rows):
                continue
            m, v = self._moments(self.S1[rows], self.S2[rows])
            region = (e.gate[None, :] >= GATE_OPEN) & e.rendered
            b = np.broadcast_to(e.background[None, :], e.signal.shape)
            mu.append((e.signal + b)[region])
            bg.append(b[region])
            sig.append(e.signal[region])
            mean.append(m[region])
            var.append(v[region])
            smean.append((m * e.signal_fraction[self.selected[j]])[region])
        if not mu:
            return []
        mu, bg, sig, mean, var, smean = (np.concatenate(a) for a in (mu, bg, sig, mean, var, smean))
        cls = _class_index(mu)
        out = []
        for k in np.unique(cls[mu > 0]):
            i = cls == k
            n = int(np.count_nonzero(i))
            if n < MIN_PER_CLASS or S * float(mean[i].sum()) < MIN_COUNTS_PER_CLASS:
                continue
            m_, v_ = float(mean[i].mean()), float(var[i].mean())
            s_ = float(smean[i].mean())
            fano = v_ / m_ if m_ > 0 else math.nan
            mu2 = float((mu[i] ** 2).sum())
            fano_sd = math.sqrt(2.0 * mu2 / (S - 1)) / float(mu[i].sum())
            lo, hi = _class_bounds(int(k))
            out.append({
                "class_lo": lo, "class_hi": hi, "n_bins": n,
                "expected_counts": float(mu[i].mean()), "expected_signal": float(sig[i].mean()),
                "expected_background": float(bg[i].mean()),
                "mean_counts": m_, "var_counts": v_,
                "snr": m_ / math.sqrt(v_) if v_ > 0 else math.nan,
                "snr_poisson": math.sqrt(m_),
                "fano": fano, "fano_sd": fano_sd, "coincidences": S * (S - 1) / 2 * mu2,
                "signal_counts": s_, "background_counts": m_ - s_,
                "signal_snr": s_ / math.sqrt(v_) if v_ > 0 else math.nan,
                "signal_snr_shot_limit": math.sqrt(max(s_, 0.0)),
                "signal_snr_poisson": s_ / math.sqrt(m_) if m_ > 0 else math.nan,
            })
        return out

    def pixel_rows(self) -> list[dict]:
        """Per-pixel (total counts) SNR classes, by dead-time regime, with the renewal prediction."""
        S = len(self.seeds)
        spots = sorted(self.expect)
        mean, var = self._moments(self.K1[spots].ravel(), self.K2[spots].ravel())
        total = np.concatenate([self.expect[j].total for j in spots])
        regime = np.concatenate([self.expect[j].regime for j in spots])
        r_mean = np.concatenate([self.expect[j].renewal_mean for j in spots])
        r_fano = np.concatenate([self.expect[j].renewal_fano for j in spots])
        cls = _class_index(total)
        out = []
        for reg in ("none", "whole_blind_cycles", "other"):
            for k in np.unique(cls[(regime == reg) & (total > 0)]):
                i = (cls == k) & (regime == reg)
                n = int(np.count_nonzero(i))
                if n < MIN_PER_CLASS:
                    continue
                m_, v_ = float(mean[i].mean()), float(var[i].mean())
                tot = float(mean[i].sum())
                rm, rf = r_mean[i], r_fano[i]
                predicted = reg != "other" and np.all(np.isfinite(rm)) and float(rm.min()) >= MIN_RENEWAL_COUNTS
                f_pred = float((rm * rf).sum() / rm.sum()) if predicted else math.nan
                # sd of the pooled variance of ~Gaussian totals: Var(s2_k) = 2 sigma_k^4 / (S - 1), with
                # sigma_k^2 ~ F x mean_k (F predicted if known, else measured; per-pixel s2^2 is too noisy for S ~ 3)
                f_use = f_pred if predicted else (v_ / m_ if m_ > 0 else math.nan)
                fano_sd = math.sqrt(2.0 * float(((f_use * mean[i]) ** 2).sum()) / (S - 1)) / tot if tot > 0 \
                    else math.nan
                lo, hi = _class_bounds(int(k))
                row = {"regime": reg, "class_lo": lo, "class_hi": hi, "n_pixels": n,
                       "expected_counts_low_flux": float(total[i].mean()),
                       "mean_counts": m_, "var_counts": v_,
                       "snr": m_ / math.sqrt(v_) if v_ > 0 else math.nan, "snr_poisson": math.sqrt(m_),
                       "fano": v_ / m_ if m_ > 0 else math.nan, "fano_sd": fano_sd,
                       "predicted_mean": None, "predicted_fano": None, "predicted_snr": None}
                if predicted:
                    row.update(predicted_mean=float(rm.mean()), predicted_fano=f_pred,
                               predicted_snr=math.sqrt(m_ / f_pred) if f_pred > 0 else math.nan)
                out.append(row)
        return out
