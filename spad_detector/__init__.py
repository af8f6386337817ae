"""spad_detector: the SPAD + TCSPC detector model (numpy/scipy/numba; never imports Mitsuba or drjit).

Turns an ideal capture (expected photons per pulse per bin) into photon
counts, modelling in the order light meets them: photon budget, photon
detection efficiency, time gate, dark counts and ambient light, dead time and
pile-up (SPAD and TCSPC), afterpulsing, crosstalk and timing jitter. See
``docs/detector.md``.

Public API
----------
DetectorParams          every parameter, with units and the paper's defaults
detect                  arrays: ideal[..., T] -> counts[..., T] (uint32)
detect_stack            capture directories, streamed spot by spot
coates_correction       pile-up correction of measured histograms (:mod:`.coates`)
resolve_budget, auto_gate, gate_efficiency, gate_mean, Jitter
nonparalyzable_rate, paralyzable_rate, pulsed_rate_per_cycle, first_photon_probabilities
"""

from __future__ import annotations

from transient_core.lazy_exports import lazy_exports

_EXPORTS = {
    "coates_correction": "coates", "coates_std": "coates",
    "Budget": "budget", "resolve_budget": "budget",
    "detect": "detect", "expected_counts_low_flux": "detect",
    "auto_gate": "gate", "gate_efficiency": "gate", "gate_mean": "gate", "gate_sigma_ps": "gate",
    "three_bounce_range_ps": "gate",
    "Jitter": "jitter", "load_irf": "jitter",
    "DEFAULT_PULSES": "params", "DEFAULT_REPETITION_RATE_HZ": "params", "DetectorParams": "params",
    "param_names": "params",
    "first_photon_probabilities": "pileup", "nonparalyzable_rate": "pileup", "paralyzable_rate": "pileup",
    "pulsed_rate_per_cycle": "pileup",
    "detect_stack": "stream",
    "ExpectedCounts": "likelihood", "poisson_nll": "likelihood", "poisson_nll_grad": "likelihood",
}

__all__ = sorted(_EXPORTS)


# Public names load their module on first use, so the import is cheap and a user of one part does not
# pay for the others (numba kernels, scipy).
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals())
