"""The time axis of a transient film: bins, the binning rule, the temporal kernel.

Pure numpy (no Mitsuba): the integrators implement the same arithmetic in
drjit, and tests compare against these reference functions.

Conventions
-----------
Time zero is the moment light leaves the emitter (the laser pulse leaving the
laser). A contribution whose optical path length (OPL) is ``opl_m`` metres
arrives at ``t_ps = opl_m / C_M_PER_PS``. Bin ``b`` is the half-open interval
``[t0_ps + b * bin_width_ps, t0_ps + (b + 1) * bin_width_ps)``: an arrival
exactly on the boundary between bins ``b - 1`` and ``b`` is recorded in bin
``b``. The index is computed in float64 as
``floor((opl_m / C_M_PER_PS - t0_ps) / bin_width_ps)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr

from transient_core.units import C_M_PER_PS

#: Half-width of the truncated Gaussian kernel, in standard deviations.
KERNEL_HALF_WIDTH_SIGMA = 5.0


@dataclass(frozen=True)
class TimeAxis:
    """Time bins of a transient film.

    Attributes
    ----------
    t0_ps : float
        Start of bin 0, ps.
    bin_width_ps : float
        Width of every bin, ps (> 0).
    n_bins : int
        Number of bins (>= 1).
    """

    t0_ps: float
    bin_width_ps: float
    n_bins: int

    @property
    def t_end_ps(self) -> float:
        """End of the last bin, ps."""
        return self.t0_ps + self.n_bins * self.bin_width_ps

    def edges_ps(self) -> np.ndarray:
        """Bin edges, ps, shape ``(n_bins + 1,)``."""
        return self.t0_ps + self.bin_width_ps * np.arange(self.n_bins + 1, dtype=np.float64)

    def centers_ps(self) -> np.ndarray:
        """Bin centres, ps, shape ``(n_bins,)``."""
        return self.t0_ps + self.bin_width_ps * (np.arange(self.n_bins, dtype=np.float64) + 0.5)

    def bin_index(self, opl_m) -> np.ndarray:
        """Bin index (int64) of arrivals with optical path ``opl_m`` metres.

        Indices outside ``[0, n_bins)`` mean the arrival is outside the film's
        time range (such contributions are dropped and counted).
        """
        t = np.asarray(opl_m, dtype=np.float64) / C_M_PER_PS
        return np.floor((t - self.t0_ps) / self.bin_width_ps).astype(np.int64)


def gaussian_kernel_taps(sigma_ps: float, bin_width_ps: float) -> np.ndarray:
    """Discrete temporal kernel for a Gaussian of standard deviation ``sigma_ps``.

    Tap ``m`` (``m = -pad .. pad``) is the Gaussian's integral over the bin
    ``m`` bins away from a contribution at a bin centre:
    ``w_m = Phi((m + 1/2) / s) - Phi((m - 1/2) / s)`` with
    ``s = sigma_ps / bin_width_ps`` (the usual discretisation of an
    instrument response). Taps are truncated at ``KERNEL_HALF_WIDTH_SIGMA``
    standard deviations plus one bin and renormalised to sum to exactly 1,
    so the kernel conserves energy. Convolving a histogram with them adds
    ``sum_m w_m (m bin_width_ps)^2`` (= ``sigma_ps^2 + bin_width_ps^2 / 12``
    for ``s >~ 1``) to the variance of the arrival times; blurring every
    contribution exactly would add ``sigma_ps^2``: the difference is
    negligible when bins are much finer than ``sigma_ps``.

    Returns
    -------
    ndarray of float64, shape ``(2 * pad + 1,)``
    """
    if not sigma_ps > 0:
        return np.ones(1)
    s = sigma_ps / bin_width_ps
    pad = int(math.ceil(KERNEL_HALF_WIDTH_SIGMA * s)) + 1
    m = np.arange(-pad, pad + 1, dtype=np.float64)
    w = ndtr((m + 0.5) / s) - ndtr((m - 0.5) / s)
    w = np.clip(w, 0.0, None)
    return w / w.sum()


def apply_kernel(hist_ext: np.ndarray, taps: np.ndarray) -> np.ndarray:
    """Convolve histograms along their last axis with centred ``taps``.

    ``hist_ext`` has ``pad = len(taps) // 2`` extra bins on each side of the
    film's range; the result has those removed: shape ``(..., T_ext - 2 pad)``.
    """
    pad = len(taps) // 2
    if pad == 0:
        return hist_ext
    from scipy.ndimage import convolve1d

    full = convolve1d(hist_ext.astype(np.float64, copy=False), taps, axis=-1, mode="constant", cval=0.0)
    return full[..., pad: hist_ext.shape[-1] - pad]
