#!/usr/bin/env python3
"""Benchmark: the cost of one fit iteration with the quadrature as forward model (``transient-mi fit --estimator
quadrature``) against Monte Carlo's, on bench_fit.py's capture of the paper's mannequin (cached in --work).

One iteration is one render (residual) and one backward pass (gradient with respect to the twin's vertices and
reflectance). Measured per twin tessellation (``--detail``; the fit's default is 20) at the quadrature's
coarse-to-fine element sizes (the fit's quadrature settings: one cell per pixel patch, the fine level only), and
Monte Carlo at the fit's default samples (bench_fit.py's settings). Each row is the second of two iterations at
the same parameters (the first compiles and loads kernels).

    python bench/bench_fit_quadrature_cost.py --array 8 --save
    python bench/bench_fit_quadrature_cost.py --array 32 --save     # bench_fit's full-size capture
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _record  # noqa: E402


def _iteration(cap, mdl, theta, spp: int, spp_residual: int) -> dict:
    cap.set_mesh(mdl.vertices(theta), mdl.albedo(theta))
    t0 = time.perf_counter()
    ideal = cap.ideal(0, spp_residual, 30.0)
    t1 = time.perf_counter()
    obj, r = cap.objective(cap.expected_counts(ideal), 30.0)
    t2 = time.perf_counter()
    cap.backward(r, ideal, 1, spp, 30.0)
    t3 = time.perf_counter()
    return {"render_s": t1 - t0, "backward_s": t3 - t2, "iteration_s": t3 - t0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--array", type=int, default=8)
    ap.add_argument("--details", default="20,8")
    ap.add_argument("--element-sizes-m", default="0.06,0.03")
    ap.add_argument("--work", type=Path, default=Path(os.environ.get("TMPDIR", "/tmp")) / "transient-mi-bench-fit")
    _record.add_arguments(ap)
    a = ap.parse_args()
    load_start = list(os.getloadavg())
    import transient_mi  # noqa: F401

    import bench_fit
    from transient_mi.fit.capture_model import FIT_QUADRATURE, CaptureModel
    from transient_mi.fit.models import MannequinModel
    from transient_mi.fit.optimize import FitSettings, resolve_spp

    counts, _ = bench_fit._capture(a.work, a.array)
    rows = []
    for detail in [int(x) for x in a.details.split(",")]:
        mdl = MannequinModel(detail)
        theta = mdl.initial((0.0, 0.0, 0.58))
        cap = CaptureModel(counts, mdl.faces, mdl.n_vertices, estimator="monte_carlo")
        spp, spp_r = resolve_spp(FitSettings(), cap.width * cap.height)
        _iteration(cap, mdl, theta, spp, spp_r)  # (compiles the kernels)
        rows.append({"estimator": "monte_carlo", "detail": detail, "faces": len(mdl.faces), "spp": spp,
                     "spp_residual": spp_r, **_iteration(cap, mdl, theta, spp, spp_r)})
        print(rows[-1], flush=True)
        for h in [float(x) for x in a.element_sizes_m.split(",")]:
            cap = CaptureModel(counts, mdl.faces, mdl.n_vertices, estimator="quadrature", element_size_m=h,
                               **FIT_QUADRATURE)
            _iteration(cap, mdl, theta, 0, 0)
            r = _iteration(cap, mdl, theta, 0, 0)
            rows.append({"estimator": "quadrature", "detail": detail, "faces": len(mdl.faces), "element_size_m": h,
                         **r})
            print(rows[-1], flush=True)
    _record.maybe_save(a, f"fit_quadrature_cost_{a.array}", {"array": a.array, "spots": 4, "rows": rows},
                       load_start=load_start)


if __name__ == "__main__":
    main()
