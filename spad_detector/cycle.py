"""The laser cycle as a set of time slots.

A TCSPC channel measures time modulo the laser period ``P``. The histogram
window ``[t0, t0 + n_bins * bin_width)`` covers part of the period; the rest
(``[t0 + n_bins * bin_width, t0 + P)``, where only dark counts and ambient
light arrive and which the histogram does not record) still matters, because
avalanches there make the SPAD and the TCSPC dead. Both engines therefore work
on *slots*: the ``n_bins`` histogram bins followed by up to
:data:`MAX_REMAINDER_SLOTS` equal slots covering the remainder of the period.
Within a slot, photons arrive uniformly in time (piecewise-constant intensity).

Slot phases are measured from ``t0`` (phase 0 = start of bin 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from transient_core.errors import UserInputError

#: Most slots used to resolve the part of the period outside the histogram window.
MAX_REMAINDER_SLOTS = 256


@dataclass(frozen=True)
class CycleGrid:
    """Slots of one laser cycle.

    Attributes
    ----------
    t0_ps, bin_width_ps, n_bins
        The histogram's time axis.
    period_ps : float
        Laser period.
    edges : ndarray, shape (n_slots + 1,)
        Slot boundaries as phases from ``t0`` (ps); ``edges[0] = 0``,
        ``edges[n_bins] = n_bins * bin_width_ps``, ``edges[-1] = period_ps``.
    """

    t0_ps: float
    bin_width_ps: float
    n_bins: int
    period_ps: float
    edges: np.ndarray

    @property
    def n_slots(self) -> int:
        return len(self.edges) - 1

    @property
    def widths(self) -> np.ndarray:
        return np.diff(self.edges)

    @property
    def centres(self) -> np.ndarray:
        return 0.5 * (self.edges[:-1] + self.edges[1:])

    @property
    def window_ps(self) -> float:
        return self.n_bins * self.bin_width_ps

    def absolute_edges(self) -> np.ndarray:
        """Slot boundaries on the capture's time axis (``t0_ps + edges``), ps."""
        return self.t0_ps + self.edges


def make_cycle_grid(t0_ps: float, bin_width_ps: float, n_bins: int, period_ps: float,
                    max_remainder_slots: int = MAX_REMAINDER_SLOTS) -> CycleGrid:
    """Slots for a histogram window inside one laser period.

    Raises
    ------
    UserInputError
        If the window is longer than the laser period (light of one pulse
        would be recorded in the next cycle's histogram).
    """
    window = n_bins * bin_width_ps
    if not (math.isfinite(period_ps) and period_ps > 0):
        raise UserInputError(f"laser period {period_ps!r} ps must be > 0")
    if window > period_ps * (1 + 1e-12):
        raise UserInputError(
            f"histogram window n_bins x bin_width_ps = {n_bins} x {bin_width_ps:g} = {window:g} ps is longer "
            f"than the laser period 1/repetition_rate = {period_ps:g} ps: light from one pulse would land in the "
            "next cycle; lower repetition_rate_hz or render a shorter window")
    edges = [np.arange(n_bins + 1, dtype=np.float64) * bin_width_ps]
    rest = period_ps - window
    if rest > 1e-9 * period_ps:
        n_rem = int(min(max_remainder_slots, max(1, math.ceil(rest / bin_width_ps - 1e-9))))
        edges.append(window + rest * np.arange(1, n_rem + 1, dtype=np.float64) / n_rem)
    e = np.concatenate(edges)
    e[-1] = period_ps  # exact end of the cycle (the window may fill it up to rounding)
    return CycleGrid(float(t0_ps), float(bin_width_ps), int(n_bins), float(period_ps), e)
