#!/usr/bin/env python3
"""Benchmark: the paper scene at the noise standard by each estimator (which one should be its default).

Renders ``scenes/paper_mannequin.xml`` (``--array`` pixels, 2 x 2 laser spots, ``--bin-width-ps`` bins over the
demo's 11.5 ns) to a noise target (``--target``, default 0.1) at ``--exposure-ms`` per spot with the paper's
detector, once by Monte Carlo (the scene's 1024-spp pilot, as the demo) and once by the quadrature (from
``--element-size-m`` and ``--patch-cells``, refined by ``render --noise-target``), one after the other in this
process, and prints one JSON object: per estimator the wall time of the render (JIT compilation included: a
first render in a fresh process) and its CPU time (every thread of this process: on a machine shared with other
work it moves less than the wall time), the samples or the quadrature's settings it ended with, and the ratio the
render states (``render.noise_target.spots``) and that ``detect`` states for the counts.

    python bench/bench_paper_estimators.py --array 4 --save
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _record  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def one(estimator: str, a, work: Path) -> dict:
    from spad_detector import detect_stack
    from transient_mi.noise_target import NoiseTargetSpec
    from transient_mi.paper import PaperConfig, paper_detector, scene_file
    from transient_mi.render_capture import prepare_render, run_render

    n_bins = int(round(11500 / a.bin_width_ps))
    cfg = PaperConfig(array=a.array, spots=2, spp=1024, bin_width_ps=a.bin_width_ps, n_bins=n_bins,
                      estimator=estimator)
    d = cfg.defines()
    if estimator == "quadrature":
        d.update(element_size_m=repr(a.element_size_m), patch_cells=str(a.patch_cells))
    params = paper_detector()
    spec = NoiseTargetSpec(target=a.target, params=params, exposure_s=a.exposure_ms * 1e-3)
    lines = []
    t, cpu = time.perf_counter(), time.process_time()
    job = prepare_render(scene_file(), work / estimator, defines=d, spp=cfg.spp, seed=0, noise_target=spec)
    ideal = run_render(job, progress=False, log=lines.append)
    wall, cpu = time.perf_counter() - t, time.process_time() - cpu
    counts = detect_stack(ideal, work / f"{estimator}_counts", params, exposure_s=a.exposure_ms * 1e-3, seed=1,
                          progress=False, warn=False)
    m = json.loads((Path(ideal) / "manifest.json").read_text())
    rn = json.loads((Path(counts) / "manifest.json").read_text())["detector"]["resolved"]["render_noise"]
    spots = m["render"]["noise_target"]["spots"]
    return {"estimator": m["render"]["estimator"], "render_wall_s": round(wall, 1),
            "render_cpu_s": round(cpu, 1),
            "spots": spots, "met": m["render"]["noise_target"]["met"],
            "render_noise_ratio_detect": rn["ratio"],
            "render_noise_ratio_pixel_totals": (rn.get("pixel_totals") or {}).get("ratio_pooled"), "log": lines}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--array", type=int, default=4)
    ap.add_argument("--exposure-ms", type=float, default=10.0)
    ap.add_argument("--target", type=float, default=0.1)
    ap.add_argument("--bin-width-ps", type=float, default=8.0)
    ap.add_argument("--element-size-m", type=float, default=None,
                    help="quadrature start (default: the paper scene's, transient_mi.paper.PAPER_ELEMENT_SIZE_M)")
    ap.add_argument("--patch-cells", type=int, default=None,
                    help="quadrature start (default: the paper scene's, transient_mi.paper.PAPER_PATCH_CELLS)")
    ap.add_argument("--only", choices=("monte_carlo", "quadrature"), default=None)
    _record.add_arguments(ap)
    a = ap.parse_args(argv)
    load_start = list(os.getloadavg())
    os.environ.setdefault("TRANSIENT_MI_PROGRESS", "0")
    import transient_mi  # noqa: F401
    from transient_mi.paper import PAPER_ELEMENT_SIZE_M, PAPER_PATCH_CELLS

    a.element_size_m = PAPER_ELEMENT_SIZE_M if a.element_size_m is None else a.element_size_m
    a.patch_cells = PAPER_PATCH_CELLS if a.patch_cells is None else a.patch_cells
    with tempfile.TemporaryDirectory(prefix="bench-paper-est-") as td:
        runs = [one(e, a, Path(td)) for e in ("monte_carlo", "quadrature") if a.only in (None, e)]
    result = {"benchmark": "paper scene at a noise target, by estimator", "array": a.array, "spots": "2x2",
              "bin_width_ps": a.bin_width_ps, "exposure_ms": a.exposure_ms, "target": a.target,
              "quadrature_start": {"element_size_m": a.element_size_m, "patch_cells": a.patch_cells},
              "detector": "the paper's (transient_mi.paper.paper_detector)", "runs": runs}
    print(json.dumps(result, indent=1))
    _record.maybe_save(a, f"paper_estimators_a{a.array}_e{a.exposure_ms:g}ms", result, load_start=load_start)
    return 0


if __name__ == "__main__":
    sys.exit(main())
