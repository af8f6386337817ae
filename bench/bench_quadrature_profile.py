#!/usr/bin/env python3
"""Where the quadrature's render time goes: wall and CPU time per stage of one render.

Renders one capture by the quadrature through ``transient-mi render``'s pipeline (``render_capture.render``, the
capture written) in a fresh process, once untimed to compile, once timed, and records for the timed one the wall
and CPU time (every thread of the process) of each stage, taken by wrapping the functions that run it:

* ``levels``: each level's integration (:func:`~transient_mi.integrators._nlos_quadrature._level`: the fine one,
  the coarse one, and with one cell per patch the cells' level), and inside them
* ``bin masses and deposits`` (``spread_group``: every pair with every spot, the exact bin masses and the
  deposits), ``pair geometry`` (``pair_geometry``, with the test of which pairs can carry light), ``visibility rays``
  (``visibility_masks`` from the cells and ``spot_masks`` from the spots), ``laser-side knots`` (``spot_knots``);
* ``elements and visibility refinement`` (``level_elements``), ``error estimate`` (``discretisation_error`` and the
  cells' ``local_rms``), ``rounding residue`` (``finish_rows``: the residue cleared and the float32 copies);
* ``render call``: the whole ``render`` (setup, the quadrature, writing the capture and its error files).

Scenes: ``--scene letter`` (``scenes/nlos_letter.xml`` at its defaults: the README capture) or ``paper`` (the
paper scene at ``--array`` pixels, 2 x 2 spots, ``--bin-width-ps`` bins (default 1 ps) over the demo's 11.5 ns, its
quadrature defaults, or the settings ``--element-size-m``, ``--patch-cells`` and ``--refine-levels`` give; the
compiling render then has ``--warm-array`` pixels per side, default ``--array``).

    python bench/bench_quadrature_profile.py --scene letter --save
    python bench/bench_quadrature_profile.py --scene paper --save
    python bench/bench_quadrature_profile.py --scene paper --element-size-m 0.010346866916648621 --patch-cells 1 \
        --refine-levels 3 --warm-array 4 --save      # the demo's 32 x 32 capture at 1 s per spot
"""

from __future__ import annotations

import argparse
import collections
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _record  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
#: (module, function, stage) of every wrapped function; ``_level`` is recorded per call (fine, coarse, cells).
STAGES = (("_nlos_pairs", "spread_group", "bin masses and deposits"), ("_nlos_pairs", "pair_geometry", "pair geometry"),
          ("_nlos_pairs", "visibility_masks", "visibility rays"), ("_nlos_pairs", "spot_masks", "visibility rays"),
          ("_nlos_pairs", "spot_knots", "laser-side knots"),
          ("_nlos_quadrature", "level_elements", "elements and visibility refinement"),
          ("_nlos_quadrature", "discretisation_error", "error estimate"),
          ("_nlos_quadrature", "local_rms", "error estimate"),
          ("_nlos_quadrature", "finish_rows", "rounding residue"))
LEVELS = ("fine", "coarse", "cells")


class _Timer:
    """Wall and CPU seconds per stage, added up over the wrapped calls while ``on``."""

    def __init__(self):
        self.on = False
        self.t = collections.defaultdict(lambda: [0.0, 0.0, 0])
        self.level_calls = 0

    def wrap(self, mod, name: str, stage: str | None):
        f = getattr(mod, name)

        def timed(*a, **k):
            w, c = time.perf_counter(), time.process_time()
            try:
                return f(*a, **k)
            finally:
                if self.on:
                    key = stage
                    if key is None:  # a level: its place in the render
                        key = f"level: {LEVELS[min(self.level_calls, 2)]}"
                        self.level_calls += 1
                    e = self.t[key]
                    e[0] += time.perf_counter() - w
                    e[1] += time.process_time() - c
                    e[2] += 1

        setattr(mod, name, timed)


def _n_bins(bin_width_ps: float) -> int:
    """Bins of ``bin_width_ps`` over the demo's time window (``DemoSettings``: 11,500 bins of 1 ps)."""
    from transient_mi.paper import DemoSettings

    demo = DemoSettings()
    return int(round(demo.n_bins * demo.bin_width_ps / bin_width_ps))


def _settings(a) -> dict:
    """The quadrature settings the command line gives (``PaperConfig``'s names; empty: the scene's defaults)."""
    given = {"element_size_m": a.element_size_m, "patch_cells": a.patch_cells, "refine_levels": a.refine_levels}
    return {k: v for k, v in given.items() if v is not None}


def _defines(a, array: int | None = None) -> tuple[Path, dict]:
    if a.scene == "letter":
        return ROOT / "scenes" / "nlos_letter.xml", {}
    from transient_mi.paper import PaperConfig, scene_file

    cfg = PaperConfig(array=a.array if array is None else array, spots=2, spp=1024, bin_width_ps=a.bin_width_ps,
                      n_bins=_n_bins(a.bin_width_ps), estimator="quadrature").replace(**_settings(a))
    return Path(scene_file()), {k: str(v) for k, v in cfg.defines().items()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", choices=("letter", "paper"), default="letter")
    ap.add_argument("--array", type=int, default=32, help="paper scene only: pixels per side (default 32)")
    ap.add_argument("--bin-width-ps", type=float, default=1.0,
                    help="paper scene only: bin width over the demo's 11.5 ns (default 1; the dataset example's 8)")
    ap.add_argument("--element-size-m", type=float, help="paper scene only: quadrature element size (m)")
    ap.add_argument("--patch-cells", type=int, help="paper scene only: quadrature cells per patch side")
    ap.add_argument("--refine-levels", type=int, help="paper scene only: visibility refinement levels")
    ap.add_argument("--warm-array", type=int, help="paper scene only: pixels per side of the compiling render "
                                                   "(default --array)")
    _record.add_arguments(ap)
    a = ap.parse_args(argv)
    if a.scene == "letter" and (_settings(a) or a.warm_array is not None):
        ap.error("--element-size-m, --patch-cells, --refine-levels and --warm-array are for --scene paper")
    load_start = list(os.getloadavg())
    os.environ.setdefault("TRANSIENT_MI_PROGRESS", "0")
    import transient_mi  # noqa: F401
    from transient_mi.integrators import _nlos_pairs, _nlos_quadrature
    from transient_mi.render_capture import render

    mods = {"_nlos_pairs": _nlos_pairs, "_nlos_quadrature": _nlos_quadrature}
    timer = _Timer()
    for mod, name, stage in STAGES:
        timer.wrap(mods[mod], name, stage)
    timer.wrap(_nlos_quadrature, "_level", None)
    scene, defines = _defines(a)
    with tempfile.TemporaryDirectory(prefix="bench-qprofile-") as td:
        render(scene, Path(td) / "warm", defines=_defines(a, a.warm_array)[1], spp=1, seed=0,
               progress=False)  # JIT compilation
        timer.on = True
        w, c = time.perf_counter(), time.process_time()
        out = render(scene, Path(td) / "timed", defines=defines, spp=1, seed=0, progress=False)
        total = (time.perf_counter() - w, time.process_time() - c)
        timer.on = False
        import json

        info = json.loads((Path(out) / "manifest.json").read_text())["variance"]["settings"]
    stages = {k: {"wall_s": round(v[0], 2), "cpu_s": round(v[1], 2), "calls": v[2]}
              for k, v in sorted(timer.t.items(), key=lambda kv: -kv[1][1])}
    result = {"scene": str(scene.relative_to(ROOT)) if scene.is_relative_to(ROOT) else scene.name,
              "config": "the README capture (the scene's defaults)" if a.scene == "letter" else
              f"{a.array} x {a.array} pixels, 2 x 2 spots, {_n_bins(a.bin_width_ps):,} bins of {a.bin_width_ps:g} ps, "
              + (", ".join(f"{k} {v:g}" for k, v in _settings(a).items()) if _settings(a)
                 else "the scene's quadrature defaults"),
              "settings": info, "render_call": {"wall_s": round(total[0], 2), "cpu_s": round(total[1], 2)},
              "stages": stages,
              "note": "stages nest: the levels hold the bin masses, pair geometry (with the lit pairs' test), "
                      "visibility from the cells and knots; CPU is every thread of the process (numba's two)"}
    print(json.dumps(result, indent=1))
    name = (f"quadrature_profile_{a.scene}" + ("" if a.bin_width_ps == 1.0 else f"_{a.bin_width_ps:g}ps")
            + ("" if not _settings(a) else "_" + "_".join(f"{k.split('_')[0][0]}{k.split('_')[1][0]}{v:g}"
                                                            for k, v in _settings(a).items())))
    _record.maybe_save(a, name, result, load_start=load_start)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
