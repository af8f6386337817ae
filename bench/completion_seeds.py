"""How much do the mannequin's metrics vary with the detection's photon noise? midpoint-fk, with and without completion.

The methods leaderboard scores one detection of one render. This script
renders the paper's scene once as the leaderboard does (32x32 array, 2x2
spots, 4 ps bins, render seed 0, by the scene's default estimator to the study's
``auto`` noise target at 10 ms per spot: the deterministic quadrature to 0.01 x the
photon noise; ``--estimator monte_carlo`` renders by Monte Carlo to 0.1 from a pilot of
``--spp``, as the leaderboard did until 2026-12-05), then detects it ``--seeds``
times at the paper's budget (10 ms per spot, detection seeds 1..N: seed 1 is
the leaderboard's), reconstructs each with ``midpoint-fk`` (the paper's
filter, its default threshold, 64x64x32 voxels over the paper's bounds) and
closes it behind its front (``recon.completion.complete_surface``, aspect
``auto``), and scores both against the mannequin. Reports per metric the
mean, the sample standard deviation and the two-sided 95 % Student-t
interval of the mean over the seeds.

Writes ``bench/results/completion_seeds.json`` (``--out``) with command,
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
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _record  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
KEYS = ("chamfer_m", "completeness_m", "iou", "visible_chamfer_m", "visible_iou", "silhouette_iou")


def summary(values) -> dict:
    import numpy as np
    from scipy import stats

    v = np.asarray(values, dtype=float)
    n = len(v)
    sd = float(v.std(ddof=1)) if n > 1 else float("nan")
    half = float(stats.t.ppf(0.975, n - 1) * sd / np.sqrt(n)) if n > 1 else float("nan")
    return {"mean": float(v.mean()), "sd": sd, "ci95": [float(v.mean()) - half, float(v.mean()) + half],
            "values": v.tolist()}


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--spp", type=int, default=16384)
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--estimator", choices=("quadrature", "monte_carlo"), default="quadrature")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "completion_seeds.json")
    a = ap.parse_args(argv)
    if a.seeds < 2:
        raise SystemExit(f"error: --seeds {a.seeds}: at least 2 (a spread needs two detections)")
    sys.path.insert(0, str(ROOT))
    import transient_mi  # noqa: F401
    import recon
    from recon.completion import complete_surface
    from recon.metrics import compute_metrics
    from transient_core.atomic import atomic_file
    from transient_mi.study.common import capture_estimator, noise_target_spec, render, resolve_noise_target
    from transient_mi.study.methods import _detect
    from transient_mi.study.scene import base_detector, load_study_ground_truth, study_scene
    from transient_mi.experiment import PAPER_BOUNDS_M

    sc = study_scene("paper_mannequin", {"spp": a.spp, "bin_width_ps": 4, "n_bins": 2875, "array": 32,
                                        "estimator": a.estimator})
    gt, gt_desc = load_study_ground_truth(sc)
    params = base_detector(sc)
    per = {"midpoint-fk": {k: [] for k in KEYS}, "midpoint-fk+completion": {k: [] for k in KEYS}}
    aspects = []
    with tempfile.TemporaryDirectory(dir=ROOT / "bench") as tmp:
        # the leaderboard's render: its "auto" noise target at 10 ms per spot (0.01 for the quadrature, 0.1 else)
        spec = noise_target_spec("auto", resolve_noise_target("auto", False), params, 0.01)
        ideal = render(sc, Path(tmp) / "ideal", 0, noise_target=spec)
        estimator = capture_estimator(ideal)
        for seed in range(1, a.seeds + 1):
            cap = _detect(ideal, params, 0.01, seed)[0]
            rec = recon.reconstruct(cap, "midpoint-fk", bounds=PAPER_BOUNDS_M, voxels=(64, 64, 32), filter="paper")
            done = complete_surface(rec, "auto")
            aspects.append([p["aspect"] for p in done.params["completion"]["aspects"]])
            for name, r in (("midpoint-fk", rec), ("midpoint-fk+completion", done)):
                m = compute_metrics(r, gt, seed=0)
                for k in KEYS:
                    per[name][k].append(m[k])
            print(f"seed {seed}: IoU {per['midpoint-fk+completion']['iou'][-1]:.3f} (completed), "
                  f"{per['midpoint-fk']['iou'][-1]:.3f} (front)", flush=True)
    res = {name: {k: summary(v) for k, v in d.items()} for name, d in per.items()}
    doc = {"benchmark": "completion_seeds",
           "command": "python bench/completion_seeds.py " + " ".join(argv),
           "date_utc": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
           "machine": {"platform": platform.platform(), "cpu_count": os.cpu_count(), "python": platform.python_version()},
           "settings": {"scene": "paper_mannequin", "array": 32, "spots": "2x2", "estimator": estimator,
                        "spp_pilot": a.spp if estimator == "monte_carlo" else None,
                        "noise_target": spec.target, "bin_width_ps": 4,
                        "exposure_s": 0.01, "render_seed": 0, "detection_seeds": list(range(1, a.seeds + 1)),
                        "voxels_xyz": [64, 64, 32], "bounds_m": list(PAPER_BOUNDS_M), "ground_truth": gt_desc},
           "results": res, "aspects": aspects}
    doc = _record.as_record("completion_seeds", doc)
    with atomic_file(a.out) as t:
        Path(t).write_text(json.dumps(doc, indent=1) + "\n")
    for name, d in res.items():
        print(name, {k: f"{v['mean']:.4f} +- {v['sd']:.4f}" for k, v in d.items()})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
