"""Sampling designs on the paper's scene: denser laser scans (N x N spots) and their cost and benefit.

For each laser grid side N in ``--spots`` (default 2, 4, 8, 16): render the
paper's mannequin scene with a ``--array`` x ``--array`` SPAD array (default
16, tiling the 1 m wall) and N x N laser spots over the wall (``-D spots=N``),
4 ps bins, ``--spp`` samples per pixel per spot; detect it with the paper's
detector at the paper's budget (10 ms per spot, so the total exposure and the
detected photons grow as N^2); reconstruct with ``bp`` (the paper's) and
``midpoint-fk`` and score against the mannequin. Records the render time,
ideal-data bytes, detected counts, reconstruction time and metrics.

Writes ``bench/results/sampling_designs.json`` (``--out``) with command,
machine and date.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _record  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
KEYS = ("chamfer_m", "completeness_m", "iou", "depth_mae_m", "visible_chamfer_m", "silhouette_iou",
        "normal_error_deg")


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--spots", default="2,4,8,16")
    ap.add_argument("--array", type=int, default=16)
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--methods", default="bp,midpoint-fk")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "sampling_designs.json")
    a = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    import numpy as np

    import transient_mi  # noqa: F401
    import recon
    from transient_core.atomic import atomic_file
    from recon.metrics import GroundTruth, compute_metrics
    from transient_mi.experiment import PAPER_BOUNDS_M, PaperConfig, ground_truth, paper_detector, render_ideal
    from transient_mi.study.detection import Detection, IdealCapture

    gt = GroundTruth(mesh=ground_truth(PaperConfig()), source="paper mannequin")
    rows = []
    for n in (int(v) for v in a.spots.split(",")):
        cfg = PaperConfig(array=a.array, spots=n, spp=a.spp, bin_width_ps=4.0, n_bins=2875, estimator="monte_carlo")
        with tempfile.TemporaryDirectory(dir=ROOT / "bench") as tmp:
            t0 = time.perf_counter()
            ideal = render_ideal(cfg, Path(tmp) / "ideal", progress=False)
            t_render = time.perf_counter() - t0
            nbytes = sum(p.stat().st_size for p in Path(ideal).glob("spot_*.exr"))
            det = Detection(IdealCapture(ideal), paper_detector(), exposure_s=0.01)
            cap = det.capture(1)
            counts = float(cap.data.sum(dtype=np.int64))
            row = {"spots": n, "n_spots": n * n, "array": a.array, "spp": a.spp, "render_s": t_render,
                   "ideal_bytes": nbytes, "detected_counts": counts, "exposure_total_s": 0.01 * n * n,
                   "methods": {}}
            for m in a.methods.split(","):
                t0 = time.perf_counter()
                rec = recon.reconstruct(cap, m, bounds=PAPER_BOUNDS_M, voxels=(64, 64, 32))
                dt = time.perf_counter() - t0
                mt = compute_metrics(rec, gt, seed=0)
                row["methods"][m] = {"reconstruct_s": dt, **{k: mt.get(k) for k in KEYS}}
            rows.append(row)
            print(json.dumps(row), flush=True)
    doc = {"benchmark": "sampling_designs", "command": "python bench/sampling_designs.py " + " ".join(argv),
           "date_utc": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
           "machine": {"platform": platform.platform(), "cpu_count": os.cpu_count(),
                       "python": platform.python_version()},
           "note": "render and reconstruction times are wall clock on a machine shared with other jobs",
           "rows": rows}
    doc = _record.as_record('sampling_designs', doc)
    with atomic_file(a.out) as t:
        Path(t).write_text(json.dumps(doc, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
