#!/usr/bin/env python3
"""How many elements the quadrature's visibility refinement splits, by rule: the paper scene's fine elements at
``--array`` pixels and ``--element-size-m``, tested once from the coarse level's cells and every laser spot
(:func:`transient_mi.integrators._nlos_refinement.mixed_elements`), counted under three rules on the same traced
masks:

* ``any``: the samples seen partly from some cell alone or some spot alone (the rule before 2026-12-05);
* ``combined``: some (cell, spot) pair sees them partly, the two masks combined (the samples seen from both);
* ``lit`` (the rule in use): ``combined`` for the pairs that can carry light, the cell and the spot on one side of a
  Lambertian element's shading normal (:func:`transient_mi.integrators._nlos_refinement.mixed_lit`).

    python bench/bench_refinement_rule.py --save   # bench/results/refinement_rule.json
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _record  # noqa: E402


def measure(array: int, h: float) -> dict:
    import transient_mi  # noqa: F401  (before mitsuba: its LLVM)
    import mitsuba as mi
    import numpy as np

    from transient_mi.integrators import _nlos_quadrature as Q
    from transient_mi.integrators import _nlos_refinement as R
    from transient_mi.integrators._nlos_elements import mesh_triangles, split4, subdivide
    from transient_mi.integrators._nlos_refinement import mixed_lit
    from transient_mi.integrators._nlos_surfaces import ElementSurfaces
    from transient_mi.paper import PaperConfig, scene_file
    from transient_mi.scene_io import load_scene

    cfg = PaperConfig(array=array, spots=2, spp=1024, bin_width_ps=1.0, n_bins=11500, estimator="quadrature")
    scene = load_scene(scene_file(), {k: str(v) for k, v in cfg.defines().items()})
    sensor = scene.sensors()[0]
    setup = sensor.nlos_setup(scene)
    g = Q._Geometry(setup, sensor.film(), 1)  # (the paper scene's one cell per side: the test's cells)
    faces = mesh_triangles(setup.hidden_shapes)
    tri_c, src_c = subdivide(faces.tri, np.arange(len(faces.tri)), 2.0 * h)
    tri, src = split4(tri_c), np.repeat(src_c, 4)
    spots = list(range(setup.n_spots))
    n_sh = ElementSurfaces(setup.hidden_shapes, mi.ShapePtr(setup.hidden_shapes), faces, tri, src).n_sh
    t0 = time.perf_counter()
    lit, traced, _ = R.mixed_elements(scene, setup, g, spots, tri, True, n_sh, False)
    test_s = time.perf_counter() - t0
    vs, vc = traced.spot, traced.cell  # [n, G], [C, n]
    part = lambda m: (m != 0) & (m != 15)  # noqa: E731
    any_rule = part(vs).any(axis=1) | part(vc).any(axis=0)
    combined = np.zeros(len(tri), dtype=bool)
    mixed_lit(np.ascontiguousarray(vc), np.ascontiguousarray(vs), 0, np.ascontiguousarray(tri.mean(axis=1)),
              np.zeros((len(tri), 3)), np.ascontiguousarray(g.cell_p), np.asarray(setup.spots, dtype=np.float64),
              np.full(len(g.cell_p), -1, dtype=np.int64), False, combined)
    return {"scene": "paper_mannequin.xml", "array": array, "spots": len(spots), "element_size_m": h,
            "fine_elements": int(len(tri)), "split": {"any": int(any_rule.sum()), "combined": int(combined.sum()),
                                                      "lit": int(lit.sum())},
            "test_s": round(test_s, 2),
            "note": "the first refinement test only (the elements before any split), from the coarse level's cells"}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--array", type=int, default=16)
    ap.add_argument("--element-size-m", type=float, default=0.0213)
    _record.add_arguments(ap)
    a = ap.parse_args(argv)
    load_start = list(os.getloadavg())
    import json

    result = measure(a.array, a.element_size_m)
    print(json.dumps(result, indent=1))
    _record.maybe_save(a, "refinement_rule", result, load_start=load_start)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
