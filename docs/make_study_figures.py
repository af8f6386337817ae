"""Draw the figures of docs/studies.md: run both studies with ``--quick`` and copy their PNGs to docs/img/.

Usage::

    python docs/make_study_figures.py [--out-dir DIR]

Runs ``transient-mi study photon-budget --quick`` and ``transient-mi study
array-size --quick`` (about a minute and a half on 2 cores), keeps their
output directories under ``--out-dir`` (default: a temporary directory) and
copies ``docs/img/study_*.png``. Seeded: the same figures every time (up to
the timing panel).
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

COPIES = {
    ("photon_budget", "error_vs_photons"): "study_error_vs_photons.png",
    ("photon_budget", "snr_vs_photons"): "study_snr_vs_photons.png",
    ("photon_budget", "reconstructions"): "study_photon_budget_reconstructions.png",
    ("array_size", "array_size"): "study_array_size.png",
    ("array_size", "reconstructions"): "study_array_size_reconstructions.png",
}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out-dir", type=Path, default=None, help="keep the study outputs here")
    a = ap.parse_args(argv)
    import transient_mi  # noqa: F401
    from transient_mi.study import run_array_size_study, run_photon_budget_study

    with tempfile.TemporaryDirectory(prefix="study-figures-") as td:
        base = a.out_dir or Path(td)
        results = {
            "photon_budget": run_photon_budget_study("paper_mannequin", base / "photon_budget", quick=True,
                                                     overwrite=True, log=print),
            "array_size": run_array_size_study("paper_mannequin", base / "array_size", quick=True, overwrite=True,
                                               log=print),
        }
        img = ROOT / "docs" / "img"
        for (study, fig), name in COPIES.items():
            shutil.copyfile(results[study].figures[fig], img / name)
            print(f"wrote {img / name}")
        for r in results.values():
            print(r.summary.read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
