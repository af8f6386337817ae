"""The quadrature's settings on the paper scene: what visibility refinement, cells and element size buy.

Renders ``scenes/paper_mannequin.xml`` (``--array`` pixels, 2 x 2 spots, ``--bin-width-ps`` bins over the demo's
11.5 ns) with ``estimator=quadrature`` once per setting, in one process (JIT compiled by a first, untimed render),
and records per setting the render time and the rendering-error ratio the capture states at ``--exposure-ms`` per
spot with the paper's detector (``transient_mi.noise_target.quadrature_ratio``, as ``render --noise-target``
and ``detect`` compute it). The defaults of ``refine_levels`` (the plug-in's), ``element_size_m`` and
``patch_cells`` (the paper scene's, ``transient_mi.paper``) are chosen from it.

    python bench/bench_quadrature_settings.py --save
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _record  # noqa: E402

#: (refine_levels, element_size_m, patch_cells) per row; the first is the paper scene's default.
SETTINGS = ((1, 0.04, 1), (0, 0.04, 1), (2, 0.04, 1), (3, 0.04, 1), (1, 0.04, 2), (1, 0.04, 4), (1, 0.02, 1),
            (1, 0.01, 1))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--array", type=int, default=8)
    ap.add_argument("--bin-width-ps", type=float, default=8.0)
    ap.add_argument("--exposure-ms", type=float, default=10.0)
    _record.add_arguments(ap)
    a = ap.parse_args(argv)
    load_start = list(os.getloadavg())
    import transient_mi  # noqa: F401
    from transient_mi.noise_target import NoiseTargetSpec, TargetRun, quadrature_ratio
    from transient_mi.paper import PaperConfig, paper_detector, scene_file
    from transient_mi.render_capture import prepare_render

    cfg = PaperConfig(array=a.array, spots=2, bin_width_ps=a.bin_width_ps, n_bins=int(round(11500 / a.bin_width_ps)),
                      estimator="quadrature")
    spec = NoiseTargetSpec(target=0.1, params=paper_detector(), exposure_s=a.exposure_ms * 1e-3)
    with tempfile.TemporaryDirectory() as tmp:  # (nothing is written: the job gives the scene and its manifest)
        job = prepare_render(scene_file(), Path(tmp) / "q", defines=cfg.defines(), spp=1, seed=0, noise_target=spec)
    scene, integ, sensor = job.scene, job.integrator, job.sensor
    run = TargetRun(spec, job.manifest)
    rows = []
    for k, (rl, h, m) in enumerate(SETTINGS[:1] + SETTINGS):
        integ.nlos_options.update(refine_levels=rl, element_size_m=h, patch_cells=m)
        t = time.perf_counter()
        res = integ.render_transient(scene, sensor, seed=0, spp=1, spots=[0, 1, 2, 3])
        dt = time.perf_counter() - t
        if k == 0:
            continue  # JIT compilation
        ratio = max(quadrature_ratio(run, j, r) for j, r in enumerate(res))
        info = res[0].estimator_info
        row = {"refine_levels": rl, "element_size_m": h, "patch_cells": m, "render_s": round(dt, 2),
               f"ratio_at_{a.exposure_ms:g}ms": ratio, "elements": info["elements"],
               "coarse_elements": info["coarse_elements"], "pairs": info["pairs"]}
        print(row, file=sys.stderr, flush=True)
        rows.append(row)
    result = {"scene": "scenes/paper_mannequin.xml", "array": a.array, "spots": "2x2", "bin_width_ps": a.bin_width_ps,
              "exposure_ms": a.exposure_ms, "detector": "the paper's (transient_mi.paper.paper_detector)",
              "ratio": "rendering-error variance over photon variance, as detect states it (headline)", "rows": rows}
    _record.maybe_save(a, f"quadrature_settings_a{a.array}_b{a.bin_width_ps:g}", result, load_start=load_start)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
