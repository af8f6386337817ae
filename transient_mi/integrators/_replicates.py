r"""Independent replicates: how noisy every ideal capture is, per time bin.

Every render is split into ``R`` *replicates*: independent estimators with
``spp / R`` samples each, each with its own random streams (and, for the NLOS
estimator's randomised QMC, its own random shift of the low-discrepancy
sequence). The capture stores their mean, which is the usual unbiased
estimate, and

.. math::

    \widehat{\mathrm{Var}}[\bar h_b] = \frac{1}{R (R - 1)} \sum_{r=1}^{R} (h_{r,b} - \bar h_b)^2 ,

the sample variance of the replicate means divided by ``R``: an unbiased
estimate of the variance of the stored value in every bin ``b`` (unbiased for
any estimator whose replicates are independent and identically distributed,
randomised QMC included, since each replicate has its own uniform random
shift). It has ``R - 1`` degrees of freedom: a single bin's estimate is
rough (relative standard deviation ``sqrt(2 / (R - 1))`` for Gaussian
replicates), sums over many bins are precise. The variance of each pixel's
time-integrated total is estimated the same way from the replicates' totals
(exact: it includes the covariance between bins).

The temporal kernel of the film (``kernel_sigma_ps``) is applied to every
replicate before the variance is taken, so the stored variance is that of the
stored (smoothed) values.

Replicates are accumulated with Welford's update in float32; batches
rendered later (``render --noise-target``) are merged with Chan's formula,
so a capture can grow replicate by replicate.

``R`` is the integrator parameter ``variance_replicates`` (default 1 for
direct renders, which stay byte-identical to a single estimator and as fast;
``transient-mi render`` and what is built on it use :data:`DEFAULT_REPLICATES`
for NLOS captures; collecting a large camera film once per replicate costs
several times the render); a render whose ``spp`` is not a multiple of it
uses ``gcd(spp, R)`` replicates (the manifest says how many); ``R = 1``
records no variance and reproduces the single-estimator render of earlier
versions byte for byte.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Replicates per render unless the integrator says otherwise.
DEFAULT_REPLICATES = 8


def effective_replicates(spp: int, requested: int) -> int:
    """Replicates actually used: ``gcd(spp, requested)`` (equal-sized replicates, >= 1)."""
    return max(1, math.gcd(int(spp), int(requested)))


def replicate_seed(seed: int, replicate: int, n_replicates: int) -> int:
    """Seed of replicate ``replicate``: ``seed`` itself for a single-replicate render, else a hash of both."""
    if n_replicates == 1 and replicate == 0:
        return int(seed)
    ss = np.random.SeedSequence([int(seed), int(replicate), 0x7E91])
    return int(ss.generate_state(1, dtype=np.uint32)[0])


@dataclass
class ReplicateStats:
    """Mean and spread of ``n`` replicate histograms (one laser spot or camera view).

    Attributes
    ----------
    n : int
        Replicates accumulated.
    mean : ndarray of float32, shape ``(n_pixels, n_bins)`` or ``(n_pixels, n_bins, n_channels)``
        Mean of the replicates (the capture's values). The first replicate's
        array is used in place, not copied (a large camera film is not held
        twice).
    m2 : ndarray of float32, same shape, or None
        Sum of squared deviations from the mean (None while ``n < 2``:
        allocated by the second replicate).
    total_mean, total_m2 : ndarray of float64, shape ``(n_pixels,)`` (or ``(n_pixels, n_channels)``)
        The same for each pixel's time-integrated (in-range) total (summed over axis 1, time).
    """

    n: int
    mean: np.ndarray
    m2: np.ndarray | None
    total_mean: np.ndarray
    total_m2: np.ndarray

    @classmethod
    def first(cls, hist: np.ndarray) -> "ReplicateStats":
        h = np.asarray(hist, dtype=np.float32)
        tot = h.sum(axis=1, dtype=np.float64)
        return cls(1, h, None, tot, np.zeros_like(tot))

    def add(self, hist: np.ndarray) -> None:
        """Welford's update with one more replicate (in place)."""
        h = np.asarray(hist, dtype=np.float32)
        if self.m2 is None:
            self.m2 = np.zeros_like(self.mean)
        self.n += 1
        delta = h - self.mean
        self.mean += delta / np.float32(self.n)
        delta *= h - self.mean
        self.m2 += delta
        tot = h.sum(axis=1, dtype=np.float64)
        d = tot - self.total_mean
        self.total_mean += d / self.n
        self.total_m2 += d * (tot - self.total_mean)

    def merge(self, other: "ReplicateStats") -> "ReplicateStats":
        """Chan's parallel formula: the statistics of both sets of replicates (new object)."""
        n = self.n + other.n
        delta = other.mean - self.mean
        mean = self.mean + delta * np.float32(other.n / n)
        m2 = np.square(delta) * np.float32(self.n * other.n / n)
        for part in (self.m2, other.m2):
            if part is not None:
                m2 += part
        dt = other.total_mean - self.total_mean
        tmean = self.total_mean + dt * (other.n / n)
        tm2 = self.total_m2 + other.total_m2 + dt ** 2 * (self.n * other.n / n)
        return ReplicateStats(n, mean.astype(np.float32), m2.astype(np.float32), tmean, tm2)

    def variance(self) -> np.ndarray | None:
        """Estimated variance of :attr:`mean` per bin (float32), None with fewer than 2 replicates."""
        if self.n < 2:
            return None
        return (np.maximum(self.m2, 0.0) * np.float32(1.0 / (self.n * (self.n - 1)))).astype(np.float32)

    def total_variance(self) -> np.ndarray | None:
        """Estimated variance of each pixel's time-integrated total (float64), None with < 2 replicates."""
        if self.n < 2:
            return None
        return np.maximum(self.total_m2, 0.0) / (self.n * (self.n - 1))

    @classmethod
    def from_result(cls, result) -> "ReplicateStats":
        """Rebuild the statistics of a :class:`TransientResult` (to merge a later batch into it)."""
        n = int(result.replicates)
        h = np.asarray(result.histogram, dtype=np.float32)
        # [H, W, T] -> [P, T]; [H, W, T, C] -> [P, T, C]
        mean = h.reshape((-1,) + h.shape[2:]).copy()
        tot = mean.sum(axis=1, dtype=np.float64)
        if n >= 2 and result.variance is not None:
            m2 = np.asarray(result.variance, dtype=np.float32).reshape(mean.shape) * np.float32(n * (n - 1))
            tm2 = np.asarray(result.total_variance, dtype=np.float64).reshape(tot.shape) * (n * (n - 1))
        else:
            m2 = None
            tm2 = np.zeros_like(tot)
        return cls(n, mean, m2, tot, tm2)
