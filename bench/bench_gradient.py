#!/usr/bin/env python3
"""Benchmark: one reverse-mode gradient of an NLOS capture against the primal render at the same spp.

Scene: ``scenes/nlos_letter.xml``, confocal capture, 32 x 32 pixels of 15 mm, 512 bins (16 ps), three-bounce light
(max_depth 4), ``hidden_geometry_prob = 1``, a temporal kernel of 32 ps. The loss is ``sum(w * capture)``
(fixed random weights); its gradient is taken with respect to

* ``bsdf``: the letter's three reflectances, the relay wall's reflectance and the laser's pulse energy;
* ``geometry``: additionally a translation of the letter's stem (its ``to_world``), which adds the arrival-time
  derivative through the temporal kernel;
* ``bsdf_depth8``: as ``bsdf`` with ``max_depth = 8`` (up to seven-bounce light; the deeper vertices by path
  replay), primal at the same depth.

The primal render (``render_transient``) and the gradient (``render_backward``, same seed and spp) of each
configuration run in separate processes: load, one untimed call (JIT compilation), then ``rounds`` timed
calls; the best is kept. Peak memory: the process's ``VmHWM`` (``peak_rss_mb``, which includes Python,
Mitsuba and the scene) and its increase over the resident set after loading (``working_mb``: what the
render or the gradient itself needs). Targets (issue 14): gradient / primal <= 3 in time and in peak memory.

    python bench/bench_gradient.py --save        # 32x32 confocal, 512 bins, 256 spp
    python bench/bench_gradient.py --small       # CI-sized
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
BSDF_KEYS = ("letter_stem.bsdf.reflectance.value", "letter_top.bsdf.reflectance.value",
             "letter_middle.bsdf.reflectance.value", "relay_wall.bsdf.reflectance.value")


def _worker(config: str, mode: str, size: int, bins: int, bin_width: float, spp: int, rounds: int) -> dict:
    import numpy as np

    import transient_mi  # noqa: F401  (before mitsuba)
    import drjit as dr
    import mitsuba as mi

    from transient_mi.scene_io import load_scene

    scene = load_scene(ROOT / "scenes" / "nlos_letter.xml",
                       {"width": str(size), "height": str(size), "n_bins": str(bins), "capture": "confocal",
                        "spp": str(spp), "max_depth": "8" if config == "bsdf_depth8" else "4",
                        "bin_width_ps": str(bin_width),
                        "pixel_footprint_m": "0.015", "estimator": "monte_carlo"})  # Monte Carlo's AD
    sensor = scene.sensors()[0]
    sensor.film().kernel_sigma_ps = 32.0
    integ = scene.integrator()
    integ.nlos_options["hidden_geometry_prob"] = 1.0
    params = mi.traverse(scene)
    keys = list(BSDF_KEYS) + [k for k in params.keys() if k.endswith(".pulse_energy_j")]
    th = None
    if mode == "gradient":
        for k in keys:
            dr.enable_grad(params[k])
        if config == "geometry":
            th = mi.Float(0.0)
            dr.enable_grad(th)
            params["letter_stem.to_world"] = mi.Transform4f().translate(mi.Vector3f(th, 0, 0)) @ \
                mi.Transform4f(params["letter_stem.to_world"])
        params.update()
    w = mi.TensorXf(np.random.default_rng(1).random((size, size, bins)).astype(np.float32))

    def primal():
        integ.render_transient(scene, sensor, seed=3, spp=spp)

    def gradient():
        integ.render_backward(scene, params, w, sensor, 3, spp)
        dr.eval(*[dr.grad(params[k]) for k in keys])

    fn = primal if mode == "primal" else gradient
    rss0 = _record.rss_mb()
    _record.reset_peak_rss()
    fn()  # compilation
    best = None
    for _ in range(rounds):
        t = time.perf_counter()
        fn()
        dt = time.perf_counter() - t
        best = dt if best is None else min(best, dt)
    peak = _record.peak_rss_mb()
    out = {"best_s": round(best, 4), "peak_rss_mb": round(peak, 1), "rss_before_mb": round(rss0, 1),
           "working_mb": round(peak - rss0, 1)}
    if mode == "gradient":
        out["gradients"] = {k: float(np.asarray(dr.grad(params[k])).ravel()[0]) for k in keys}
        if th is not None:
            out["gradients"]["letter_stem.translate_x"] = float(dr.grad(th)[0])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", type=int, default=32)
    ap.add_argument("--bins", type=int, default=512)
    ap.add_argument("--bin-width", type=float, default=16.0, help="ps")
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--small", action="store_true")
    ap.add_argument("--worker", nargs=2, metavar=("CONFIG", "MODE"), help=argparse.SUPPRESS)
    _record.add_arguments(ap)
    a = ap.parse_args()
    if a.small:
        a.size, a.bins, a.bin_width, a.spp, a.rounds = 8, 128, 64.0, 8, 1
    if a.worker:
        print("JSON" + json.dumps(_worker(a.worker[0], a.worker[1], a.size, a.bins, a.bin_width, a.spp, a.rounds)))
        return
    load_start = list(os.getloadavg())
    runs = {}
    for config in ("bsdf", "geometry", "bsdf_depth8"):
        r = {}
        for mode in ("primal", "gradient"):
            cmd = [sys.executable, __file__, "--worker", config, mode, "--size", str(a.size), "--bins", str(a.bins),
                   "--bin-width", str(a.bin_width), "--spp", str(a.spp), "--rounds", str(a.rounds)]
            out = subprocess.run(cmd, capture_output=True, text=True, check=True,
                                 env=dict(os.environ, TRANSIENT_MI_PROGRESS="0"))
            r[mode] = json.loads([x for x in out.stdout.splitlines() if x.startswith("JSON")][-1][4:])
        p, g = r["primal"], r["gradient"]
        r["time_ratio"] = round(g["best_s"] / p["best_s"], 2)
        r["peak_rss_ratio"] = round(g["peak_rss_mb"] / p["peak_rss_mb"], 2)
        r["working_memory_ratio"] = round(g["working_mb"] / max(p["working_mb"], 0.1), 2)
        runs[config] = r
    result = {
        "benchmark": "reverse-mode gradient vs primal: transient_nlos_path, scenes/nlos_letter.xml confocal",
        "cpu_count": os.cpu_count(),
        "settings": {"size": a.size, "bins": a.bins, "bin_width_ps": a.bin_width, "spp": a.spp,
                     "rounds": a.rounds, "max_depth": {"bsdf": 4, "geometry": 4, "bsdf_depth8": 8},
                     "kernel_sigma_ps": 32.0, "hidden_geometry_prob": 1.0,
                     "warm_policy": "one untimed call of each first (compilation); best round kept"},
        "targets": {"time_ratio_max": 3.0, "peak_rss_ratio_max": 3.0},
        "runs": runs,
    }
    print(json.dumps(result, indent=1))
    _record.maybe_save(a, "gradient_small" if a.small else "gradient", result, load_start=load_start)


if __name__ == "__main__":
    main()
