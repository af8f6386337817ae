"""Timing jitter and instrument response (IRF).

Convention
----------
``jitter_ps`` is the *timing resolution* as TCSPC datasheets and the
reference paper quote it: the **FWHM** of a Gaussian. Its standard deviation
is ``sigma = jitter_ps / (2 sqrt(2 ln 2)) = jitter_ps / 2.3548`` (25 ps FWHM
-> 10.62 ps sigma).

Model
-----
Each recorded avalanche gets a random delay ``J`` added to its time stamp
(after the dead-time logic, which runs on true arrival times)::

    J = sigma * Z + B * tau * E,   Z ~ N(0, 1), B ~ Bernoulli(irf_tail_fraction), E ~ Exp(1)

i.e. a Gaussian plus, for a fraction of the detections, an exponential
diffusion tail of time constant ``irf_tail_ps`` (the usual shape of a SPAD's
measured IRF: a peak and a slow tail). Alternatively ``irf_file`` gives a
*measured* IRF as two columns ``time_ps, weight`` on a uniform time grid
(delay relative to the true arrival; weights >= 0, normalised here); it is
used as a histogram: density ``weight_i / dt`` on ``[t_i - dt/2, t_i + dt/2)``.
A measured IRF sampled more coarsely than the capture's bins cannot be
represented at that resolution and is refused.

Time stamps pushed outside the histogram window by the jitter are lost (the
TCSPC still converted them, so they still cost dead time).

On histograms the jitter acts as a convolution with the bin kernel
``k[s] = P(an avalanche uniform in bin b is stamped in bin b + s)``
(:meth:`Jitter.bin_kernel`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.special import log_ndtr, ndtr

from transient_core.errors import UserInputError

from .params import FWHM_PER_SIGMA, DetectorParams

_SQRT2PI = math.sqrt(2.0 * math.pi)


def load_irf(path) -> tuple[np.ndarray, np.ndarray]:
    """Read a measured IRF: ``(time_ps[n], weight[n])`` from ``.npy`` ([n, 2]) or text (2 columns).

    Raises
    ------
    UserInputError
        Unreadable file, wrong shape, non-uniform or non-increasing times,
        negative/non-finite weights, or zero total weight.
    """
    p = Path(path)
    try:
        arr = np.load(p) if p.suffix == ".npy" else np.loadtxt(p, delimiter=None if p.suffix != ".csv" else ",",
                                                               ndmin=2)
    except Exception as e:  # noqa: BLE001 - any parse failure is a user error
        raise UserInputError(f"irf_file={str(p)!r}: cannot read it as a two-column table ({e})") from None
    arr = np.asarray(arr, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 2 or arr.shape[0] < 2:
        raise UserInputError(f"irf_file={str(p)!r}: expected two columns (time_ps, weight) and >= 2 rows, "
                             f"got shape {arr.shape}")
    t, w = arr[:, 0], arr[:, 1]
    if not (np.all(np.isfinite(arr)) and np.all(w >= 0) and w.sum() > 0):
        raise UserInputError(f"irf_file={str(p)!r}: weights must be finite, >= 0 and not all zero")
    dt = np.diff(t)
    if not np.all(dt > 0) or not np.allclose(dt, dt[0], rtol=1e-6, atol=0):
        raise UserInputError(f"irf_file={str(p)!r}: times must increase on a uniform grid")
    return t, w / w.sum()


@dataclass(frozen=True)
class Jitter:
    """The time-stamp delay distribution.

    Attributes
    ----------
    sigma_ps : float
        Gaussian standard deviation (``jitter_ps / 2.3548``).
    tail_fraction, tail_ps : float
        Weight and time constant of the exponential tail.
    irf_t_ps, irf_w : ndarray or None
        Measured IRF (uniform grid, normalised weights); replaces the above.
    """

    sigma_ps: float = 0.0
    tail_fraction: float = 0.0
    tail_ps: float = 0.0
    irf_t_ps: np.ndarray | None = None
    irf_w: np.ndarray | None = None

    @classmethod
    def from_params(cls, params: DetectorParams) -> "Jitter":
        if params.irf_file is not None:
            t, w = load_irf(params.irf_file)
            return cls(irf_t_ps=t, irf_w=w)
        return cls(sigma_ps=params.jitter_ps / FWHM_PER_SIGMA,
                   tail_fraction=params.irf_tail_fraction, tail_ps=params.irf_tail_ps)

    @property
    def is_measured(self) -> bool:
        return self.irf_t_ps is not None

    @property
    def irf_step_ps(self) -> float:
        return float(self.irf_t_ps[1] - self.irf_t_ps[0]) if self.is_measured else 0.0

    @property
    def is_zero(self) -> bool:
        return not self.is_measured and self.sigma_ps == 0 and self.tail_fraction == 0

    def check_bin_width(self, bin_width_ps: float) -> None:
        """Refuse bins finer than a measured IRF's sampling step."""
        if self.is_measured and bin_width_ps < self.irf_step_ps * (1 - 1e-9):
            raise UserInputError(
                f"bin_width_ps={bin_width_ps:g} is finer than the measured IRF's sampling step "
                f"{self.irf_step_ps:g} ps (irf_file): the jitter model cannot represent the IRF at this "
                "resolution; resample the IRF to <= the bin width or use jitter_ps/irf_tail_ps instead")

    # ------------------------------------------------------------- sampling

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """``n`` independent delays, ps (float64)."""
        if self.is_measured:
            cdf = np.cumsum(self.irf_w)
            i = np.minimum(np.searchsorted(cdf, rng.random(n) * cdf[-1], side="right"), len(cdf) - 1)
            return self.irf_t_ps[i] + (rng.random(n) - 0.5) * self.irf_step_ps
        out = np.zeros(n)
        if self.sigma_ps > 0:
            out += self.sigma_ps * rng.standard_normal(n)
        if self.tail_fraction > 0:
            tail = rng.random(n) < self.tail_fraction
            out[tail] += rng.exponential(self.tail_ps, int(tail.sum()))
        return out

    # ------------------------------------------------------------------ CDF

    def cdf(self, x_ps) -> np.ndarray:
        """``P(J <= x)`` for delays ``x_ps``."""
        x = np.asarray(x_ps, dtype=np.float64)
        if self.is_measured:
            lo = self.irf_t_ps - 0.5 * self.irf_step_ps
            edges = np.append(lo, lo[-1] + self.irf_step_ps)
            cum = np.concatenate([[0.0], np.cumsum(self.irf_w)])
            return np.interp(x, edges, cum, left=0.0, right=1.0)
        s, f, tau = self.sigma_ps, self.tail_fraction, self.tail_ps
        gauss = ndtr(x / s) if s > 0 else (x >= 0).astype(np.float64)
        if f == 0:
            return gauss
        if s > 0:
            # exponentially modified Gaussian, in log space to avoid overflow
            with np.errstate(over="ignore"):
                corr = np.exp(-x / tau + 0.5 * (s / tau) ** 2 + log_ndtr(x / s - s / tau))
            emg = gauss - corr
        else:
            emg = np.where(x >= 0, -np.expm1(-np.maximum(x, 0) / tau), 0.0)
        return (1 - f) * gauss + f * emg

    def support_ps(self) -> tuple[float, float]:
        """An interval holding all but ~1e-15 of the delay distribution."""
        if self.is_measured:
            return (float(self.irf_t_ps[0] - self.irf_step_ps), float(self.irf_t_ps[-1] + self.irf_step_ps))
        lo = -8.3 * self.sigma_ps
        hi = 8.3 * self.sigma_ps + (35.0 * self.tail_ps if self.tail_fraction > 0 else 0.0)
        return lo, hi

    # --------------------------------------------------------------- kernel

    def bin_kernel(self, bin_width_ps: float, max_shift_bins: int | None = None) -> tuple[int, np.ndarray]:
        """Histogram kernel of the jitter.

        Returns
        -------
        first : int
            Shift (in bins) of ``kernel[0]``.
        kernel : ndarray
            ``kernel[i] = P(shift = first + i bins)`` for an avalanche uniform
            within its bin; sums to 1 (up to ~1e-15 of tail outside).
        """
        w = float(bin_width_ps)
        self.check_bin_width(w)
        if self.is_zero:
            return 0, np.ones(1)
        lo, hi = self.support_ps()
        first = int(math.floor(lo / w)) - 1
        last = int(math.ceil(hi / w)) + 1
        if max_shift_bins is not None:
            first, last = max(first, -max_shift_bins - 1), min(last, max_shift_bins + 1)
        shifts = np.arange(first, last + 1, dtype=np.float64)
        if not self.is_measured and self.tail_fraction == 0:
            # exact: second difference of the antiderivative of Phi
            s = self.sigma_ps / w

            def A(y):
                z = y / s
                return s * (z * ndtr(z) + np.exp(-0.5 * z * z) / _SQRT2PI)

            k = A(shifts + 1) - 2 * A(shifts) + A(shifts - 1)
        else:
            # average over the avalanche's position u in its bin (midpoint rule)
            scale = min([v for v in (self.sigma_ps, self.tail_ps if self.tail_fraction > 0 else 0,
                                     self.irf_step_ps) if v > 0] or [w])
            n_u = int(min(4096, max(64, math.ceil(64 * w / scale))))
            u = (np.arange(n_u) + 0.5) / n_u
            k = np.zeros(len(shifts))
            for chunk in np.array_split(u, max(1, n_u // 256)):
                x_hi = (shifts[:, None] + 1 - chunk[None]) * w
                x_lo = (shifts[:, None] - chunk[None]) * w
                k += (self.cdf(x_hi) - self.cdf(x_lo)).sum(1)
            k /= n_u
        k = np.clip(k, 0.0, None)
        nz = np.nonzero(k > 1e-300)[0]
        if len(nz) == 0:
            return 0, np.zeros(1)
        # not renormalised: mass beyond max_shift_bins leaves the window anyway (lost)
        return first + int(nz[0]), k[nz[0]:nz[-1] + 1]
