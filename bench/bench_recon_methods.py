"""Benchmark: every method that reconstructs array captures, at 64^3 voxels (time and peak memory per method).

Capture (closed form, :func:`recon.synthetic.point_capture`, no renderer): the
paper's geometry, a 32x32 SPAD array tiling the 1 m relay wall, 2x2 laser
spots at (+-0.25, +-0.25) m, four point targets in the paper's volume, 4 ps
bins covering every path (plus 8 bins each side), 25 ps FWHM timing blur.
Volume: the paper's bounds (x, y in [-0.5, 0.5] m, z in [0.25, 0.75] m),
64 x 64 x 64 voxels, the paper's filter with each method's default threshold.

Each method runs in a fresh child process (so ``ru_maxrss``, the peak
resident set of that process with Python, numpy, scipy and numba loaded, is
per method): one untimed warm-up call on the same capture (numba compiles or
loads its cache; recorded as ``first_call_s``), then ``--repeat`` timed calls
of :func:`recon.reconstruct` (every repeat recorded, wall clock).

Writes one JSON document (``--out``, default stdout): command, machine, date,
the goal (<= 2 s, <= 1 GB on 2 cores) and per method every repeat.
``--small`` shrinks everything (8x8 pixels, 16^3 voxels) for CI.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import resource
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
METHODS = ("bp", "fbp", "phasor", "midpoint-lct", "midpoint-fk")
POINTS = [[0.1, -0.05, 0.5], [-0.2, 0.2, 0.4], [0.0, 0.0, 0.7], [0.25, 0.15, 0.6]]
BOUNDS = (-0.5, 0.5, -0.5, 0.5, 0.25, 0.75)
GOAL = {"time_s": 2.0, "peak_rss_gb": 1.0}


def _capture(small: bool):
    import numpy as np

    from recon.synthetic import point_capture, wall_grid

    spots = wall_grid(2, 2, 0.5).reshape(-1, 3)
    return point_capture(POINTS, pixels=8 if small else 32, wall_size_m=1.0, spots=spots, spot_grid=(2, 2),
                         bin_width_ps=16.0 if small else 4.0, sigma_ps=25.0 / (2 * np.sqrt(2 * np.log(2))))


def child(method: str, small: bool, repeat: int) -> dict:
    import time

    import recon

    cap = _capture(small)
    cap.data
    n = 16 if small else 64
    t0 = time.perf_counter()
    recon.reconstruct(cap, method, bounds=BOUNDS, voxels=n)
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        rec = recon.reconstruct(cap, method, bounds=BOUNDS, voxels=n)
        times.append(time.perf_counter() - t0)
    return {"method": method, "times_s": times, "best_s": min(times), "first_call_s": first,
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
            "shape_zyx": list(rec.volume.shape), "capture": cap.describe()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--small", action="store_true")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child:
        print(json.dumps(child(a.child, a.small, a.repeat)))
        return 0
    load_start = os.getloadavg()
    env = dict(os.environ, TRANSIENT_MI_PROGRESS="0")
    results = []
    for m in a.methods.split(","):
        cmd = [sys.executable, str(Path(__file__).resolve()), "--child", m, "--repeat", str(a.repeat)]
        r = subprocess.run(cmd + (["--small"] if a.small else []), capture_output=True, text=True, env=env,
                           cwd=ROOT)
        if r.returncode != 0:
            results.append({"method": m, "status": "failed", "stderr": r.stderr[-2000:]})
            continue
        res = json.loads(r.stdout.strip().splitlines()[-1])
        res["status"] = "ok"
        res["meets_goal"] = (res["best_s"] <= GOAL["time_s"] and res["peak_rss_mb"] <= GOAL["peak_rss_gb"] * 1024)
        results.append(res)
    doc = {
        "benchmark": "recon_methods",
        "command": "python bench/bench_recon_methods.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "date_utc": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "machine": {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
                    "cpu_count": os.cpu_count(), "python": platform.python_version(),
                    "load_average_1min_start": round(load_start[0], 2),
                    "load_average_1_5_15_at_end": list(os.getloadavg())},
        "small": a.small, "repeat": a.repeat, "voxels": 16 if a.small else 64, "bounds_m": list(BOUNDS),
        "goal": GOAL, "results": results,
    }
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import _record

    doc = _record.as_record(Path(a.out).stem if a.out else "recon_methods", doc)
    text = json.dumps(doc, indent=1) + "\n"
    if a.out is not None:
        sys.path.insert(0, str(ROOT))
        from transient_core.atomic import atomic_file

        with atomic_file(a.out) as tmp:
            Path(tmp).write_text(text)
    else:
        sys.stdout.write(text)
    return 0 if all(r["status"] == "ok" for r in results) else 1


if __name__ == "__main__":
    raise SystemExit(main())
