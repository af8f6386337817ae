"""The quadrature's settings on an embedded scene: what visibility refinement, cells and element size buy.

Renders a scene with ``estimator=quadrature`` once per setting, in one process (JIT compiled by a first, untimed
render), and records per setting the render time and the rendering-error ratio the capture states at
``--exposure-ms`` per spot (``transient_mi.noise_target_quadrature.quadrature_ratio``, as ``render --noise-target`` and
``detect`` compute it). The scenes' defaults are chosen from it:

* ``--scene paper`` (the default): ``scenes/paper_mannequin.xml``, ``--array`` pixels, 2 x 2 spots,
  ``--bin-width-ps`` bins over the demo's 11.5 ns, the paper's detector; ``refine_levels`` (the plug-in's),
  ``element_size_m`` and ``patch_cells`` (the paper scene's, ``transient_mi.paper``);
* ``--scene letter`` / ``tilted_plane``: ``scenes/nlos_letter.xml`` / ``nlos_tilted_plane.xml`` at their own
  defaults (4 x 4 spots, 512 bins of 16 ps, wall return on) but ``--array`` pixels, the paper's detector defaults
  with ``--auto-gate`` (as ``bench_quadrature.py``); the scene files' ``element_size_m`` and ``patch_cells``.

    python bench/bench_quadrature_settings.py --save
    python bench/bench_quadrature_settings.py --scene letter --save
    python bench/bench_quadrature_settings.py --scene tilted_plane --save
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

ROOT = Path(__file__).resolve().parents[1]
#: (refine_levels, element_size_m, patch_cells) per row (paper: the first is the scene's default; the letter's and the
#: tilted plane's defaults, in their scene files, were chosen from these rows: docs/quadrature.md marks them).
SETTINGS = {
    "paper": ((1, 0.04, 1), (0, 0.04, 1), (2, 0.04, 1), (3, 0.04, 1), (1, 0.04, 2), (1, 0.04, 4), (1, 0.02, 1),
              (1, 0.01, 1)),
    "letter": ((1, 0.01, 6), (1, 0.009, 6), (1, 0.011, 6), (1, 0.012, 6), (1, 0.01, 4), (1, 0.01, 8), (1, 0.008, 6),
               (1, 0.014, 6), (1, 0.02, 8), (1, 0.01, 3), (1, 0.01, 2), (1, 0.01, 1), (1, 0.009, 4), (1, 0.008, 4),
               (1, 0.007, 4)),
    "tilted_plane": ((1, 0.007, 4), (1, 0.008, 4), (1, 0.009, 4), (1, 0.01, 4), (1, 0.01, 6), (1, 0.01, 8),
                     (1, 0.0125, 6), (1, 0.005, 4), (1, 0.02, 8), (1, 0.007, 2), (1, 0.006, 2), (1, 0.005, 2)),
}
SCENE_FILES = {"letter": "scenes/nlos_letter.xml", "tilted_plane": "scenes/nlos_tilted_plane.xml"}


def _paper_job(a, spec, tmp):
    from transient_mi.paper import PaperConfig, scene_file
    from transient_mi.render_capture import prepare_render

    cfg = PaperConfig(array=a.array, spots=2, bin_width_ps=a.bin_width_ps, n_bins=int(round(11500 / a.bin_width_ps)),
                      estimator="quadrature")
    return prepare_render(scene_file(), Path(tmp) / "q", defines=cfg.defines(), spp=1, seed=0, noise_target=spec)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", choices=sorted(SETTINGS), default="paper")
    ap.add_argument("--array", type=int, default=8, help="pixels per side (default 8)")
    ap.add_argument("--bin-width-ps", type=float, default=8.0, help="paper scene only (default 8)")
    ap.add_argument("--exposure-ms", type=float, default=10.0)
    ap.add_argument("--settings", nargs="+", metavar="RL,H,M",
                    help="rows to render instead of the scene's table: refine_levels,element_size_m,patch_cells")
    _record.add_arguments(ap)
    a = ap.parse_args(argv)
    load_start = list(os.getloadavg())
    import transient_mi  # noqa: F401
    from spad_detector import DetectorParams
    from transient_mi.noise_target import NoiseTargetSpec, TargetRun
    from transient_mi.noise_target_quadrature import quadrature_ratio
    from transient_mi.paper import paper_detector
    from transient_mi.render_capture import prepare_render

    paper = a.scene == "paper"
    params = paper_detector() if paper else DetectorParams(auto_gate=True)
    spec = NoiseTargetSpec(target=0.1, params=params, exposure_s=a.exposure_ms * 1e-3)
    with tempfile.TemporaryDirectory() as tmp:  # (nothing is written: the job gives the scene and its manifest)
        if paper:
            job = _paper_job(a, spec, tmp)
        else:
            job = prepare_render(ROOT / SCENE_FILES[a.scene], Path(tmp) / "q",
                                 defines={"estimator": "quadrature", "width": a.array, "height": a.array}, spp=1,
                                 seed=0, noise_target=spec)
    scene, integ, sensor = job.scene, job.integrator, job.sensor
    run = TargetRun(spec, job.manifest)
    spots = list(range(job.manifest["n_files"])) if "n_files" in job.manifest else [0, 1, 2, 3]
    settings = SETTINGS[a.scene] if not a.settings else tuple(
        (int(r), float(h), int(m)) for r, h, m in (x.split(",") for x in a.settings))
    rows = []
    for k, (rl, h, m) in enumerate(settings[:1] + settings):
        integ.nlos_options.update(refine_levels=rl, element_size_m=h, patch_cells=m)
        t = time.perf_counter()
        res = integ.render_transient(scene, sensor, seed=0, spp=1, spots=spots)
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
    if paper:
        result = {"scene": "scenes/paper_mannequin.xml", "array": a.array, "spots": "2x2",
                  "bin_width_ps": a.bin_width_ps, "exposure_ms": a.exposure_ms,
                  "detector": "the paper's (transient_mi.paper.paper_detector)"}
        name = f"quadrature_settings_a{a.array}_b{a.bin_width_ps:g}"
    else:
        tm = job.manifest["time"]
        result = {"scene": SCENE_FILES[a.scene], "array": a.array, "spots": f"{len(spots)} (the scene's 4x4)",
                  "bin_width_ps": tm["bin_width_ps"], "exposure_ms": a.exposure_ms,
                  "detector": "paper's defaults, --auto-gate", "wall_return": "on (the scene's default)"}
        name = f"quadrature_settings_{a.scene}_a{a.array}"
    result.update(ratio="rendering-error variance over photon variance, as detect states it (headline)", rows=rows)
    _record.maybe_save(a, name, result, load_start=load_start)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
