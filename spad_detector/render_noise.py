r"""How much of a detection's noise is rendering noise.

An ideal capture is a Monte Carlo estimate ``x_b`` of the expected photons per
pulse in bin ``b``, with its own variance ``s_b^2`` (stored beside the capture,
see :mod:`transient_core.stack`, ``variance/``). Detection draws counts whose mean is
the *estimate*, so the counts carry two noises: the photon (shot) noise the
user wants to study, and the frozen rendering noise of ``x``. For a photon
budget of ``N`` pulses, the low-flux mean counts after the gate ``g_b``, the
photon detection efficiency ``eta`` and the jitter kernel ``k_j`` are

.. math::

    \mu_b = N \sum_j k_j (\eta g x + d)_{b - j},

with ``d`` the dark and ambient counts per pulse and bin, and their
rendering variance is

.. math::

    V_b = N^2 \sum_j k_j^2 (\eta g)^2_{b - j} s^2_{b - j}

(covariances between bins neglected: in a three-bounce NLOS capture each
sample adds to one bin per spot, so they are negative, of relative size
about the share of a pixel's light that falls within one jitter width; the
neglect overstates ``V`` by that much at most). The photon variance of a bin is ``mu_b``
(Poisson, the low-flux limit; dead time makes real counts less variable).
The *noise ratio* of a set of bins is ``sum V_b / sum mu_b``: rendering
variance over photon variance. Bins are grouped into classes by their mean
counts (0.1-1, 1-10, 10-100, 100-1000, > 1000); the headline ratio is the
largest class ratio among the classes holding at least
:data:`MIN_CLASS_SHARE` of the counts. Per-pixel totals (all bins of a
pixel) are reported beside it: their ratio is larger, since the jitter
averages rendering noise over ~``2 sqrt(pi) sigma / bin_width`` bins but a
total averages over the whole histogram. A total's rendering variance uses
the capture's exact estimate of each pixel's total variance (covariances
included), ``N^2 eta^2 gbar^2 Var(sum_b x_b)``, with ``gbar`` the
light-weighted mean gate of the pixel.

Rendering variance falls as ``1/spp`` for plain Monte Carlo (faster for the
randomised QMC of the NLOS estimator), so ``spp * ratio / threshold``
samples per pixel bring the ratio under ``threshold`` (a conservative
estimate).

A capture of two parts (``estimator="quadrature"`` beyond three bounces: the quadrature's three-bounce light
plus the Monte Carlo remainder, see :mod:`transient_mi.capture_error`) has both a variance ``s_b^2`` (the
remainder's) and a bound ``B_b`` (the quadrature's). Its rendering variance per bin is the sum of the two,

.. math::

    V_b = N^2 \sum_j k_j^2 (\eta g)^2_{b - j} s^2_{b - j} + N^2 \Big(\sum_j k_j (\eta g B)_{b - j}\Big)^2,

and of a pixel total ``(N eta gbar)^2 (Var(sum_b x_b) + B_total^2)``; the report gives each part's share.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .model import DetectorModel, apply_jitter_kernel

#: Default noise-ratio threshold: rendering variance at most 10 % of the photon variance.
DEFAULT_THRESHOLD = 0.1
#: Classes of bins by mean counts (lower bound exclusive, upper inclusive).
BIN_CLASSES = ((0.1, 1.0), (1.0, 10.0), (10.0, 100.0), (100.0, 1000.0), (1000.0, math.inf))
#: A class counts for the headline ratio when it holds at least this share of all counts.
MIN_CLASS_SHARE = 0.01

DEFINITION = ("rendering variance / photon (Poisson) variance of the low-flux mean counts after gate, PDE and "
              "jitter; headline = largest ratio among bin classes (by mean counts) holding >= 1 % of the counts; "
              "covariance between bins neglected")


@dataclass
class NoiseRatio:
    """Accumulates rendering and photon variance over spots, per bin class and per pixel total.

    Use :meth:`add_spot` for each laser spot, then :meth:`report`.
    """

    threshold: float = DEFAULT_THRESHOLD
    class_mu: np.ndarray = field(default_factory=lambda: np.zeros(len(BIN_CLASSES)))
    class_var: np.ndarray = field(default_factory=lambda: np.zeros(len(BIN_CLASSES)))
    class_bins: np.ndarray = field(default_factory=lambda: np.zeros(len(BIN_CLASSES), dtype=np.int64))
    total_mu: float = 0.0
    total_var: float = 0.0
    pixel_ratios: list = field(default_factory=list)
    mu_all: float = 0.0
    #: sum over bins of mu^2 and of V (count-weighted relative rendering error: sqrt(var_sum / mu2_sum))
    mu2_sum: float = 0.0
    var_sum: float = 0.0
    #: of ``var_sum``: the part from a bound given beside a variance (``add_spot(..., bound=...)``)
    bound_var_sum: float = 0.0
    two_parts: bool = False

    def add_spot(self, model: DetectorModel, ideal: np.ndarray, variance: np.ndarray, n_pulses: int,
                 total_variance: np.ndarray | None = None, error_bound: bool = False,
                 bound: np.ndarray | None = None, total_bound: np.ndarray | None = None) -> None:
        """Add one spot.

        Parameters
        ----------
        model : DetectorModel
            The spot's detector model (gate, PDE, background, jitter kernel).
        ideal, variance : ndarray, shape (n_pixels, n_bins)
            Expected photons per pulse (photon scale applied) and the
            estimated variance of each value (scale squared applied).
        n_pulses : int
            Pulses integrated per histogram.
        total_variance : ndarray, shape (n_pixels,), optional
            Estimated variance of each pixel's sum over time (scale squared
            applied); without it, the per-bin variances are summed.
        error_bound : bool
            ``variance`` and ``total_variance`` hold a deterministic estimator's
            bound ``B`` on the absolute error (photon scale applied, not squared).
            A bound is a worst case, correlated between bins: it is carried
            through gate, PDE and jitter linearly, and its square stands for the
            rendering variance, ``V_b = N^2 (sum_j k_j (eta g B)_{b - j})^2``.
        bound, total_bound : ndarray, shape (n_pixels, n_bins) and (n_pixels,), optional
            A capture of two parts: the quadrature's bound beside the Monte Carlo remainder's ``variance``
            (photon scale applied). Its linear-through-jitter square is added to the variance of every bin,
            and ``total_bound^2`` to each total's.
        """
        x_all = np.asarray(ideal, dtype=np.float64)
        T = x_all.shape[-1]
        # only the bins the gated light (or its jitter) reaches: elsewhere the counts are background alone (light
        # below 1e-12 of the peak, e.g. behind a closed gate, is neglected), with no rendering variance and far
        # below the smallest class; their background is added to the totals in closed form below
        gated_peak = (x_all * (model.params.pde * model.gate_slots[None, :T])).max(axis=0)
        lit = np.flatnonzero(gated_peak > 1e-12 * max(float(gated_peak.max()), 1e-300))
        reach = len(model.kernel) + abs(model.kernel_first) + 1
        t_lo, t_hi = (0, 0) if lit.size == 0 else (max(0, int(lit[0]) - reach), min(T, int(lit[-1]) + reach + 1))
        w_all = model.params.pde * model.gate_slots[:T]
        bg = model.background[:T]
        x = x_all[:, t_lo:t_hi]
        lam = model.params.pde * model.gate_slots[None, t_lo:t_hi] * x + bg[None, t_lo:t_hi]
        mu = apply_jitter_kernel(lam, model.kernel_first, model.kernel) * n_pulses
        w = w_all[None, t_lo:t_hi]
        if error_bound:
            b_in = w * np.asarray(variance, dtype=np.float64)[:, t_lo:t_hi]
            var = np.square(apply_jitter_kernel(b_in, model.kernel_first, model.kernel) * float(n_pulses))
        else:
            v_in = np.square(w) * np.asarray(variance, dtype=np.float64)[:, t_lo:t_hi]
            var = apply_jitter_kernel(v_in, model.kernel_first, np.square(model.kernel)) * float(n_pulses) ** 2
        var_b = None
        if bound is not None:
            b_in = w * np.asarray(bound, dtype=np.float64)[:, t_lo:t_hi]
            var_b = np.square(apply_jitter_kernel(b_in, model.kernel_first, model.kernel) * float(n_pulses))
            var = var + var_b
            self.bound_var_sum += float(var_b.sum())
            self.two_parts = True
        bg_outside = float(n_pulses) * float(bg[:t_lo].sum() + bg[t_hi:].sum())
        for c, (lo, hi) in enumerate(BIN_CLASSES):
            sel = (mu > lo) & (mu <= hi)
            self.class_mu[c] += float(mu[sel].sum())
            self.class_var[c] += float(var[sel].sum())
            self.class_bins[c] += int(sel.sum())
        self.mu_all += float(mu.sum()) + bg_outside * x_all.shape[0]
        self.mu2_sum += float(np.square(mu).sum())
        self.var_sum += float(var.sum())
        pm = mu.sum(axis=1) + bg_outside
        if total_variance is None:
            pv = var.sum(axis=1)
        else:
            xs = x.sum(axis=1)
            gbar = np.divide((x * model.gate_slots[None, t_lo:t_hi]).sum(axis=1), xs, out=np.zeros_like(xs),
                             where=xs > 0)
            tv = np.asarray(total_variance, dtype=np.float64)
            tv = np.square(tv) if error_bound else tv
            if total_bound is not None:
                tv = tv + np.square(np.asarray(total_bound, dtype=np.float64))
            pv = (float(n_pulses) * model.params.pde * gbar) ** 2 * tv
        self.total_mu += float(pm.sum())
        self.total_var += float(pv.sum())
        ok = pm > 1.0
        self.pixel_ratios.extend((pv[ok] / pm[ok]).tolist())

    def report(self, spp: int | None = None, replicates: int | None = None, estimator: str | None = None) -> dict:
        """The JSON block written to a counts manifest (``detector.resolved.render_noise``).

        ``estimator``: ``"quadrature"`` when the ideal capture's error is a deterministic bound (the ratio is
        then (bound / photon noise) squared and no spp hint is given)."""
        classes = []
        headline = 0.0
        for c, (lo, hi) in enumerate(BIN_CLASSES):
            share = self.class_mu[c] / self.mu_all if self.mu_all > 0 else 0.0
            ratio = self.class_var[c] / self.class_mu[c] if self.class_mu[c] > 0 else None
            classes.append({"counts_above": lo, "counts_up_to": None if math.isinf(hi) else hi,
                            "bins": int(self.class_bins[c]), "share_of_counts": share, "ratio": ratio})
            if ratio is not None and share >= MIN_CLASS_SHARE:
                headline = max(headline, ratio)
        totals = {
            "ratio_pooled": self.total_var / self.total_mu if self.total_mu > 0 else None,
            "ratio_median_pixel": float(np.median(self.pixel_ratios)) if self.pixel_ratios else None,
        }
        out = {"available": True, "ratio": headline, "threshold": self.threshold,
               "exceeds_threshold": bool(headline > self.threshold), "definition": DEFINITION,
               "classes": classes, "pixel_totals": totals}
        if estimator is not None:
            out["estimator"] = estimator
            out["definition"] = DEFINITION + "; rendering variance = square of the deterministic error bound"
        if self.two_parts:
            out["definition"] = (DEFINITION + "; rendering variance = Monte Carlo variance of the remainder + square "
                                 "of the quadrature's error bound (carried linearly through gate, PDE and jitter)")
            share_b = self.bound_var_sum / self.var_sum if self.var_sum > 0 else 0.0
            out["parts"] = {"quadrature_error_bound": {"share_of_rendering_variance": share_b},
                            "monte_carlo_remainder": {"share_of_rendering_variance": 1.0 - share_b
                                                      if self.var_sum > 0 else 0.0}}
        if spp and estimator is None:
            out["spp"] = int(spp)
            out["spp_for_threshold"] = spp_for_threshold(spp, headline, self.threshold, replicates or 1)
        elif spp and self.two_parts:
            # only the remainder's part falls with spp (its share pooled over the lit bins: an approximation)
            share_b = out["parts"]["quadrature_error_bound"]["share_of_rendering_variance"]
            room = self.threshold - headline * share_b
            out["spp"] = int(spp)
            out["spp_for_threshold"] = (spp_for_threshold(spp, headline * (1.0 - share_b), room, replicates or 1)
                                        if room > 0 else None)
        return out


def spp_for_threshold(spp: int, ratio: float, threshold: float, replicates: int = 1) -> int:
    """Samples per pixel that bring ``ratio`` (measured at ``spp``) to ``threshold``, assuming variance ~ 1/spp.

    Rounded up to a multiple of ``replicates``; at least ``spp``.
    """
    if ratio <= threshold:
        return int(spp)
    need = math.ceil(spp * ratio / threshold)
    r = max(1, int(replicates))
    return int(max(spp, r * math.ceil(need / r)))


def unavailable(reason: str) -> dict:
    """The manifest block when the ideal capture stores no variance."""
    return {"available": False, "reason": reason}


def warning_line(report: dict) -> str | None:
    """One line for stderr when the ratio exceeds its threshold, else None."""
    if not report.get("available") or not report.get("exceeds_threshold"):
        return None
    spp = report.get("spp")
    need = report.get("spp_for_threshold")
    hint = (f"; render with --spp {need} (now {spp}) or `transient-mi render --noise-target "
            f"{report['threshold']:g}` to bring it under" if spp and need else "")
    if report.get("estimator") == "quadrature+monte_carlo":
        share = report.get("parts", {}).get("quadrature_error_bound", {}).get("share_of_rendering_variance", 0.0)
        return (f"warning: rendering error is {report['ratio']:.3g}x the photon noise at this budget (threshold "
                f"{report['threshold']:g}); {share:.0%} of it is the quadrature's error bound (smaller "
                f"element_size_m, more patch_cells), the rest the Monte Carlo remainder's variance{hint}")
    if report.get("estimator") == "quadrature":
        return (f"warning: the quadrature's error bound is {report['ratio']:.3g}x the photon noise (squared) at this "
                f"budget (threshold {report['threshold']:g}): render with a smaller element_size_m or more "
                "patch_cells")
    tot = report["pixel_totals"].get("ratio_pooled")
    tot_txt = f" (per-pixel totals: {tot:.3g})" if tot is not None else ""
    return (f"warning: rendering noise is {report['ratio']:.3g}x the photon noise at this budget "
            f"(threshold {report['threshold']:g}){tot_txt}: the counts mostly show Monte Carlo noise of the ideal "
            f"capture{hint}")
