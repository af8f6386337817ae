"""``fit:mesh`` on the paper's mannequin from midpoint-fk's surface, within a wall-time budget (issue 29's target:
occupancy IoU >= 0.7 and Chamfer <= 0.8 cm in at most 5 minutes on 2 cores, no mannequin prior).

The capture: ``scenes/paper_mannequin.xml`` at 32 x 32 pixels, 2 x 2 laser spots, 1 ps bins, rendered by the
quadrature at the scene's settings and detected with the paper's detector for ``--exposure-ms`` per spot. midpoint
f-k reconstructs the counts on the methods study's grid; the free mesh starts from its front surface (as the study's
``fit:mesh`` row: :func:`transient_mi.study.methods_fit.fit_row`) and runs ``--iterations`` iterations after
``--align`` alignment iterations; the fitted surface is scored on the same grid as the leaderboard's rows
(the paper's volume, ``PAPER_BOUNDS_M``, 64 x 64 x 32 voxels)
(:mod:`transient_mi.study.metrics_rows`), beside midpoint-fk's own. Time: the fit's wall time (start mesh to
``fit.json``), the budget the target names.

    python bench/bench_fit_mesh_mannequin.py --pixel-step 1 --save    # fit_mesh_mannequin.json (every pixel)
    python bench/bench_fit_mesh_mannequin.py --pixel-step 2 --save-as bench/results/fit_mesh_mannequin_step2.json
    python bench/bench_fit_mesh_mannequin.py --pixel-step 4 --save-as bench/results/fit_mesh_mannequin_step4.json
    python bench/bench_fit_mesh_mannequin.py --start-shape closed --iterations 20 --align 8 --carve 0 --save  # ..._closed
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))
import _record  # noqa: E402

#: The issue's targets for the mannequin from midpoint-fk's surface.
TARGETS = {"iou_min": 0.7, "chamfer_m_max": 0.008, "wall_s_max": 300.0}
#: The methods study's default grid (``run_methods_study``'s ``voxels``).
VOXELS = (64, 64, 32)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--array", type=int, default=32)
    ap.add_argument("--exposure-ms", type=float, default=10.0)
    ap.add_argument("--iterations", type=int, default=12)
    ap.add_argument("--align", type=int, default=4)
    ap.add_argument("--start-shape", choices=("front", "closed"), default="front",
                    help="midpoint-fk's front surface (as the study's fit:mesh row) or a closed surface around its "
                         "occupied voxels (mesh_start.closed_surface)")
    ap.add_argument("--pixel-step", type=int, default=None,
                    help="fit every n-th pixel along each axis (MeshSettings.pixel_step; default: the fit's own)")
    ap.add_argument("--carve", type=int, default=None,
                    help="carving iterations (MeshSettings.carve; default: the fit's, capped at --iterations)")
    ap.add_argument("--suffix", default="", help="appended to the record's name")
    _record.add_arguments(ap)
    a = ap.parse_args(argv)
    load_start = list(os.getloadavg())
    os.environ.setdefault("TRANSIENT_MI_PROGRESS", "0")
    import numpy as np

    import transient_mi  # noqa: F401
    from spad_detector import detect_stack
    from transient_core.stack import read_manifest
    from transient_mi.fit import FitSettings, fit_capture
    from transient_mi.paper import PaperConfig, paper_detector, scene_file
    from transient_mi.render_capture import render
    from transient_mi.study.methods import _reconstruct, scene_ground_truth
    from transient_mi.study.methods_fit import FIT_MESH_START, _mesh_start, fit_bin_width_ps, mesh_reconstruction
    from transient_mi.study.metrics_rows import LEADERBOARD_METRICS, score
    from transient_mi.study.scene import study_scene

    cfg = PaperConfig(array=a.array, spots=2, bin_width_ps=1.0, n_bins=11500, estimator="quadrature")
    defines = {k: str(v) for k, v in cfg.defines().items()}
    with tempfile.TemporaryDirectory(prefix="bench-fitmesh-mannequin-") as td:
        td = Path(td)
        t0 = time.perf_counter()
        ideal = render(Path(scene_file()), td / "ideal", defines=defines, progress=False)
        render_s = time.perf_counter() - t0
        counts = detect_stack(ideal, td / "counts", paper_detector(), exposure_s=1e-3 * a.exposure_ms, seed=1,
                              progress=False)
        from recon.capture import load_capture

        cap = load_capture(counts)
        from transient_mi.paper import PAPER_BOUNDS_M

        bounds = tuple(float(b) for b in PAPER_BOUNDS_M)  # (the methods study's volume for the paper scene)
        rec, rec_s, _ = _reconstruct(cap, FIT_MESH_START, bounds, VOXELS, None)
        gt = scene_ground_truth(study_scene("paper_mannequin"))
        start_metrics = score(rec, gt, 0)
        t = read_manifest(counts)["time"]
        bw = fit_bin_width_ps(float(t["bin_width_ps"]), int(t["n_bins"]))
        # (its carving capped at the iterations, as the methods study caps it)
        mesh = replace(_mesh_start(td / "fit_work", rec, a.iterations), align=a.align)
        if a.pixel_step is not None:
            mesh = replace(mesh, pixel_step=a.pixel_step)
        if a.carve is not None:
            mesh = replace(mesh, carve=a.carve)
        if a.start_shape == "closed":
            from recon.surface import write_ply
            from transient_mi.fit.mesh_start import closed_surface

            v, f = closed_surface(np.asarray(rec.volume), rec.grid, mesh.cell_m)
            write_ply(td / "fit_work" / "start_closed.ply", v, f)
            mesh = replace(mesh, start_mesh=str(td / "fit_work" / "start_closed.ply"))
        t1 = time.perf_counter()
        res = fit_capture(counts, td / "fit", model="mesh", bin_width_ps=bw, progress=False, log=lambda *x: None,
                          settings=FitSettings(iterations=a.iterations), mesh=mesh)
        fit_s = time.perf_counter() - t1
        fit_metrics = score(mesh_reconstruction(td / "fit" / "fitted.ply", rec.grid, "fit:mesh", {}), gt, 0)
        # (the start as the fit took it: clear of the view)
        start_mesh_metrics = score(mesh_reconstruction(td / "fit" / "start.ply", rec.grid, "start", {}), gt, 0)
    keep = list(LEADERBOARD_METRICS)
    fit_row = {k: fit_metrics.get(k) for k in keep}
    result = {"scene": "paper_mannequin", "bounds_m": list(bounds), "voxels": list(VOXELS), "array": a.array, "spots": 2, "exposure_ms": a.exposure_ms,
              "iterations": a.iterations, "align": a.align, "fit_bin_width_ps": bw, "start": FIT_MESH_START,
              "start_shape": a.start_shape, "pixel_step": res["estimator"]["pixel_step"],
              "carve": res["config"]["mesh"]["carve"], "grow": res["config"]["mesh"]["grow"],
              "render_s": render_s, "reconstruct_s": rec_s, "fit_wall_s": fit_s,
              "fit_time_s": res["time_s"], "n_faces": {"start": res["parameters"]["start"]["n_faces"],
                                                        "fit": res["parameters"]["fit"]["n_faces"]},
              "metrics": {"fit": fit_row, FIT_MESH_START: {k: start_metrics.get(k) for k in keep},
                          "start_mesh": {k: start_mesh_metrics.get(k) for k in keep}},
              "targets": {**TARGETS, "met": {"iou": (fit_row.get("iou") or 0) >= TARGETS["iou_min"],
                                             "chamfer": (fit_row.get("chamfer_m") or 9) <= TARGETS["chamfer_m_max"],
                                             "time": fit_s <= TARGETS["wall_s_max"]}}}
    for k, r in result["metrics"].items():
        print(f"{k:12s} " + "  ".join(f"{c}={v:.4g}" for c, v in r.items() if isinstance(v, float)))
    print(f"fit {fit_s:.0f} s (render {render_s:.0f} s, {FIT_MESH_START} {rec_s:.1f} s)")
    _record.maybe_save(a, "fit_mesh_mannequin" + ("_closed" if a.start_shape == "closed" else "") + a.suffix, result,
                       load_start=load_start)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
