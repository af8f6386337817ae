"""Detection engines: ``analytic`` (fast, per-cycle probabilities + one draw) and ``exact`` (event Monte Carlo).

Both take a :class:`~spad_detector.model.DetectorModel`, the ideal
photons per pulse ``[n_pix, n_bins]`` of one spot, the number of pulses and
a numpy Generator, and return ``(counts[n_pix, n_bins] int64, info)``.
"""

from .analytic import is_exact, run_analytic
from .exact import estimated_events, run_exact

__all__ = ["run_analytic", "run_exact", "is_exact", "estimated_events"]
