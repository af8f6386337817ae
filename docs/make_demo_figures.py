"""Draw the demo figures of the README: run ``transient-mi demo`` and copy its figures to docs/img/.

Usage::

    python docs/make_demo_figures.py [--out-dir DIR]

Runs the full demo (every array rendered to a noise target of 0.1 at the paper's budget; a few minutes
on 2 cores) into ``--out-dir`` (default: a temporary directory) and copies ``fig4_histograms.png`` and
``fig5_reconstructions.png`` to ``docs/img/demo_fig4_histograms.png`` and
``docs/img/demo_fig5_reconstructions.png``. Seeded: the same figures every time.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

COPIES = {"fig4_histograms.png": "demo_fig4_histograms.png",
          "fig5_reconstructions.png": "demo_fig5_reconstructions.png"}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out-dir", type=Path, default=None)
    a = ap.parse_args(argv)
    import transient_mi  # noqa: F401  (sets up LLVM before drjit loads)
    from transient_mi.demo import run_demo

    with tempfile.TemporaryDirectory() as td:
        out = (a.out_dir or Path(td)) / "demo"
        run_demo(out, overwrite=True, progress=False)
        for src, dst in COPIES.items():
            shutil.copyfile(out / src, ROOT / "docs" / "img" / dst)
            print(f"docs/img/{dst}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
