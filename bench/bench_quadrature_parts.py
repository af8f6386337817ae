#!/usr/bin/env python3
"""Which part of the quadrature's error sets a capture's ratio: the demo's capture at settings of the quadrature,
each part's ratio alone beside the whole, and the render time.

The quadrature's error is the sum of three parts (:func:`transient_mi.integrators._nlos_quadrature.error_parts`):
the light of elements whose visibility samples disagree (``visibility``), the elements' discretisation estimate
(``elements``) and, with one cell per patch side, the cells' estimate (``cells``). ``render --noise-target``
refines the part with the largest share (:func:`transient_mi.noise_target_quadrature.plan_quadrature_level`); this benchmark
shows what each part gives alone (the ratio ``detect`` would state if the error were that part only: rendering
error over photon noise, squared, headline over the bin classes, the worst spot) at the demo's detector and
``--exposure-ms`` per spot, for each ``--settings`` entry ``element_size_m,patch_cells,refine_levels``.

    python bench/bench_quadrature_parts.py --array 8 --exposure-ms 1000 --save   # quadrature_parts_a8_e1000ms.json
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _record  # noqa: E402

DEFAULT_SETTINGS = ("0.04,1,1", "0.04,2,1", "0.04,1,2", "0.04,1,3", "0.028,1,1", "0.02,1,1")


def measure(array: int, exposure_s: float, settings: list[tuple[float, int, int]]) -> dict:
    import transient_mi  # noqa: F401
    from _quadrature_jobs import paper_demo_job
    from transient_mi.noise_target import TargetRun
    from transient_mi.noise_target_quadrature import quadrature_part_ratios, quadrature_ratio

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        job, spec = paper_demo_job(tmp, array, exposure_s)
        run = TargetRun(spec, dict(job.manifest))
        opts = job.integrator.nlos_options
        spots = list(range(job.manifest["n_files"]))
        side = math.isqrt(len(spots))  # (the demo's square scan grid)
        config = (f"the demo's capture: {array} x {array} pixels, {side} x {side} spots, "
                  f"{job.manifest['time']['bin_width_ps']:g} ps bins, the paper's detector")
        for h, m, rl in settings:
            opts.update(element_size_m=h, patch_cells=m, refine_levels=rl, error_parts=True)
            t0 = time.perf_counter()
            res = job.integrator.render_transient(job.scene, job.sensor, seed=0, spp=1, spots=spots)
            render_s = time.perf_counter() - t0
            ratios = [quadrature_ratio(run, j, r) for j, r in zip(spots, res)]
            parts = [quadrature_part_ratios(run, j, r) for j, r in zip(spots, res)]
            worst = max(range(len(spots)), key=lambda g: ratios[g])
            rows.append({"element_size_m": h, "patch_cells": m, "refine_levels": rl, "render_s": round(render_s, 2),
                         "ratio": ratios[worst], "parts": parts[worst], "worst_spot": spots[worst],
                         "pairs": int(res[0].estimator_info["pairs"]),
                         "elements": int(res[0].estimator_info["elements"])})
            print(rows[-1], file=sys.stderr, flush=True)
            del res
    return {"scene": "transient_mi/scenes/paper_mannequin.xml", "array": array,
            "config": config, "exposure_ms": exposure_s * 1e3, "target": spec.target,
            "ratio": "rendering-error over photon noise, squared, as detect states it (headline over bin classes), "
                     "worst spot; parts: the ratio each part of the error gives alone",
            "rows": rows}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--array", type=int, default=8)
    ap.add_argument("--exposure-ms", type=float, default=1000.0)
    ap.add_argument("--settings", nargs="+", default=list(DEFAULT_SETTINGS),
                    help="element_size_m,patch_cells,refine_levels per render (default: %(default)s)")
    _record.add_arguments(ap)
    a = ap.parse_args(argv)
    load_start = list(os.getloadavg())
    os.environ.setdefault("TRANSIENT_MI_PROGRESS", "0")
    settings = []
    for s in a.settings:
        h, m, rl = s.split(",")
        settings.append((float(h), int(m), int(rl)))
    result = measure(a.array, a.exposure_ms / 1e3, settings)
    name = f"quadrature_parts_a{a.array}_e{a.exposure_ms:g}ms"
    print(json.dumps(result, indent=1))
    _record.maybe_save(a, name, result, load_start=load_start)


if __name__ == "__main__":
    os.environ.setdefault("PYTHONHASHSEED", "0")
    main()
