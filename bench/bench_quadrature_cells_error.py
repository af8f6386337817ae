#!/usr/bin/env python3
"""The cells' part of the quadrature's error on the letter: actual against stated, per cells per patch side.

Renders ``scenes/nlos_letter.xml`` by the quadrature (``--array`` pixels, the spots ``SPOTS`` of its 4 x 4 (a
diagonal), its 16 ps bins, the paper's detector defaults with ``--auto-gate`` at ``--exposure-ms`` per spot) with the
same elements (``--element-size-m``) and ``--cells`` cells per patch side, and once with ``--reference-cells``. Per
setting it records:

* ``actual_ratio``: the rendering-error ratio (``detect``'s headline, variance over photon variance) of the
  difference from the reference, taken as the error: the cells' part alone, since the elements are the same (the
  reference's own cells' part is left in; at 12 cells it is far below every row's);
* ``stated_ratio``: the ratio of the error estimate the capture states (all its parts: visibility, elements,
  cells);
* the render time (one process, kernels compiled by an untimed first render).

It shows how far the stated error is above the actual one where the cells set it (docs/quadrature.md):

    python bench/bench_quadrature_cells_error.py --save
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

#: The letter's spots rendered (of its 4 x 4, row-major): the four on a diagonal, corners to centre.
SPOTS = (0, 5, 10, 15)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--array", type=int, default=8, help="pixels per side (default 8)")
    ap.add_argument("--element-size-m", type=float, default=0.01)
    ap.add_argument("--cells", default="1,2,3,4,6", help="cells per patch side, comma-separated")
    ap.add_argument("--reference-cells", type=int, default=12)
    ap.add_argument("--exposure-ms", type=float, default=10.0)
    _record.add_arguments(ap)
    a = ap.parse_args(argv)
    load_start = list(os.getloadavg())
    import numpy as np

    import transient_mi  # noqa: F401
    from _quadrature_jobs import letter_job
    from transient_mi.noise_target import TargetRun
    from transient_mi.noise_target_quadrature import quadrature_ratio

    with tempfile.TemporaryDirectory() as tmp:  # (nothing is written: the job gives the scene and its manifest)
        job, spec = letter_job(tmp, a.array, a.exposure_ms)
    scene, integ, sensor = job.scene, job.integrator, job.sensor
    run = TargetRun(spec, job.manifest)

    def render(cells: int):
        integ.nlos_options.update(refine_levels=1, element_size_m=a.element_size_m, patch_cells=cells)
        t = time.perf_counter()
        res = integ.render_transient(scene, sensor, seed=0, spp=1, spots=list(SPOTS))
        return res, time.perf_counter() - t

    render(2)  # (JIT compilation)
    ref, ref_s = render(a.reference_cells)
    rows = []
    for m in [int(c) for c in a.cells.split(",")]:
        res, dt = render(m)
        actual = max(run.headline(j, r.histogram, np.abs(r.histogram.astype(np.float64) - q.histogram),
                                  error_bound=True) for j, (r, q) in enumerate(zip(res, ref)))
        stated = max(quadrature_ratio(run, j, r) for j, r in enumerate(res))
        row = {"patch_cells": m, "render_s": round(dt, 2), "actual_ratio": actual, "stated_ratio": stated,
               "stated_over_actual": stated / actual if actual > 0 else None}
        print(row, file=sys.stderr, flush=True)
        rows.append(row)
    tm = job.manifest["time"]
    result = {"scene": "scenes/nlos_letter.xml", "array": a.array, "spots": list(SPOTS),
              "bin_width_ps": tm["bin_width_ps"], "element_size_m": a.element_size_m, "refine_levels": 1,
              "exposure_ms": a.exposure_ms, "detector": "paper's defaults, --auto-gate",
              "reference_cells": a.reference_cells, "reference_render_s": round(ref_s, 2),
              "ratio": "rendering-error variance over photon variance, as detect states it (the largest over the "
                       "spots)", "rows": rows}
    _record.maybe_save(a, f"quadrature_cells_error_letter_a{a.array}", result, load_start=load_start)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
