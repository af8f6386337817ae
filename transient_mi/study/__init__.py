"""Studies on one scene: how reconstruction quality and noise depend on the photon budget and the array size.

Public API
----------
run_photon_budget_study   one render, detection over photon budgets x dark counts x dead times x seeds,
                          reconstruction error and SNR against detected photons (:mod:`.photon_budget`)
run_array_size_study      render + detect + reconstruct per SPAD array size, error and time (:mod:`.array_size`)
run_methods_study         leaderboard: every method x array size x photon budget (:mod:`.methods`)
StudyResult               what both return: table rows, output paths, figure paths

Both write an output directory atomically (built under a temporary sibling
name, renamed when complete): ``results.csv``/``results.json`` (byte-identical
for the same arguments), ``timings.csv``/``timings.json`` (run times, kept
apart), figures and ``summary.md``. See ``docs/studies.md``.
"""

from .array_size import DEFAULT_ARRAYS, run_array_size_study
from .methods import run_methods_study
from .photon_budget import (DEFAULT_DARK_COUNT_RATES_CPS, DEFAULT_DEAD_TIMES_NS, DEFAULT_EXPOSURES_S,
                            run_photon_budget_study)
from .study_result import StudyResult

__all__ = ["run_photon_budget_study", "run_array_size_study", "run_methods_study", "StudyResult", "DEFAULT_EXPOSURES_S",
           "DEFAULT_DARK_COUNT_RATES_CPS", "DEFAULT_DEAD_TIMES_NS", "DEFAULT_ARRAYS"]
