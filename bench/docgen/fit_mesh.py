"""The free-mesh fit (``transient-mi fit --model mesh``) on a small capture (docs/fit.md)."""

from __future__ import annotations

from .common import provenance


def _cm(x) -> str:
    return "-" if x is None else f"{100 * x:.2f} cm"


def _f(x) -> str:
    return "-" if x is None else f"{x:.2f}"


def fit_mesh_table(R) -> str:
    """The letter: fit, start and backprojection against the scene's hidden shapes, and the targets."""
    return _table(R("fit_mesh_letter"))


def fit_mesh_plane_table(R) -> str:
    """The tilted plane, as :func:`fit_mesh_table`."""
    return _table(R("fit_mesh_tilted_plane"))


def fit_mesh_plane_vertex_table(R) -> str:
    """The tilted plane with one Adam second moment per vertex (``moments="vertex"``)."""
    return _table(R("fit_mesh_tilted_plane_vertex"))


def _table(rec) -> str:
    r = rec["result"]
    m = r["metrics"]
    t = r["targets"]
    rows = ["| | fit | start (backprojection's front surface) | backprojection "
            "| target (full-size capture) |",
            "|---|---|---|---|---|",
            f"| Chamfer, surface to surface | {_cm(m['fit']['chamfer_mesh_m'])} | {_cm(m['start']['chamfer_mesh_m'])} "
            f"| | <= {_cm(t['chamfer_mesh_m_max'])}: {'met' if t['met']['chamfer'] else 'not met'} |",
            f"| Chamfer (voxels) | {_cm(m['fit']['chamfer_m'])} | {_cm(m['start']['chamfer_m'])} "
            f"| {_cm(m['backprojection']['chamfer_m'])} | |",
            f"| silhouette IoU | {_f(m['fit']['silhouette_iou'])} | {_f(m['start']['silhouette_iou'])} "
            f"| {_f(m['backprojection']['silhouette_iou'])} | >= {t['silhouette_iou_min']:g}: "
            f"{'met' if t['met']['silhouette_iou'] else 'not met'} |",
            f"| occupancy IoU | {_f(m['fit']['iou'])} | {_f(m['start']['iou'])} | {_f(m['backprojection']['iou'])} | |",
            f"| depth MAE | {_cm(m['fit']['depth_mae_m'])} | {_cm(m['start']['depth_mae_m'])} "
            f"| {_cm(m['backprojection']['depth_mae_m'])} | |"]
    nll = r["poisson_nll"]
    scene = r["scene"].removeprefix("nlos_").replace("_", " ")
    variant = (f", one second moment per vertex, {1000 * r['step_m']:g} mm steps"
               if r.get("moments") == "vertex" else "")
    head = (f"The {scene} at a small configuration ({r['width']} x {r['width']} pixels of {32 / r['width']:g} cm, "
            f"{r['spots']} x {r['spots']} laser spots, the paper's detector for {r['exposure_ms']:g} ms per spot, the "
            f"capture rendered by the quadrature); {r['iterations']} iterations in {r['stages']} stages from "
            f"{r['cell_m'] * 100:g} cm cells ({r['n_faces']['start']} -> {r['n_faces']['fit']} triangles){variant}, "
            f"{r['time_s']['fit_wall']:.0f} s (fit, wall):")
    return (head + "\n\n" + "\n".join(rows) + "\n\n"
            f"Poisson NLL of the counts: {nll['start']:.6g} at the start, {nll['fit']:.6g} fitted; fitted reflectance "
            f"{r['fit_albedo']:.2f}. " + provenance(rec))
