"""What a study returns: its table rows and where it wrote them."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path


@dataclass(frozen=True)
class StudyResult:
    """The outcome of a study.

    Attributes
    ----------
    study : str
        ``"photon_budget"`` or ``"array_size"``.
    out_dir : Path
        The output directory.
    rows : list of dict
        One row per run (the content of ``results.csv``; deterministic for a
        given seed).
    timings : list of dict
        Wall-clock seconds per run (``timings.csv``; the key columns of
        ``rows`` plus ``*_s`` columns).
    tables : dict of str -> Path
        ``results_csv``, ``results_json``, ``timings_csv``, ``timings_json``
        and study-specific tables (``snr_bins_csv``, ``snr_pixels_csv``).
    figures : dict of str -> Path
        PNG figures by name.
    summary : Path
        ``summary.md``.
    snr_bins, snr_pixels : list of dict
        Photon-budget study only: the SNR tables (``snr_bins.csv``,
        ``snr_pixels.csv``, see :mod:`transient_mi.study.snr`).
    aggregate : list of dict
        Means and standard deviations over the detection seeds (photon-budget
        study) or the rows again (array-size study).
    """

    study: str
    out_dir: Path
    rows: list
    timings: list
    tables: dict
    figures: dict
    summary: Path
    snr_bins: list = field(default_factory=list)
    snr_pixels: list = field(default_factory=list)
    aggregate: list = field(default_factory=list)
