"""Preprocessing of captures: first/last segment removal, pile-up correction, time crop and downsampling.

Every function returns a new :class:`~recon.capture.Capture` whose files are
transformed lazily, one laser spot at a time, so memory stays bounded.
"""

from __future__ import annotations

import math

import numpy as np

from .capture import Capture, PULSE_KEYS
from transient_core.errors import UserInputError
from transient_core.units import C_M_PER_PS

__all__ = ["remove_first_last", "resample_time_axis", "pileup_correction", "crop_time", "downsample_time"]


def _shift(hist: np.ndarray, shift_bins: np.ndarray, n_out: int) -> np.ndarray:
    from . import _kernels

    H, W, T = hist.shape
    out = np.zeros((H * W, n_out), dtype=np.float32)
    _kernels.shift_rows(np.ascontiguousarray(hist.reshape(H * W, T), dtype=np.float32),
                        np.ascontiguousarray(shift_bins.reshape(H * W), dtype=np.float64), out)
    return out.reshape(H, W, n_out)


def resample_time_axis(capture: Capture, t0_ps: float, n_bins: int | None = None,
                       remove_offsets: bool = True) -> Capture:
    """Move every histogram onto the time axis starting at ``t0_ps`` (same bin width).

    With ``remove_offsets`` (and a capture that includes them), histogram
    ``(j, k)`` is also moved earlier by its first + last segments
    ``|laser - S_j| + |P_k - detector|``, so the result holds three-bounce
    path lengths only (``include_first_last = False``). Shifts are exact
    integrals of the piecewise-constant histograms (fractional shifts split a
    bin between two neighbours), so photon totals are kept except for content
    moved outside the new axis.

    Parameters
    ----------
    capture : Capture
    t0_ps : float
        Start of the new bin 0, ps.
    n_bins : int, optional
        Bins of the new axis; default: enough to hold all shifted content.
    remove_offsets : bool
        Remove the first/last segments (if the capture includes them).

    Returns
    -------
    Capture
        Float32 data (``kind`` unchanged).
    """
    w = capture.bin_width_ps
    drop = remove_offsets and capture.include_first_last
    offs_ps = [capture.path_offsets_m(j) / C_M_PER_PS if drop else np.zeros((capture.height, capture.width))
               for j in range(capture.n_files)]
    # new index of old bin b: b + (t0_old - off - t0_new) / w
    shifts = [(capture.t0_ps - o - t0_ps) / w for o in offs_ps]
    if n_bins is None:
        # bin T-1 shifted by s ends in bin ceil(T - 1 + s) (or floor(T - 1 + s) for whole shifts)
        n_bins = int(math.ceil(max(float(s.max()) for s in shifts) + capture.n_bins - 1e-9))
    if n_bins < 1:
        raise UserInputError(f"the resampled time axis from {t0_ps:g} ps would hold no bin of this capture")

    def transform(j, h):
        return _shift(np.asarray(h, dtype=np.float32), shifts[j], n_bins)

    step = f"resample_time_axis(t0_ps={t0_ps:g}, n_bins={n_bins}{', remove first/last' if drop else ''})"
    return capture.derive(transform, step, t0_ps=float(t0_ps), n_bins=int(n_bins),
                          include_first_last=capture.include_first_last and not drop)


def remove_first_last(capture: Capture) -> Capture:
    """Remove the laser -> wall and wall -> detector segments from every histogram.

    Each histogram (j, k) moves earlier by ``|laser - S_j| + |P_k - detector|``
    (from the manifest geometry) onto a common axis starting at
    ``t0 - max(offset)``; a capture without them is returned unchanged.
    Backprojection does not need this (it removes them exactly per pair);
    LCT and f-k do.
    """
    if not capture.include_first_last:
        return capture
    off_max = max(float(capture.path_offsets_m(j).max()) for j in range(capture.n_files)) / C_M_PER_PS
    w = capture.bin_width_ps
    t0 = capture.t0_ps - math.ceil(off_max / w) * w
    return resample_time_axis(capture, t0, remove_offsets=True)


def blind_cycles_from_manifest(capture: Capture) -> tuple[int, str]:
    """Whole laser cycles the detector stays blind after a detection, from a counts manifest.

    Uses ``detector.resolved``: ``period_ps`` and the larger of
    ``spad_dead_time_ps`` / ``tcspc_dead_time_ps`` (``tau``), and the recorded
    window ``[a, b) = [t0, t_end)``. A dead time blinds exactly ``m`` whole
    cycles after any detection in the window when ``tau >= b - a`` and
    ``m P + b <= a + tau <= (m + 1) P + a - (b - a)``, i.e.
    ``m = floor((a + tau - b) / P)`` (the detector model's condition,
    ``spad_detector.pileup.blind_cycles``). ``m = 0`` is Coates'
    classic setting.

    Returns
    -------
    (m, note)
        ``m >= 0``; ``note`` says where it came from (and when it is only
        approximate: the dead time is not whole cycles for this window, or the
        manifest has no dead time).
    """
    res = ((capture.manifest.get("detector") or {}).get("resolved")) or {}
    P = res.get("period_ps")
    taus = [t for t in (res.get("spad_dead_time_ps"), res.get("tcspc_dead_time_ps")) if isinstance(t, (int, float))]
    if not isinstance(P, (int, float)) or not P > 0 or not taus:
        return 0, "no dead time in the manifest: Coates' setting (0 blind cycles) assumed"
    tau = float(max(taus))
    a, b = capture.t0_ps, capture.t_end_ps
    tol = 1e-9 * P
    m = math.floor((a + tau - b + tol) / P)
    if tau + tol >= b - a and m >= 0 and b + tau <= (m + 1) * P + a + tol:
        return int(m), f"{m} blind cycles (dead time {tau:g} ps, period {P:g} ps)"
    m = max(0, math.floor(tau / P))
    return m, (f"dead time {tau:g} ps is not whole periods of {P:g} ps for the window [{a:g}, {b:g}) ps: "
               f"{m} blind cycles used, the correction is approximate")


def pileup_correction(capture: Capture, n_cycles: float | None = None, blind_cycles: int | None = None) -> Capture:
    """Coates' pile-up correction of a counts capture (see :func:`spad_detector.coates.coates_correction`).

    Each histogram becomes ``n_cycles * lambda_b``: the counts a detector
    without dead time would have recorded. Bins in which every remaining
    cycle fired (``lambda = inf``) get the histogram's largest finite value.

    Parameters
    ----------
    capture : Capture
        ``kind = "counts"``.
    n_cycles : float, optional
        Laser pulses the histograms integrate; default from the manifest's
        ``detector`` section (``pulses``).
    blind_cycles : int, optional
        Whole cycles the detector is blind after each detection (dead time
        longer than the period); default :func:`blind_cycles_from_manifest`.
    """
    from spad_detector.coates import coates_correction

    if capture.kind != "counts":
        raise UserInputError(f"pile-up correction needs a counts capture; this one is kind={capture.kind!r}")
    n = capture.n_pulses() if n_cycles is None else float(n_cycles)
    if n is None:
        raise UserInputError(
            "pile-up correction needs the number of laser pulses: the manifest's detector section has none of "
            f"{', '.join(PULSE_KEYS)}; pass n_cycles")
    if not (math.isfinite(n) and n > 0):
        raise UserInputError(f"n_cycles={n_cycles!r} must be a positive number of laser pulses")
    if blind_cycles is None:
        m, note = blind_cycles_from_manifest(capture)
    else:
        if not isinstance(blind_cycles, (int, np.integer)) or isinstance(blind_cycles, bool) or blind_cycles < 0:
            raise UserInputError(f"blind_cycles={blind_cycles!r} must be a whole number >= 0")
        m, note = int(blind_cycles), f"{int(blind_cycles)} blind cycles (given)"

    def transform(j, h):
        lam = coates_correction(h, n, axis=-1, blind_cycles=m) * n
        if not np.all(np.isfinite(lam)):
            finite = np.where(np.isfinite(lam), lam, -np.inf)
            cap = np.max(finite, axis=-1, keepdims=True)
            lam = np.where(np.isfinite(lam), lam, np.maximum(cap, 0))
        return lam.astype(np.float32)

    return capture.derive(transform, f"pileup_correction(n_cycles={n:g}; {note})")


def crop_time(capture: Capture, t_min_ps: float | None = None, t_max_ps: float | None = None) -> Capture:
    """Keep the bins overlapping ``[t_min_ps, t_max_ps)``."""
    t0, w, T = capture.t0_ps, capture.bin_width_ps, capture.n_bins
    lo = 0 if t_min_ps is None else int(math.floor((float(t_min_ps) - t0) / w))
    hi = T if t_max_ps is None else int(math.ceil((float(t_max_ps) - t0) / w))
    lo, hi = max(lo, 0), min(hi, T)
    if hi <= lo:
        raise UserInputError(
            f"time crop [{t_min_ps}, {t_max_ps}) ps keeps no bin of the capture's axis [{t0:g}, {capture.t_end_ps:g}) ps")
    if (lo, hi) == (0, T):
        return capture
    return capture.derive(lambda j, h: h[..., lo:hi], f"crop_time({t_min_ps}, {t_max_ps})",
                          t0_ps=t0 + lo * w, n_bins=hi - lo)


def downsample_time(capture: Capture, factor: int) -> Capture:
    """Sum groups of ``factor`` consecutive bins (a trailing partial group is dropped)."""
    if not isinstance(factor, (int, np.integer)) or isinstance(factor, bool) or factor < 1:
        raise UserInputError(f"time downsampling factor={factor!r} must be a positive integer")
    if factor == 1:
        return capture
    T = capture.n_bins // factor
    if T < 1:
        raise UserInputError(f"time downsampling factor (--time-downsample) {factor} exceeds the {capture.n_bins} "
                             f"bins of the capture (allowed 1..{capture.n_bins})")

    def transform(j, h):
        H, W, _ = h.shape
        s = h[..., : T * factor].reshape(H, W, T, factor).sum(axis=-1, dtype=np.float64)
        if h.dtype.kind in "ui" and (s.size == 0 or s.max() < 2 ** 32):
            return s.astype(np.uint32)
        return s.astype(np.float32)

    return capture.derive(transform, f"downsample_time({factor})", bin_width_ps=capture.bin_width_ps * factor,
                          n_bins=T)
