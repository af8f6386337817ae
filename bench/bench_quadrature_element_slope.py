#!/usr/bin/env python3
"""What the element's slope buys: the quadrature's actual and stated error with and without it.

The quadrature weights each (element, cell) pair by its integrand at the element's centroid; since 2026-12-07 the
weight is also taken linear in arrival time over the element (``element_slope``, default true: the regression of
the weight at the three vertices on their arrival times; docs/quadrature.md). This renders two captures at several
settings, each with the slope and without (``element_slope=false``), one after the other in one process, and
records per row:

* ``actual_ratio``: the rendering-error ratio (``detect``'s headline: variance over photon variance, the largest
  over the spots) of the difference from a much finer reference level (rendered with the slope), taken as the
  error (the reference's own error is left in: its stated ratio is recorded);
* ``stated_ratio``: the ratio of the error estimate the capture states (all its parts), and each part's;
* the render time (kernels compiled by an untimed first render).

The captures (``--capture``, default both):

* ``letter``: ``scenes/nlos_letter.xml``, 8 x 8 pixels, the four spots on a diagonal of its 4 x 4, its 16 ps bins,
  the paper's detector defaults with ``--auto-gate`` at 10 ms per spot; reference 4 mm elements, 6 cells;
* ``paper``: the demo's 8 x 8 capture of the paper's mannequin (2 x 2 spots, 1 ps bins, the paper's detector) at
  1000 ms per spot, where the demo's noise target refines most; reference 10 mm elements, 2 cells, 3 visibility
  levels.

::

    python bench/bench_quadrature_element_slope.py --save
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _record  # noqa: E402

#: (element_size_m, patch_cells, refine_levels) per row, and the reference's, per capture.
CAPTURES = {
    "letter": {"rows": ((0.02, 6, 1), (0.014, 6, 1), (0.01, 6, 1), (0.02, 8, 1)), "reference": (0.004, 6, 1),
               "exposure_ms": 10.0},
    "paper": {"rows": ((0.04, 1, 1), (0.028, 1, 1), (0.02, 1, 2)), "reference": (0.01, 2, 3), "exposure_ms": 1000.0},
}
#: The letter's spots rendered (of its 4 x 4, row-major): the four on a diagonal.
LETTER_SPOTS = (0, 5, 10, 15)


def _job(capture: str, exposure_ms: float, tmp: str):
    from _quadrature_jobs import letter_job, paper_demo_job

    if capture == "letter":
        job, spec = letter_job(tmp, 8, exposure_ms)
        return job, spec, list(LETTER_SPOTS)
    job, spec = paper_demo_job(tmp, 8, exposure_ms * 1e-3)
    return job, spec, list(range(job.manifest["n_files"]))


def measure(capture: str) -> dict:
    import numpy as np

    from transient_mi.noise_target import TargetRun
    from transient_mi.noise_target_quadrature import quadrature_part_ratios, quadrature_ratio

    c = CAPTURES[capture]
    with tempfile.TemporaryDirectory() as tmp:  # (nothing is written: the job gives the scene and its manifest)
        job, spec, spots = _job(capture, c["exposure_ms"], tmp)
    integ, run = job.integrator, TargetRun(spec, dict(job.manifest))

    def render(h, m, rl, slope):
        integ.nlos_options.update(element_size_m=h, patch_cells=m, refine_levels=rl, element_slope=slope,
                                  error_parts=True)
        t = time.perf_counter()
        res = integ.render_transient(job.scene, job.sensor, seed=0, spp=1, spots=spots)
        return res, time.perf_counter() - t

    render(*c["rows"][0], True)  # (JIT compilation)
    ref, ref_s = render(*c["reference"], True)
    rows = []
    for h, m, rl in c["rows"]:
        for slope in (True, False):
            res, dt = render(h, m, rl, slope)
            actual = max(run.headline(j, r.histogram, np.abs(r.histogram.astype(np.float64) - q.histogram),
                                      error_bound=True) for j, (r, q) in enumerate(zip(res, ref)))
            stated = [quadrature_ratio(run, j, r) for j, r in enumerate(res)]
            worst = int(np.argmax(stated))
            row = {"element_size_m": h, "patch_cells": m, "refine_levels": rl, "element_slope": slope,
                   "render_s": round(dt, 2), "actual_ratio": actual, "stated_ratio": stated[worst],
                   "stated_parts": quadrature_part_ratios(run, worst, res[worst])}
            print(capture, row, file=sys.stderr, flush=True)
            rows.append(row)
            del res
    ref_stated = max(quadrature_ratio(run, j, r) for j, r in enumerate(ref))
    tm = job.manifest["time"]
    return {"pixels": "8 x 8", "spots": spots, "bin_width_ps": tm["bin_width_ps"], "exposure_ms": c["exposure_ms"],
            "detector": "paper's defaults, --auto-gate" if capture == "letter" else "the paper's",
            "reference": dict(zip(("element_size_m", "patch_cells", "refine_levels"), c["reference"]),
                              render_s=round(ref_s, 2), stated_ratio=ref_stated),
            "rows": rows}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--capture", choices=("letter", "paper", "both"), default="both")
    _record.add_arguments(ap)
    a = ap.parse_args(argv)
    load_start = list(os.getloadavg())
    import transient_mi  # noqa: F401

    captures = ("letter", "paper") if a.capture == "both" else (a.capture,)
    result = {"ratio": "rendering-error variance over photon variance, as detect states it (the largest over the "
                       "spots); actual: the difference from the reference level",
              "captures": {k: measure(k) for k in captures}}
    _record.maybe_save(a, "quadrature_element_slope", result, load_start=load_start)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
