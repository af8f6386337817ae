#!/usr/bin/env python3
"""Benchmark: what colour and polarization per time bin cost over one value per bin.

The same camera render (``scenes/cornell_box.xml``, ``transient_path``) in ``llvm_ad_mono`` (one value
per bin), ``llvm_ad_rgb`` (R, G, B per bin), ``llvm_ad_mono_polarized`` (Stokes S0..S3 per bin),
``llvm_ad_spectral`` (R, G, B per bin, and six 50 nm wavelength bands per bin) and,
for reference, ``llvm_ad_rgb`` with ``channels=mono`` (the rgb variant's transport, one value per bin):
the variant's own transport cost and the per-bin channels' cost can be told apart. Each variant runs in
its own process (one Mitsuba variant per process); in each, every round renders twice with the same
seed and times the second render (the first compiles); the best round is kept. Prints one JSON object
with paths per second per configuration and the overhead of each over mono.

    python bench/bench_channels.py --save        # 128x128, 512 bins, 32 spp
    python bench/bench_channels.py --small       # CI-sized
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
CONFIGS = [("mono", "llvm_ad_mono", "auto"), ("rgb", "llvm_ad_rgb", "auto"),
           ("rgb_transport_mono_bins", "llvm_ad_rgb", "mono"), ("stokes", "llvm_ad_mono_polarized", "auto"),
           ("spectral_rgb", "llvm_ad_spectral", "auto"), ("spectral_bands", "llvm_ad_spectral", "bands")]
#: the wavelength bands of the ``spectral_bands`` configuration (film parameter ``spectral_bands_nm``)
BANDS_NM = "400, 450, 500, 550, 600, 650, 700"


def _worker(variant: str, channels: str, size: int, bins: int, spp: int, rounds: int) -> dict:
    os.environ["TRANSIENT_MI_VARIANT"] = variant
    import transient_mi  # noqa: F401
    import mitsuba as mi

    bands = BANDS_NM if channels == "bands" else ""
    scene = mi.load_file(str(ROOT / "scenes" / "cornell_box.xml"), width=str(size), height=str(size),
                         n_bins=str(bins), t0_ps="10000", bin_width_ps="60", max_depth="6", spectral_bands_nm=bands)
    film = scene.sensors()[0].film()
    film.channels = "auto" if channels == "bands" else channels
    best = None
    for r in range(rounds):
        for k in range(2):
            t = time.perf_counter()
            res = scene.integrator().render_transient(scene, scene.sensors()[0], seed=r, spp=spp)
            dt = time.perf_counter() - t
        best = dt if best is None else min(best, dt)
    return {"variant": variant, "channels": channels, "histogram_shape": list(res.histogram.shape),
            "best_render_s": round(best, 4), "paths_per_s": size * size * spp / best,
            "peak_rss_mb": round(_record.peak_rss_mb(), 1)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--bins", type=int, default=512)
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--small", action="store_true")
    ap.add_argument("--worker", nargs=2, metavar=("VARIANT", "CHANNELS"), help=argparse.SUPPRESS)
    _record.add_arguments(ap)
    a = ap.parse_args()
    if a.small:
        a.size, a.bins, a.spp, a.rounds = 16, 64, 4, 1
    if a.worker:
        print("JSON" + json.dumps(_worker(a.worker[0], a.worker[1], a.size, a.bins, a.spp, a.rounds)))
        return
    load_start = list(os.getloadavg())
    runs = {}
    for name, variant, channels in CONFIGS:
        cmd = [sys.executable, __file__, "--worker", variant, channels, "--size", str(a.size), "--bins",
               str(a.bins), "--spp", str(a.spp), "--rounds", str(a.rounds)]
        out = subprocess.run(cmd, capture_output=True, text=True, check=True, env=dict(os.environ,
                             TRANSIENT_MI_PROGRESS="0"))
        runs[name] = json.loads([x for x in out.stdout.splitlines() if x.startswith("JSON")][-1][4:])
    mono = runs["mono"]["best_render_s"]
    result = {
        "benchmark": "channels per time bin: transient_path, scenes/cornell_box.xml",
        "cpu_count": os.cpu_count(),
        "settings": {"size": a.size, "bins": a.bins, "spp": a.spp, "rounds": a.rounds, "max_depth": 6,
                     "warm_policy": "each render twice with the same seed, the second timed; best round kept"},
        "runs": runs,
        "overhead_over_mono": {k: round(v["best_render_s"] / mono - 1.0, 3) for k, v in runs.items() if k != "mono"},
    }
    print(json.dumps(result, indent=1))
    _record.maybe_save(a, "channels_small" if a.small else "channels", result, load_start=load_start)


if __name__ == "__main__":
    main()
