"""Are the mannequin's legs separated and its head present? Front-view checks of bp and midpoint-fk.

Renders the paper's scene (32x32 array, 2x2 spots, 4 ps bins; from a pilot
of ``--spp`` until its rendering noise is at most 0.1 x the photon noise at
10 ms per spot, as the leaderboard renders), detects it at the paper's budget (10 ms per spot, detection seed 1), and
reconstructs with each method (paper filter, default threshold, 64x64x32
voxels). On the front view (columns holding any kept voxel) it counts, on
every row through the legs (y from -0.30 to -0.10 m, where the ground-truth
silhouette has two runs), the runs of occupied columns, and on the head rows
(y from 0.27 to 0.33 m) whether any column is occupied within 6 cm of x = 0.
Writes ``bench/results/mannequin_features.json`` with command, machine, date.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _record  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def runs(row) -> int:
    import numpy as np

    r = np.asarray(row, dtype=np.int8)
    return int(np.count_nonzero(np.diff(np.concatenate([[0], r, [0]])) == 1))


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--spp", type=int, default=16384)
    ap.add_argument("--methods", default="bp,midpoint-fk")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "mannequin_features.json")
    a = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    import numpy as np

    import transient_mi  # noqa: F401
    import recon
    from transient_core.atomic import atomic_file
    from recon.ground_truth import ground_truth_silhouette
    from transient_mi.experiment import PAPER_BOUNDS_M, PaperConfig, ground_truth, paper_detector, render_ideal
    from transient_mi.study.detection import Detection, IdealCapture

    cfg = PaperConfig(array=32, spots=2, spp=a.spp, bin_width_ps=4.0, n_bins=2875, estimator="monte_carlo")
    mesh = ground_truth(cfg)
    out = {}
    with tempfile.TemporaryDirectory(dir=ROOT / "bench") as tmp:
        ideal = render_ideal(cfg, Path(tmp) / "ideal", progress=False, noise_target=0.1, exposure_s=0.01)
        cap = Detection(IdealCapture(ideal), paper_detector(), exposure_s=0.01).capture(1)
        cap.data
        for m in ["ground_truth"] + a.methods.split(","):
            if m == "ground_truth":
                g = recon.make_grid(cap, bounds=PAPER_BOUNDS_M, voxels=(64, 64, 32))
                sil = ground_truth_silhouette(mesh, g.x_m, g.y_m)
            else:
                rec = recon.reconstruct(cap, m, bounds=PAPER_BOUNDS_M, voxels=(64, 64, 32))
                g = rec.grid
                sil = (rec.volume > 0).any(axis=0)
            legs = [(float(y), runs(sil[i])) for i, y in enumerate(g.y_m) if -0.30 <= y <= -0.10]
            head = [i for i, y in enumerate(g.y_m) if 0.27 <= y <= 0.33]
            near = np.abs(g.x_m) <= 0.06
            out[m] = {"leg_rows": len(legs), "leg_rows_with_two_runs": sum(1 for _, n in legs if n == 2),
                      "runs_per_leg_row": legs, "head_present": bool(sil[np.ix_(head, np.flatnonzero(near))].any())}
            print(m, {k: v for k, v in out[m].items() if k != "runs_per_leg_row"}, flush=True)
    doc = {"benchmark": "mannequin_features", "command": "python bench/mannequin_features.py " + " ".join(argv),
           "date_utc": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
           "machine": {"platform": platform.platform(), "cpu_count": os.cpu_count(),
                       "python": platform.python_version()},
           "settings": {"spp_pilot": a.spp, "noise_target": 0.1, "exposure_s": 0.01, "detection_seed": 1},
           "results": out}
    doc = _record.as_record('mannequin_features', doc)
    with atomic_file(a.out) as t:
        Path(t).write_text(json.dumps(doc, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
