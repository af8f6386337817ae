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


def make_spec(src: Path, dst: Path, repeats: int | None, tiny: bool) -> dict:
    """Copy a spec with its scene path made absolute, optionally fewer repeats or tiny renders."""
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
        return {
            "workers": workers, "scheduler": scheduler, "cluster": report.cluster, "items": report.built,
            "wall_s": round(wall, 3), "items_per_hour": round(report.built / wall * 3600, 1),
            "mean_item_s_in_worker": round(sum(item_s) / len(item_s), 4),
            "mean_render_s_in_worker": round(sum(render_s) / len(render_s), 4),
            "items_per_worker_process": sorted(per_worker.values(), reverse=True),
            "dataset_bytes": size,
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
    _record.add_arguments(ap)
    args = ap.parse_args(argv)
    load_start = list(os.getloadavg())
    os.environ.setdefault("TRANSIENT_MI_PROGRESS", "0")
    import transient_mi  # noqa: F401
    from dask.system import CPU_COUNT

    with tempfile.TemporaryDirectory() as td:
        spec = Path(td) / "spec.yaml"
        data = make_spec(args.spec, spec, args.repeats, args.tiny)
        runs = ([one_run(spec, None, args.scheduler)] if args.scheduler else
                [one_run(spec, w, None) for w in args.workers])
    try:
        spec_name = str(args.spec.resolve().relative_to(ROOT))
    except ValueError:
        spec_name = str(args.spec)
    result = {
        "benchmark": "dataset", "spec": spec_name, "tiny": args.tiny, "repeats": data.get("repeats", 1),
        "defines": data.get("defines"), "spp": data.get("spp"), "cores": int(CPU_COUNT),
        "cpu": _record.cpu_model(), "runs": runs,
    }
    print(json.dumps(result, indent=2))
    name = "dataset_" + Path(spec_name).stem + ("_tiny" if args.tiny else "")
    _record.maybe_save(args, name, result, load_start=load_start)
    return 0


if __name__ == "__main__":
    sys.exit(main())
