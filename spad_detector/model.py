"""From an ideal histogram to the per-slot avalanche intensity both engines sample.

In the order light meets the detector (see ``docs/detector.md``): photons per
pulse (already scaled by the photon budget) x PDE x gate, plus dark counts and
ambient light x gate, on the slots of one laser cycle (:mod:`.cycle`). Dead
time, TCSPC, afterpulsing, crosstalk and jitter are applied by the engines.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from transient_core.errors import UserInputError

from .cycle import CycleGrid, make_cycle_grid
from .gate import gate_mean, gate_sigma_ps
from .jitter import Jitter
from .noise import background_per_slot
from .params import DEFAULT_REPETITION_RATE_HZ, DetectorParams


@dataclass
class DetectorModel:
    """Everything the engines need, for one time axis (shared by the spots of a capture).

    Attributes
    ----------
    grid : CycleGrid
    gate_slots : ndarray, shape (n_slots,)
        Mean gate efficiency per slot.
    background : ndarray, shape (n_slots,)
        Dark + ambient triggering events per cycle per slot.
    jitter : Jitter
    kernel_first, kernel : int, ndarray
        Histogram kernel of the jitter (:meth:`Jitter.bin_kernel`).
    """

    params: DetectorParams
    grid: CycleGrid
    gate_slots: np.ndarray
    background: np.ndarray
    jitter: Jitter
    kernel_first: int
    kernel: np.ndarray

    @property
    def spad_dead_time_ps(self) -> float:
        return self.params.dead_time_ns * 1e3

    @property
    def tcspc_dead_time_ps(self) -> float:
        return self.params.tcspc_dead_time_ns * 1e3

    @property
    def paralyzable(self) -> bool:
        return self.params.dead_time_model == "paralyzable"

    @property
    def gate_sigma_ps(self) -> float:
        return gate_sigma_ps(self.params.gate_transition_ps)

    def intensity(self, ideal: np.ndarray) -> np.ndarray:
        """Triggering events per cycle per slot, shape (n_pix, n_slots), from ideal photons (n_pix, n_bins)."""
        T = self.grid.n_bins
        lam = np.empty((ideal.shape[0], self.grid.n_slots))
        lam[:, :T] = self.params.pde * self.gate_slots[None, :T] * ideal
        lam[:, :T] += self.background[None, :T]
        lam[:, T:] = self.background[None, T:]
        return lam


def build_model(params: DetectorParams, *, bin_width_ps: float, n_bins: int, t0_ps: float = 0.0,
                repetition_rate_hz: float | None = None) -> DetectorModel:
    """Validate the parameters against the time axis and precompute gate, background and jitter kernel.

    ``params`` must have explicit gate times if any (resolve ``auto_gate``
    first, see :func:`~spad_detector.gate.auto_gate`).
    """
    params.validate()
    if params.auto_gate:
        raise UserInputError("auto_gate needs the capture geometry: use detect_stack on a capture, or give "
                             "gate_open_ps and gate_close_ps")
    if not (isinstance(bin_width_ps, (int, float)) and np.isfinite(bin_width_ps) and bin_width_ps > 0):
        raise UserInputError(f"bin_width_ps={bin_width_ps!r}: must be a finite number > 0")
    if not (isinstance(t0_ps, (int, float)) and np.isfinite(t0_ps)):
        raise UserInputError(f"t0_ps={t0_ps!r}: must be a finite number")
    rate = repetition_rate_hz or params.repetition_rate_hz or DEFAULT_REPETITION_RATE_HZ
    period = 1e12 / rate
    grid = make_cycle_grid(t0_ps, bin_width_ps, n_bins, period)
    if params.gate_open_ps is not None and params.gate_close_ps - params.gate_open_ps > period:
        raise UserInputError(
            f"gate_close_ps - gate_open_ps = {params.gate_close_ps - params.gate_open_ps:g} ps is longer than "
            f"the laser period {period:g} ps: a gate cannot stay open for more than one cycle")
    g = gate_mean(grid.absolute_edges(), params.gate_open_ps, params.gate_close_ps,
                  params.gate_transition_ps, period)
    jitter = Jitter.from_params(params)
    first, kernel = jitter.bin_kernel(bin_width_ps, max_shift_bins=n_bins)
    bg = background_per_slot(params, grid, g)
    return DetectorModel(params=params, grid=grid, gate_slots=g, background=bg, jitter=jitter,
                         kernel_first=first, kernel=kernel)


def apply_jitter_kernel(x: np.ndarray, first: int, kernel: np.ndarray) -> np.ndarray:
    """Convolve per-bin probabilities ``x[..., T]`` with the jitter kernel; mass leaving the window is dropped.

    Output bin ``b`` receives ``sum_j x[b - first - j] kernel[j]`` (kernel
    index ``j`` is a shift of ``first + j`` bins). Short kernels are applied
    directly, long ones by FFT (negative round-off is clipped to 0).
    """
    T = x.shape[-1]
    if len(kernel) == 1 and first == 0:
        return x * kernel[0]
    K = len(kernel)
    out = np.zeros_like(x)
    if K <= 16:
        for j, kj in enumerate(kernel):
            s = first + j  # shift in bins
            if s >= 0 and s < T:
                out[..., s:] += kj * x[..., :T - s]
            elif s < 0 and -s < T:
                out[..., :T + s] += kj * x[..., -s:]
        return out
    n = T + K - 1
    nfft = 1 << (n - 1).bit_length()
    full = np.fft.irfft(np.fft.rfft(x, nfft, axis=-1) * np.fft.rfft(kernel, nfft), nfft, axis=-1)[..., :n]
    # full[..., i] = sum_j x[..., i - j] kernel[j], so out[..., b] = full[..., b - first]
    src_lo = max(0, -first)
    dst_lo = max(0, first)
    m = min(T - dst_lo, n - src_lo)
    if m > 0:
        out[..., dst_lo:dst_lo + m] = full[..., src_lo:src_lo + m]
    return np.clip(out, 0.0, None)
