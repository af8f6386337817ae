"""SPAD + TCSPC detector model (pure numpy; never imports Mitsuba).

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
coates_correction       pile-up correction (from :mod:`recon.pileup`)
resolve_budget, auto_gate, gate_efficiency, gate_mean, Jitter
nonparalyzable_rate, paralyzable_rate, pulsed_rate_per_cycle, first_photon_probabilities
"""

from recon.pileup import coates_correction, coates_std

from .budget import Budget, resolve_budget
from .detect import detect, expected_counts_low_flux
from .gate import auto_gate, gate_efficiency, gate_mean, gate_sigma_ps, three_bounce_range_ps
from .jitter import Jitter, load_irf
from .params import DEFAULT_PULSES, DEFAULT_REPETITION_RATE_HZ, DetectorParams, param_names
from .pileup import (first_photon_probabilities, nonparalyzable_rate, paralyzable_rate,
                     pulsed_rate_per_cycle)
from .stack import detect_stack

__all__ = [
    "DetectorParams", "detect", "detect_stack", "coates_correction", "coates_std", "Budget", "resolve_budget",
    "auto_gate", "three_bounce_range_ps", "gate_efficiency", "gate_mean", "gate_sigma_ps", "Jitter",
    "load_irf", "first_photon_probabilities", "nonparalyzable_rate", "paralyzable_rate",
    "pulsed_rate_per_cycle", "expected_counts_low_flux", "param_names", "DEFAULT_PULSES",
    "DEFAULT_REPETITION_RATE_HZ",
]
