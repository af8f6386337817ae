"""Pile-up correction for TCSPC histograms (Coates' estimator).

A TCSPC channel records at most the first photon of each laser cycle, so
late bins are under-counted when the flux is high ("pile-up"). With ``N``
cycles and ``n_b`` counts in bin ``b``, the number of cycles still able to
detect in bin ``b`` is ``N - sum_{i<b} n_i``. Coates (1968) estimates the
per-cycle probability of a detection in bin ``b`` as
``p_b = n_b / (N - sum_{i<b} n_i)`` and the mean number of detectable photons
per cycle in that bin as ``lambda_b = -ln(1 - p_b)``, which undoes the
pile-up exactly in expectation for a Poisson source whose first photon in a
cycle is detected (dead time longer than the rest of the cycle, shorter than
one cycle).

Reference: P. B. Coates, "The correction for photon 'pile-up' in the
measurement of radiative lifetimes", J. Phys. E 1, 878 (1968).
"""

from __future__ import annotations

import numpy as np

from .errors import UserInputError


def coates_correction(counts: np.ndarray, n_cycles, axis: int = -1) -> np.ndarray:
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

    Returns
    -------
    ndarray of float64, same shape as ``counts``
        ``lambda_b``: mean detectable photons per cycle in each bin (after
        detection efficiency and gating, i.e. what a dead-time-free detector
        would count per cycle). Multiply by ``n_cycles`` for corrected counts.
        Bins where every remaining cycle fired give ``inf``.
    """
    c = np.asarray(counts, dtype=np.float64)
    if c.size and (not np.all(np.isfinite(c)) or c.min() < 0):
        raise UserInputError("counts must be finite and >= 0 for the Coates correction")
    c = np.moveaxis(c, axis, -1)
    n = np.asarray(n_cycles, dtype=np.float64)
    if np.any(~(n > 0)):
        raise UserInputError(f"n_cycles={n_cycles!r} must be > 0")
    n = n[..., None] if n.ndim else n
    before = np.cumsum(c, axis=-1) - c  # counts in earlier bins
    remaining = n - before
    if np.any(remaining < c - 1e-9):
        raise UserInputError("counts exceed n_cycles: more detections than laser cycles")
    with np.errstate(divide="ignore", invalid="ignore"):
        p = np.where(remaining > 0, c / remaining, 0.0)
        lam = -np.log1p(-np.clip(p, 0.0, 1.0))
    return np.moveaxis(lam, -1, axis)
