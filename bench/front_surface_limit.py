"""What the metrics give a perfect front-surface reconstruction of the paper's mannequin (the limit of NLOS).

Three-bounce light only comes from surface the relay wall sees. This script
scores two "oracle" reconstructions of the paper's mannequin on the paper's
voxel grid (64 x 64 x 32 over x, y in [-0.5, 0.5] m, z in [0.25, 0.75] m)
with :func:`recon.metrics.compute_metrics`:

- ``front_surface``: per voxel column, the voxel holding the mesh's first
  hit along +z (the exact visible surface, one voxel per column);
- ``all_surface``: every voxel holding mesh surface samples (front and back);
- ``front_surface_completed``: ``front_surface`` closed behind itself by
  :func:`recon.completion.complete_surface` (aspect estimated from the front):
  what the completion prior gives an exact, voxel-quantised front.

Writes ``bench/results/front_surface_limit.json`` (``--out``) with the
command, machine and date.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _record  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
KEYS = ("chamfer_m", "accuracy_m", "completeness_m", "iou", "depth_mae_m", "visible_chamfer_m",
        "visible_completeness_m", "visible_iou", "silhouette_iou", "normal_error_deg")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "front_surface_limit.json")
    a = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    import numpy as np

    import transient_mi  # noqa: F401
    from transient_core.atomic import atomic_file
    from recon.completion import complete_surface
    from recon.grid import VoxelGrid
    from recon.metrics import GroundTruth, compute_metrics, mesh_depth_map, mesh_occupancy
    from recon.result import Reconstruction
    from transient_mi.experiment import PAPER_BOUNDS_M, PaperConfig, ground_truth

    mesh = ground_truth(PaperConfig())
    g = VoxelGrid.from_bounds(PAPER_BOUNDS_M, voxels=(64, 64, 32))
    gt = GroundTruth(mesh=mesh, source="paper mannequin")
    d = mesh_depth_map(mesh, g)
    front = np.zeros(g.shape, np.float32)
    iy, ix = np.nonzero(np.isfinite(d))
    iz = np.clip(np.floor((d[iy, ix] - g.bounds[4]) / g.voxel_size_m[2]).astype(int), 0, g.shape[0] - 1)
    front[iz, iy, ix] = 1.0
    allv = mesh_occupancy(mesh, g).astype(np.float32)
    res = {}
    for name, vol in (("front_surface", front), ("all_surface", allv)):
        m = compute_metrics(Reconstruction(raw=vol, grid=g, method=name), gt, seed=0)
        res[name] = {k: m.get(k) for k in KEYS}
    done = complete_surface(Reconstruction(raw=front, grid=g, method="front_surface"), "auto")
    m = compute_metrics(done, gt, seed=0)
    res["front_surface_completed"] = {**{k: m.get(k) for k in KEYS},
                                      "aspects": [p["aspect"] for p in done.params["completion"]["aspects"]]}
    doc = {"benchmark": "front_surface_limit",
           "command": "python bench/front_surface_limit.py " + " ".join(argv if argv is not None else sys.argv[1:]),
           "date_utc": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
           "machine": {"platform": platform.platform(), "cpu_count": os.cpu_count(),
                       "python": platform.python_version()},
           "grid": {"bounds_m": list(PAPER_BOUNDS_M), "voxels_xyz": [64, 64, 32]}, "results": res}
    a.out.parent.mkdir(parents=True, exist_ok=True)
    doc = _record.as_record('front_surface_limit', doc)
    with atomic_file(a.out) as tmp:
        Path(tmp).write_text(json.dumps(doc, indent=1) + "\n")
    print(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
