"""Pile-up correction for TCSPC histograms (Coates' estimator).

A TCSPC channel records at most the first photon of each laser cycle, so
late bins are under-counted when the flux is high ("pile-up"). With ``N``
cycles and ``n_b`` counts in bin ``b``, the number of cycles still able to
detect in bin ``b`` is ``R_b = N - sum_{i<b} n_i``. Coates (1968) estimates the
per-cycle probability of a detection in bin ``b`` *given* none before it (the
hazard) as ``h_b = n_b / R_b`` and the mean number of detectable photons per
cycle in that bin as ``lambda_b = -ln(1 - h_b)``. For a Poisson source whose
first photon in a cycle is detected (dead time longer than the rest of the
window and shorter than the gap to the next one) this is the maximum-likelihood
estimate of ``lambda``, consistent as ``N`` grows.

Dead time longer than the period
--------------------------------
If every detection blinds the detector for ``m`` whole further cycles (e.g. a
TCSPC that converts at most 20 M counts/s, i.e. 50 ns dead time, at a 50 MHz
laser with a short gated window: ``m = 2``), only the cycles in which it was
ready can detect: ``N_live = N - m * K`` with ``K = sum_b n_b``, up to the last
detection's blind cycles, which may run past the end of the measurement
(between 0 and ``m`` of them are lost; half of them, ``m / 2``, are added
back: the midpoint of the bounds). ``blind_cycles=m`` uses ``N_live`` in
place of ``N``; apply it per pixel (a histogram summed over pixels needs
``m / 2`` per pixel, an O(m / N) difference). Detections falling outside the
histogram (e.g. pushed out by jitter) are not seen and are neglected.

Limits: the estimator assumes bins are in the order of the true arrival
times; timing jitter smears the histogram after the pile-up happened, so apply
it to histograms whose jitter is small compared with the pile-up's time scale,
or accept the residual bias. Bins where every remaining cycle fired give
``inf``.

Reference: P. B. Coates, "The correction for photon 'pile-up' in the
measurement of radiative lifetimes", J. Phys. E 1, 878 (1968).
"""

from __future__ import annotations

import numpy as np

from transient_core.errors import UserInputError

__all__ = ["coates_correction", "coates_std"]


def _prepare(counts, n_cycles, axis, blind_cycles):
    c = np.asarray(counts, dtype=np.float64)
    if c.ndim == 0:
        raise UserInputError("counts must have a time axis")
    if c.size and (not np.all(np.isfinite(c)) or c.min() < 0):
        raise UserInputError("counts must be finite and >= 0 for the Coates correction")
    c = np.moveaxis(c, axis, -1)
    n = np.asarray(n_cycles, dtype=np.float64)
    if np.any(~(n > 0)) or np.any(~np.isfinite(n)):
        raise UserInputError(f"n_cycles={n_cycles!r} must be finite and > 0")
    m = np.asarray(blind_cycles, dtype=np.float64)
    if np.any(~(m >= 0)) or np.any(~np.isfinite(m)):
        raise UserInputError(f"blind_cycles={blind_cycles!r} must be finite and >= 0")
    try:
        total = c.sum(-1)
        live = n - m * total + 0.5 * m * (total > 0)
    except ValueError:
        raise UserInputError(f"n_cycles shape {n.shape} does not broadcast against the counts' "
                             f"non-time shape {c.shape[:-1]}") from None
    if np.any(live <= 0):
        raise UserInputError(
            f"n_cycles - blind_cycles x total counts <= 0 (n_cycles={n_cycles!r}, blind_cycles={blind_cycles!r}): "
            "more detections than the detector had live cycles")
    live = live[..., None]
    before = np.cumsum(c, axis=-1) - c  # counts in earlier bins
    remaining = live - before
    # with blind cycles, the last detection's unknown truncation allows up to m/2 more
    slack = 1e-9 + 0.5 * np.asarray(m, dtype=np.float64)[..., None] if np.ndim(m) else 1e-9 + 0.5 * float(m)
    if np.any(remaining < c - slack):
        raise UserInputError("counts exceed the live cycles: more detections than laser cycles")
    return c, np.maximum(remaining, c)


def coates_correction(counts: np.ndarray, n_cycles, axis: int = -1, blind_cycles=0) -> np.ndarray:
    """Estimate detectable photons per cycle per bin from piled-up counts.

    Parameters
    ----------
    counts : ndarray
        Photon counts, time along ``axis`` (e.g. ``[..., time]``).
    n_cycles : int or ndarray
        Number of laser cycles (pulses) the histogram integrates; broadcast
        against ``counts`` with the time axis removed.
    axis : int
        The time axis of ``counts``.
    blind_cycles : int or ndarray, optional
        Whole cycles the detector stays blind after each detection (0: the
        classic Coates setting). See the module docstring.

    Returns
    -------
    ndarray of float64, same shape as ``counts``
        ``lambda_b``: mean detectable photons per cycle in each bin (after
        detection efficiency and gating, i.e. what a dead-time-free detector
        would count per cycle). Multiply by ``n_cycles`` for corrected counts.
        Bins where every remaining cycle fired give ``inf``.
    """
    c, remaining = _prepare(counts, n_cycles, axis, blind_cycles)
    with np.errstate(divide="ignore", invalid="ignore"):
        h = np.where(remaining > 0, c / remaining, 0.0)
        lam = -np.log1p(-np.clip(h, 0.0, 1.0))
    return np.moveaxis(lam, -1, axis)


def coates_std(counts: np.ndarray, n_cycles, axis: int = -1, blind_cycles=0) -> np.ndarray:
    """Standard error of :func:`coates_correction` per bin (delta method).

    Given ``R_b`` cycles still able to detect, ``n_b ~ Binomial(R_b, h_b)``,
    so ``Var(lambda_b) ~= h_b / ((1 - h_b) R_b)``, evaluated at the estimate
    ``h_b = n_b / R_b`` (0 for empty bins, ``inf`` where ``h_b = 1``).
    """
    c, remaining = _prepare(counts, n_cycles, axis, blind_cycles)
    with np.errstate(divide="ignore", invalid="ignore"):
        h = np.where(remaining > 0, c / remaining, 0.0)
        var = np.where(remaining > 0, h / ((1.0 - h) * remaining), 0.0)
    return np.moveaxis(np.sqrt(var), -1, axis)
