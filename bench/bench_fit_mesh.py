"""``transient-mi fit --model mesh`` on a small capture of an embedded scene: Chamfer and IoU of the fitted mesh
against the scene's hidden shapes, beside its start (the backprojection's front surface) and the
backprojection, on the same grid.

The capture is rendered by the quadrature (deterministic) to the noise standard (``--noise-target``, 0.1: its
stated error at most 0.1 of the photon variance at that budget; until 2026-12-05 it was rendered at fixed settings,
2 cm and 2 cells) and detected with the paper's detector for ``--exposure-ms`` per spot. The chair runs with
``--noise-target none`` (those fixed settings): its self-occlusion keeps the mixed-visibility bound above the
target even at the refinement cap (the worst spot stated 24 at 2 cm, 0.93 at 7 mm, 6 cells and 4 levels, 107 s; a
third round did not finish in 5 minutes), so its record states the capture's ratio instead. The fit runs with the
given iterations and stages. Defaults are a small configuration (8 x 8 pixels of 4 cm, 2 x 2 laser spots), not the
issue's full-size targets (16 x 16, 4 x 4 spots).

    python bench/bench_fit_mesh.py --save --figure docs/img/fit_mesh_letter_views.png   # fit_mesh_letter.json
    python bench/bench_fit_mesh.py --scene nlos_tilted_plane --save
    python bench/bench_fit_mesh.py --scene chair --noise-target none --save   # generated (scenes.topology)
    python bench/bench_fit_mesh.py --scene holed_plate --save

``--scene`` takes an embedded scene or one of the generated shapes of other topology
(:data:`transient_mi.scenes.topology.TOPOLOGY_SHAPES`), whose scene is written into the work folder.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _record  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
TARGETS = {"chamfer_mesh_m": 0.005, "silhouette_iou": 0.8}
IOU_OTHER_TOPOLOGY = 0.6  # the target for the generated shapes of other topology


def _capture(work: Path, scene: str, width: int, spots: int, exposure_s: float,
             noise_target: float | None) -> Path:
    from spad_detector import detect_stack
    from transient_mi.noise_target import NoiseTargetSpec
    from transient_mi.paper import paper_detector
    from transient_mi.render_capture import render
    from transient_mi.scenes import scene_path
    from transient_mi.scenes.topology import TOPOLOGY_SHAPES, write_topology_scene

    d = work / f"{scene}_{width}_{spots}" / ("fixed" if noise_target is None else f"nt{noise_target:g}")
    if (d / "counts" / "manifest.json").is_file():
        return d / "counts"
    pix = 0.32 / width
    xml = write_topology_scene(scene, d / "scene") if scene in TOPOLOGY_SHAPES else scene_path(scene)
    spec = None if noise_target is None else NoiseTargetSpec(target=noise_target, params=paper_detector(),
                                                             exposure_s=exposure_s)
    ideal = render(xml, d / "ideal", progress=False, resume=True, noise_target=spec,
                   defines={"width": str(width), "height": str(width), "spots_x": str(spots), "spots_y": str(spots),
                            "spot_spacing_m": "0.2", "pixel_footprint_m": repr(pix), "aperture_diameter_m": "0.005",
                            "n_bins": "400", "bin_width_ps": "16", "t0_ps": "9000", "estimator": "quadrature",
                            "element_size_m": "0.02", "patch_cells": "2"})
    return detect_stack(ideal, d / "counts", paper_detector(), exposure_s=exposure_s, seed=0, progress=False,
                        overwrite=True)


def _capture_note(counts: Path, noise_target: float | None) -> dict:
    """The capture's quadrature settings per spot and the rendering-error ratio its detection states."""
    from transient_core.stack import read_manifest
    from transient_mi.capture_error import quadrature_settings_per_spot

    det = read_manifest(counts)["detector"]["resolved"].get("render_noise") or {}
    return {"noise_target": noise_target, "render_noise_ratio": det.get("ratio"),
            "settings_per_spot": quadrature_settings_per_spot(read_manifest(counts.parent / "ideal"))}


def _closed_hole_bound(counts: Path) -> dict:
    """Metrics of the holed plate's square without the hole against the truth, on the fit's grid: the best a
    fit that cannot open the hole reaches."""
    import trimesh

    from transient_core.stack import read_manifest
    from transient_mi.fit.outputs import _backprojection, _bounds, _ground_truth, mesh_metrics
    from transient_mi.scenes.topology import closed_plate_mesh

    man = read_manifest(counts)
    m = mesh_metrics(trimesh.Trimesh(*closed_plate_mesh(), process=False), _backprojection(counts, _bounds(man)),
                     _ground_truth(man)[0])
    return {k: m[k] for k in ("silhouette_iou", "iou", "chamfer_mesh_m")}


def _targets(scene: str, fit: dict, counts: Path, full_size: bool = False) -> dict:
    """The issue's targets for this scene and whether the fit meets them (``full_size``: the capture is the
    issue's, 16 x 16 pixels and 4 x 4 spots)."""
    from transient_mi.scenes.topology import HOLED_PLATE_CLOSED_IOU, TOPOLOGY_SHAPES

    if scene in TOPOLOGY_SHAPES:
        out = {"iou_min": IOU_OTHER_TOPOLOGY,
               "met": {"iou": (fit["iou"] or 0) >= IOU_OTHER_TOPOLOGY,
                       "silhouette_iou": (fit["silhouette_iou"] or 0) >= IOU_OTHER_TOPOLOGY},
               "note": "the issue's 'IoU >= 0.6' for shapes of other topology, read as both the voxel IoU and "
                       "the silhouette IoU; " + ("the letter's full-size capture (16x16, 4x4 spots)" if full_size
                                                 else "a small capture")}
        if scene == "holed_plate":
            out["closed_hole_silhouette_iou_whole_plate"] = HOLED_PLATE_CLOSED_IOU
            out["closed_hole_on_the_grid"] = _closed_hole_bound(counts)
        return out
    return {"chamfer_mesh_m_max": TARGETS["chamfer_mesh_m"], "silhouette_iou_min": TARGETS["silhouette_iou"],
            "met": {"chamfer": (fit["chamfer_mesh_m"] or 9) <= TARGETS["chamfer_mesh_m"],
                    "silhouette_iou": (fit["silhouette_iou"] or 0) >= TARGETS["silhouette_iou"]},
            "note": ("the issue's full-size capture (16x16, 4x4 spots)" if full_size else
                     "the issue's targets are for the full 16x16, 4x4-spot capture; this is a smaller one")}


def dead_time_check(counts: Path) -> dict:
    """Total counts of the capture against the detector layer's mean of the capture's own ideal (its rendered
    light), with the first-order dead-time factor (the mannequin fits) and the whole-blind-cycles renewal mean
    (the free-mesh fit): how far each model is from the data at the true shape."""
    import numpy as np

    from transient_core.stack import read_manifest, read_spot
    from transient_mi.fit.capture_model import CaptureModel

    ideal_dir = counts.parent / "ideal"
    mi_ = read_manifest(ideal_dir)
    out = {}
    for dead_time in ("first_order", "renewal"):
        cap = CaptureModel(counts, np.array([[0, 1, 2]]), 3, bin_width_ps=16.0, estimator="quadrature",
                           dead_time=dead_time)
        ideal = np.stack([read_spot(ideal_dir, g, mi_).astype(np.float64).reshape(cap.width * cap.height, -1)
                          for g in range(cap.n_spots)])
        out[dead_time] = float(cap.expected_counts(ideal).sum())
        out["counts"] = float(cap.counts.sum())
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="nlos_letter")
    ap.add_argument("--width", type=int, default=8, help="pixels per side")
    ap.add_argument("--spots", type=int, default=2, help="laser spots per side")
    ap.add_argument("--exposure-ms", type=float, default=10.0)
    ap.add_argument("--noise-target", type=lambda v: None if v == "none" else float(v), default=0.1,
                    help="the capture is rendered until its error is at most this share of the photon noise "
                         "(squared) at --exposure-ms, refining from 2 cm elements and 2 cells per patch side; "
                         "'none': at those settings")
    ap.add_argument("--iterations", type=int, default=40)
    ap.add_argument("--stages", type=int, default=2)
    ap.add_argument("--cell-m", type=float, default=0.04)
    ap.add_argument("--element-size-m", type=float, default=0.03)
    ap.add_argument("--moments", default="uniform", choices=("uniform", "vertex"))
    ap.add_argument("--step-m", type=float, default=0.003)
    ap.add_argument("--align", type=int, default=8, help="Levenberg-Marquardt iterations of the affine alignment")
    ap.add_argument("--carve", type=int, default=None,
                    help="per-face reflectance iterations of the carving step (default: the fit's own default)")
    ap.add_argument("--grow", type=int, default=None,
                    help="rings of faces added before carving (default: the fit's, 2 where it carves)")
    ap.add_argument("--carve-tv", type=float, default=None,
                    help="weight of the carving's total-variation prior (default: the fit's, mesh_carve.TV_WEIGHT)")
    ap.add_argument("--reflectance", default="global", choices=("global", "face"),
                    help="one reflectance for the mesh, or one per face (the record's name gets '_face')")
    ap.add_argument("--start", default="front", choices=("front", "closed"),
                    help="the backprojection's front surface (the fit's default) or a closed surface around its "
                         "occupied voxels (--start closed; such a start is not carved by default)")
    ap.add_argument("--work", type=Path, default=ROOT / "out" / "bench_fit_mesh")
    ap.add_argument("--figure", type=Path, default=None, help="also copy the fit's views.png here")
    ap.add_argument("--pixel-step", type=int, default=None,
                    help="fit every n-th pixel along each axis (--pixel-step; default: the fit's own)")
    _record.add_arguments(ap)
    a = ap.parse_args()
    load_start = list(os.getloadavg())
    import transient_mi  # noqa: F401
    from transient_mi.fit import FitSettings, fit_capture
    from transient_mi.fit.mesh_settings import MeshSettings, carve_iterations, grow_rings

    t0 = time.perf_counter()
    counts = _capture(a.work, a.scene, a.width, a.spots, 1e-3 * a.exposure_ms, a.noise_target)
    t_cap = time.perf_counter() - t0
    dead_time = dead_time_check(counts)
    t1 = time.perf_counter()
    res = fit_capture(counts, a.work / f"fit_{a.scene}", model="mesh", bin_width_ps=16.0, overwrite=True,
                      settings=FitSettings(iterations=a.iterations, sigma_start_ps=150.0,
                                           element_size_m=a.element_size_m),
                      mesh=MeshSettings(start=a.start, cell_m=a.cell_m, stages=a.stages, moments=a.moments,
                                        step_m=a.step_m, align=a.align, reflectance=a.reflectance, grow=a.grow,
                                        pixel_step=a.pixel_step,
                                        **({} if a.carve is None else {"carve": a.carve}),
                                        **({} if a.carve_tv is None else {"carve_tv": a.carve_tv})),
                      progress=False)
    t_fit = time.perf_counter() - t1
    m = res["metrics"]
    keys = ("chamfer_mesh_m", "chamfer_m", "iou", "silhouette_iou", "depth_mae_m")
    rows = {k: {c: m[k].get(c) for c in keys} for k in ("fit", "carved", "aligned", "start", "backprojection")
            if k in m}
    result = {"scene": a.scene, "width": a.width, "spots": a.spots, "exposure_ms": a.exposure_ms, "start": a.start,
              "iterations": a.iterations, "stages": a.stages, "cell_m": a.cell_m, "element_size_m": a.element_size_m,
              "moments": a.moments, "step_m": a.step_m, "align": a.align, "align_albedo": res["align"]["albedo"],
              "carve": carve_iterations(MeshSettings(**res["config"]["mesh"])) if res.get("carve") else 0,
              "carve_result": res.get("carve"),
              "grow": grow_rings(MeshSettings(**res["config"]["mesh"])), "carve_tv": res["config"]["mesh"]["carve_tv"],
              "reflectance": a.reflectance, "pixel_step": res["estimator"]["pixel_step"],
              "fit_albedo_range": [res["parameters"]["fit"].get("albedo_min"), res["parameters"]["fit"].get("albedo_max")],
              "metrics": rows, "dead_time_check": dead_time, "poisson_nll": res["poisson_nll"], "fit_albedo": res["parameters"]["fit"]["albedo"],
              "n_faces": {"start": res["parameters"]["start"]["n_faces"], "fit": res["parameters"]["fit"]["n_faces"]},
              "time_s": {"capture": t_cap, "fit_wall": t_fit, "align": res["time_s"]["align"],
                         "carve": res["time_s"].get("carve"),
                         "optimisation": res["time_s"]["optimisation"]},
              "capture": _capture_note(counts, a.noise_target),
              "targets": _targets(a.scene, rows["fit"], counts, a.width == 16 and a.spots == 4)}
    for k, r in rows.items():
        print(f"{k:15s} " + "  ".join(f"{c}={v:.4g}" for c, v in r.items() if v is not None))
    print(f"fit {t_fit:.0f} s")
    if a.figure is not None:
        import shutil

        shutil.copyfile(a.work / f"fit_{a.scene}" / "views.png", a.figure)
    name = (f"fit_mesh_{a.scene.removeprefix('nlos_')}" + ("_vertex" if a.moments == "vertex" else "")
            + ("_face" if a.reflectance == "face" else ""))
    _record.maybe_save(a, name, result, load_start=load_start)


if __name__ == "__main__":
    main()
