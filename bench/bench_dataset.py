#!/usr/bin/env python3
"""Benchmark: dataset items per hour with ``transient-mi dataset`` (local Dask cluster or a scheduler).

Builds a spec (default ``docs/examples/dataset_example.yaml``) into a fresh
temporary directory once per ``--workers`` value and prints one JSON object:
for each run the wall time of the whole command (validation, cluster start,
all items, index), items per hour over that wall time, and from the items'
``result.json`` the mean time per item inside a worker and the items per
worker process.

    python bench/bench_dataset.py                          # the example spec, --workers 1 and 2
    python bench/bench_dataset.py --workers 2 --repeats 2  # fewer items (repeats per grid point)
    python bench/bench_dataset.py --scheduler tcp://127.0.0.1:8786
    python bench/bench_dataset.py --tiny --repeats 1 --workers 1   # CI-sized
    python bench/bench_dataset.py --spec docs/examples/dataset_nlos_mannequin.yaml --noise-target 0.1 --repeats 1
                                         # every item rendered to the noise standard (the spec's detector budget)

The record is ``dataset_<spec>[_tiny][_nt<R>_<estimator>]``: with ``--noise-target`` it also holds, per run,
the estimator that made the captures (from each item's ``result.json``) and the largest rendering / photon
noise ratio of the items (``render_noise_ratio`` as ``detect`` states it).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))
import _record  # noqa: E402
DEFAULT_SPEC = ROOT / "docs" / "examples" / "dataset_example.yaml"
#: --tiny: the CI-sized render settings (only those the scene has are applied).
TINY = {"width": 8, "height": 8, "n_bins": 50, "spp": 2}


def make_spec(src: Path, dst: Path, repeats: int | None, tiny: bool, noise_target: float | None = None,
              defines: dict | None = None) -> dict:
    """Copy a spec with its scene path made absolute, optionally fewer repeats, tiny renders, a noise target
    or other fixed ``defines``."""
    import yaml

    from transient_mi.dataset.spec import resolve_scene

    data = yaml.safe_load(src.read_text())
    data["scene"] = str(resolve_scene(data["scene"], src.resolve().parent))
    if repeats is not None:
        data["repeats"] = repeats
    if tiny:
        data["spp"] = TINY["spp"]
        defines = data.setdefault("defines", {}) or {}
        for k in ("width", "height", "n_bins"):
            if k in defines:
                defines[k] = TINY[k]
        if "n_bins" in defines and "bin_width_ps" in defines:
            defines["bin_width_ps"] = 200
    if noise_target is not None:
        data["noise_target"] = noise_target
    if defines:
        data["defines"] = dict(data.get("defines") or {}, **defines)
    dst.write_text(yaml.safe_dump(data, sort_keys=False))
    return data


def one_run(spec: Path, workers: int | None, scheduler: str | None) -> dict:
    from transient_mi.dataset import run_dataset

    out = Path(tempfile.mkdtemp(prefix="bench-dataset-")) / "ds"
    try:
        t = time.perf_counter()
        report = run_dataset(spec, out, workers=workers, scheduler=scheduler, progress=False)
        wall = time.perf_counter() - t
        results = [json.loads(p.read_text()) for p in sorted((out / "items").glob("item_*/result.json"))]
        per_worker = Counter(r["worker"] for r in results)
        item_s = [r["total_time_s"] for r in results]
        render_s = [r.get("render_time_s", 0.0) for r in results]
        size = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
        ratios = [r["render_noise_ratio"] for r in results if r.get("render_noise_ratio") is not None]
        spp = [r["spp_used"] for r in results if r.get("spp_used") is not None]
        return {
            "workers": workers, "scheduler": scheduler, "cluster": report.cluster, "items": report.built,
            "wall_s": round(wall, 3), "items_per_hour": round(report.built / wall * 3600, 1),
            "mean_item_s_in_worker": round(sum(item_s) / len(item_s), 4),
            "mean_render_s_in_worker": round(sum(render_s) / len(render_s), 4),
            "items_per_worker_process": sorted(per_worker.values(), reverse=True),
            "dataset_bytes": size,
            "estimators": dict(Counter(r.get("estimator", "monte_carlo") for r in results)),
            "render_noise_ratio_max": max(ratios) if ratios else None,
            "render_noise_ratio_median": sorted(ratios)[len(ratios) // 2] if ratios else None,
            "noise_target_met": sum(bool((r.get("noise_target") or {}).get("met")) for r in results),
            "spp_used_range": [min(spp), max(spp)] if spp else None,
        }
    finally:
        shutil.rmtree(out.parent, ignore_errors=True)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--spec", type=Path, default=DEFAULT_SPEC)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="local cluster sizes to time")
    ap.add_argument("--scheduler", default=None, help="time on this Dask scheduler instead of local clusters")
    ap.add_argument("--repeats", type=int, default=None, help="override the spec's repeats (fewer items)")
    ap.add_argument("--tiny", action="store_true", help="8x8 pixels, 50 bins, 2 spp (CI)")
    ap.add_argument("--noise-target", type=float, default=None,
                    help="the spec's noise_target (every item rendered to it; needs the spec's detector)")
    ap.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE",
                    help="a fixed scene define added to the spec's (e.g. -D estimator=monte_carlo); repeatable")
    _record.add_arguments(ap)
    args = ap.parse_args(argv)
    load_start = list(os.getloadavg())
    os.environ.setdefault("TRANSIENT_MI_PROGRESS", "0")
    import transient_mi  # noqa: F401
    from dask.system import CPU_COUNT

    with tempfile.TemporaryDirectory() as td:
        spec = Path(td) / "spec.yaml"
        defines = dict(d.split("=", 1) for d in args.defines)
        data = make_spec(args.spec, spec, args.repeats, args.tiny, args.noise_target, defines)
        runs = ([one_run(spec, None, args.scheduler)] if args.scheduler else
                [one_run(spec, w, None) for w in args.workers])
    try:
        spec_name = str(args.spec.resolve().relative_to(ROOT))
    except ValueError:
        spec_name = str(args.spec)
    result = {
        "benchmark": "dataset", "spec": spec_name, "tiny": args.tiny, "repeats": data.get("repeats", 1),
        "defines": data.get("defines"), "spp": data.get("spp"), "noise_target": args.noise_target,
        "detector": data.get("detector"), "cores": int(CPU_COUNT),
        "cpu": _record.cpu_model(), "runs": runs,
    }
    print(json.dumps(result, indent=2))
    name = "dataset_" + Path(spec_name).stem + ("_tiny" if args.tiny else "")
    if args.noise_target is not None:
        est = sorted({e for r in runs for e in r["estimators"]})
        name += f"_nt{args.noise_target:g}_" + "+".join(est)
    _record.maybe_save(args, name, result, load_start=load_start)
    return 0


if __name__ == "__main__":
    sys.exit(main())
