#!/usr/bin/env python3
"""Benchmark: ``transient_path`` vs Mitsuba's ``path`` on the same scene and spp.

Prints one JSON object: for each integrator the paths per second (best of
``--repeats`` timed renders after a warm-up render that compiles the kernel,
best over ``--rounds`` alternating fresh processes),
the throughput ratio transient/path (goal >= 0.70), and the peak resident
memory of a fresh process rendering a ``--size`` x ``--size`` x ``--bins``
transient film (each measurement runs in its own child process).

    python bench/bench_integrator.py               # 256x256, 1024 bins, 64 spp
    python bench/bench_integrator.py --small       # CI-sized
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _record  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def _scene(kind: str, size: int, bins: int, max_depth: int):
    import mitsuba as mi

    cb = mi.cornell_box()
    if kind == "transient":
        cb["sensor"]["film"] = {"type": "transient_film", "width": size, "height": size, "n_bins": bins,
                                "bin_width_ps": 30.0 * 1024 / bins, "t0_ps": 10000.0,
                                "rfilter": {"type": "box"}}  # as the hdrfilm below (and as before filters were honoured)
        cb["integrator"] = {"type": "transient_path", "max_depth": max_depth}
    else:
        cb["sensor"]["film"] = {"type": "hdrfilm", "width": size, "height": size, "rfilter": {"type": "box"},
                                "pixel_format": "luminance"}
        cb["integrator"] = {"type": "path", "max_depth": max_depth}
    return mi.load_dict(cb)


def child(kind: str, size: int, bins: int, spp: int, max_depth: int, repeats: int) -> dict:
    """Run inside a fresh process: time renders, report peak RSS."""
    import transient_mi  # noqa: F401  (first: LLVM for drjit, plug-ins)
    import drjit as dr
    import mitsuba as mi

    scene = _scene(kind, size, bins, max_depth)
    integ = scene.integrator()
    sensor = scene.sensors()[0]

    def once(seed):
        if kind == "transient":
            integ.render_transient(scene, sensor, seed=seed, spp=spp)
        else:
            img = mi.render(scene, spp=spp, seed=seed)
            dr.eval(img)
            img.numpy()

    t = time.perf_counter()
    once(0)  # compile
    first = time.perf_counter() - t
    times = []
    for r in range(repeats):
        t = time.perf_counter()
        once(r + 1)
        times.append(time.perf_counter() - t)
    best = min(times)
    paths = size * size * spp
    return {
        "integrator": "transient_path" if kind == "transient" else "path",
        "film": f"{size}x{size}" + (f"x{bins}" if kind == "transient" else ""),
        "spp": spp,
        "first_render_s": round(first, 4),
        "best_render_s": round(best, 4),
        "render_s": [round(x, 4) for x in times],
        "paths_per_s": paths / best,
        "peak_rss_mb": _record.peak_rss_mb(),
    }


def run_child(args: list[str]) -> dict:
    env = dict(os.environ, TRANSIENT_MI_PROGRESS="0", PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run([sys.executable, __file__, "--child", *args], capture_output=True, text=True, env=env,
                         check=False)
    if out.returncode != 0:
        raise SystemExit(f"benchmark child failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def readme_example(spp: int = 512) -> dict:
    """The README's first example, as a user runs it: wall time of the command, its render time, VmHWM."""
    import tempfile

    with tempfile.TemporaryDirectory(prefix="bench-cornell-") as td:
        out = Path(td) / "cornell_box"
        env = dict(os.environ, TRANSIENT_MI_PROGRESS="0")
        r = _record.run_measured(["transient_mi", "render", "scenes/cornell_box.xml", "-o", str(out),
                                  "--spp", str(spp)], cwd=ROOT, env=env, log=Path(td) / "log.txt")
        if r["returncode"] != 0:
            return {"status": "failed", "output": (Path(td) / "log.txt").read_text()[-2000:]}
        manifest = json.loads((out / "manifest.json").read_text())
    return {"status": "ok", "command": f"transient-mi render scenes/cornell_box.xml -o OUT --spp {spp}",
            "wall_s": round(r["wall_s"], 2), "peak_rss_mb": round(r["peak_rss_mb"], 1),
            "render_time_s": (manifest.get("render") or {}).get("render_time_s")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--bins", type=int, default=1024)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--max-depth", type=int, default=8)
    ap.add_argument("--repeats", type=int, default=3, help="timed renders per process")
    ap.add_argument("--rounds", type=int, default=2, help="alternating path/transient processes")
    ap.add_argument("--small", action="store_true", help="tiny sizes for CI")
    ap.add_argument("--no-readme-example", action="store_true",
                    help="skip timing the README's example (transient-mi render scenes/cornell_box.xml --spp 512)")
    _record.add_arguments(ap)
    ap.add_argument("--child", nargs=6, metavar=("KIND", "SIZE", "BINS", "SPP", "DEPTH", "REPEATS"),
                    help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        kind, size, bins, spp, depth, reps = a.child
        print(json.dumps(child(kind, int(size), int(bins), int(spp), int(depth), int(reps))))
        return
    if a.small:
        a.size, a.bins, a.spp, a.repeats, a.rounds = 32, 64, 4, 1, 1
    load_start = list(os.getloadavg())
    common = [str(a.size), str(a.bins), str(a.spp), str(a.max_depth), str(a.repeats)]
    # Alternate fresh processes and keep each one's best: background load then hurts both alike.
    runs = {"path": [], "transient": []}
    for _ in range(a.rounds):
        for kind in ("path", "transient"):
            runs[kind].append(run_child([kind, *common]))
    path = max(runs["path"], key=lambda r: r["paths_per_s"])
    trans = max(runs["transient"], key=lambda r: r["paths_per_s"])
    trans["peak_rss_mb"] = max(r["peak_rss_mb"] for r in runs["transient"])
    ratio = trans["paths_per_s"] / path["paths_per_s"]
    # the ratio of each round's pair (both measured back to back) shows how much the load moved it
    round_ratios = [t["paths_per_s"] / p["paths_per_s"] for p, t in zip(runs["path"], runs["transient"])]
    result = {
        "benchmark": "transient_path vs path (Cornell box, llvm_ad_mono)",
        "cpu_count": os.cpu_count(),
        "settings": {"size": a.size, "bins": a.bins, "spp": a.spp, "max_depth": a.max_depth, "repeats": a.repeats,
                     "rounds": a.rounds},
        "path": path,
        "transient_path": trans,
        "all_runs": runs,
        "throughput_ratio": round(ratio, 3),
        "throughput_ratio_per_round": [round(r, 3) for r in round_ratios],
        "goal_ratio": 0.70,
        "meets_goal": ratio >= 0.70,
        "film_memory_mb": round(trans["peak_rss_mb"], 1),
        "film_bytes": a.size * a.size * a.bins * 4,
        "peak_rss_path_mb": round(max(r["peak_rss_mb"] for r in runs["path"]), 1),
    }
    if not a.small and not a.no_readme_example:
        result["readme_example"] = readme_example()
    print(json.dumps(result, indent=1))
    _record.maybe_save(a, "integrator_small" if a.small else "integrator", result, load_start=load_start)


if __name__ == "__main__":
    main()
