#!/usr/bin/env python3
"""Benchmark: ``transient_volpath`` vs Mitsuba's ``volpath`` on the same fog scene and spp.

The scene is ``scenes/fog_camera.xml`` (camera in homogeneous fog, floor, wall, a lamp in the fog);
Mitsuba's run loads the same file with ``volpath`` and an ``hdrfilm`` in place of the transient
integrator and film (both with the film's default reconstruction filter, Mitsuba's ``gaussian``). In
one process, each round renders each integrator twice with the same seed and times the second render
(the first compiles the kernels); rounds alternate the two, and the best round of each is kept
(background load then hurts both alike). Prints one JSON object: paths per
second of each, the throughput ratio transient/volpath (goal >= 0.70) and every round's ratio.

    python bench/bench_volpath.py --save          # 128x128, 1000 bins, 64 spp, max_depth 8
    python bench/bench_volpath.py --small         # CI-sized
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _record  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "fog_camera.xml"


def _load(kind: str, size: int, bins: int, max_depth: int):
    import mitsuba as mi

    params = {"width": str(size), "height": str(size), "max_depth": str(max_depth)}
    if kind == "transient":
        return mi.load_file(str(SCENE), n_bins=str(bins), **params)
    xml = SCENE.read_text()
    xml = xml.replace('<integrator type="transient_volpath">', '<integrator type="volpath">')
    xml, n = re.subn(r'<film type="transient_film">.*?</film>',
                     '<film type="hdrfilm"><integer name="width" value="$width"/>'
                     '<integer name="height" value="$height"/><string name="pixel_format" value="luminance"/>'
                     '</film>', xml, flags=re.S)
    assert n == 1, "scenes/fog_camera.xml: expected one transient_film"
    return mi.load_string(xml, **params)


def _timed(kind: str, scene, spp: int, seed: int) -> float:
    import drjit as dr
    import mitsuba as mi

    t = time.perf_counter()
    if kind == "transient":
        integ = scene.integrator()
        integ.render_transient(scene, scene.sensors()[0], seed=seed, spp=spp)
    else:
        img = mi.render(scene, spp=spp, seed=seed)
        dr.eval(img)
        img.numpy()
    return time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--bins", type=int, default=1000)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--max-depth", type=int, default=8)
    ap.add_argument("--rounds", type=int, default=3, help="alternating volpath/transient rounds")
    ap.add_argument("--small", action="store_true", help="tiny sizes for CI")
    _record.add_arguments(ap)
    a = ap.parse_args()
    if a.small:
        a.size, a.bins, a.spp, a.rounds = 16, 64, 4, 1
    os.environ.setdefault("TRANSIENT_MI_PROGRESS", "0")
    load_start = list(os.getloadavg())
    import transient_mi  # noqa: F401  (first: LLVM + plug-ins)
    import mitsuba as mi

    scenes = {k: _load(k, a.size, a.bins, a.max_depth) for k in ("volpath", "transient")}
    paths = a.size * a.size * a.spp
    runs = {"volpath": [], "transient": []}
    for r in range(a.rounds):
        for kind in ("volpath", "transient"):
            first = _timed(kind, scenes[kind], a.spp, seed=r)
            second = _timed(kind, scenes[kind], a.spp, seed=r)
            runs[kind].append({"first_render_s": round(first, 4), "timed_render_s": round(second, 4),
                               "paths_per_s": paths / second})
    best = {k: max(v, key=lambda x: x["paths_per_s"]) for k, v in runs.items()}
    ratio = best["transient"]["paths_per_s"] / best["volpath"]["paths_per_s"]
    result = {
        "benchmark": "transient_volpath vs volpath (scenes/fog_camera.xml, " + mi.variant() + ")",
        "cpu_count": os.cpu_count(),
        "settings": {"size": a.size, "bins": a.bins, "spp": a.spp, "max_depth": a.max_depth, "rounds": a.rounds,
                     "warm_policy": "each render twice with the same seed, the second timed; best round kept"},
        "volpath": best["volpath"],
        "transient_volpath": best["transient"],
        "all_runs": runs,
        "throughput_ratio": round(ratio, 3),
        "throughput_ratio_per_round": [round(t["paths_per_s"] / p["paths_per_s"], 3)
                                       for p, t in zip(runs["volpath"], runs["transient"])],
        "goal_ratio": 0.70,
        "meets_goal": ratio >= 0.70,
        "peak_rss_mb": round(_record.peak_rss_mb(), 1),
    }
    print(json.dumps(result, indent=1))
    _record.maybe_save(a, "volpath_small" if a.small else "volpath", result, load_start=load_start)


if __name__ == "__main__":
    main()
