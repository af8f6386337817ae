"""What a fit writes and scores, shared by the model fits (:mod:`transient_mi.fit.api`) and the free-mesh fit
(:mod:`transient_mi.fit.mesh_fit`): the output directory's claim, atomic text files, the reconstruction bounds and
the backprojection a fit starts from and is compared with, the ground truth from the capture's scene, the metrics
(surface Chamfer in metres, voxel metrics on the backprojection's grid) and the figures."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from transient_core.atomic import atomic_file
from transient_core.errors import UserInputError

from .optimize import FitState


def _write_text(path: Path, text: str) -> None:
    with atomic_file(path) as tmp:
        Path(tmp).write_text(text)


def claim_output(out: Path, config: dict, resume: bool, overwrite: bool) -> bool:
    """Whether ``out`` already holds a fit, after checking that this run may write there (call under
    :func:`~transient_core.lock.output_lock`): ``--resume`` needs the same ``config``, ``--overwrite`` replaces an
    earlier fit only, anything else in a non-empty directory is refused in one line."""
    existing = out.is_dir() and any(out.iterdir())
    if existing:
        if resume:
            try:
                old = json.loads((out / "config.json").read_text())
            except (OSError, ValueError):
                raise UserInputError(f"--resume: {out} holds no fit to resume (config.json missing)") from None
            if old != config:
                raise UserInputError(f"--resume: {out} holds a fit of other settings or another capture; "
                                     "resume with the same options, or --overwrite")
        elif overwrite:
            if not (out / "config.json").is_file():
                raise UserInputError(f"-o {out}: --overwrite replaces an earlier fit only; this directory holds "
                                     "something else")
        else:
            raise UserInputError(f"-o {out}: directory exists and is not empty (pass --overwrite to replace an "
                                 "earlier fit, or --resume to continue it)")
    return existing


def _bounds(manifest: dict) -> tuple:
    """Reconstruction bounds: the wall patch the pixels cover, depths from the detector's automatic gate
    (the hidden space the capture was gated for), else 0.1 to 1.5 m."""
    pc = np.asarray(manifest["geometry"]["pixel_centers"], dtype=np.float64).reshape(-1, 3)
    det = manifest.get("detector") or {}
    z0 = float(det.get("auto_gate_depth_min_m") or 0.1)
    z1 = float(det.get("auto_gate_depth_max_m") or 1.5)
    pad = 0.5 * (np.ptp(pc[:, 0]) / max(int(manifest["width"]) - 1, 1))
    return (float(pc[:, 0].min() - pad), float(pc[:, 0].max() + pad), float(pc[:, 1].min() - pad),
            float(pc[:, 1].max() + pad), z0, z1)


def fit_bins_capture(capture: Path, bin_width_ps: float):
    """``(recon capture, counts)``: ``capture`` as a :class:`recon.Capture`, its counts summed into the fit's bins
    (``bin_width_ps``: :func:`~transient_mi.fit.capture_model.fit_bin_factor`'s rule) and read once, and those counts
    ``[G, H, W, T]`` for ``CaptureModel(counts=...)``. The fits' backprojection and their forward model share the
    read: each file of the demo's capture takes a third of a second. Where the fit's bins are the capture's own (or
    not a whole multiple of them, which the forward model refuses), or the capture has channels, nothing is summed
    or kept in memory: ``counts`` is None and the forward model reads the files itself."""
    import recon

    from .capture_model import fit_bin_factor

    cap = recon.load_capture(capture)
    factor = fit_bin_factor(bin_width_ps, cap.bin_width_ps, cap.n_bins)
    if factor is None or factor == 1 or cap.manifest.get("channels"):
        return cap, None
    from recon.preprocess import downsample_time

    cap = downsample_time(cap, factor)
    return cap, cap.data  # (each file read once)


def _backprojection(capture, bounds, voxels=(64, 64, 32)):
    """The paper's filtered backprojection of ``capture`` (a path, or a :class:`recon.Capture`:
    :func:`fit_bins_capture`'s) on ``bounds``."""
    import recon

    cap = recon.load_capture(capture) if isinstance(capture, (str, Path)) else capture
    return recon.reconstruct(cap, "bp", bounds=bounds, voxels=voxels, filter="paper", threshold="rel:0.3")


def _ground_truth(manifest: dict):
    """``(mesh, truth parameters or None)`` from the capture's scene (None, None when it cannot be loaded)."""
    import trimesh

    from transient_mi.scene_mesh import hidden_mesh

    render = manifest.get("render") or {}
    defines = dict(render.get("defines") or {})
    try:
        v, f, _ = hidden_mesh(render["scene_file"], defines)
    except Exception:  # noqa: BLE001 (a scene without hidden shapes, or that no longer loads: no ground truth)
        return None, None
    mesh = trimesh.Trimesh(vertices=v, faces=f, process=False)
    truth = None
    if Path(render["scene_file"]).name == "paper_mannequin.xml":
        from transient_mi.paper import scene_defaults
        from transient_mi.scenes.mannequin import rest_arm_angle_deg
        from transient_mi.scenes.mannequin_skeleton import JOINTS, parse_joints, resolve_joints

        d = dict(scene_defaults())
        d.update(defines)
        h, w = float(d["mannequin_height"]), float(d["mannequin_width"])
        joints = resolve_joints(d["pose"], rest_arm_angle_deg(h, w), parse_joints(d.get("joints", "")))
        truth = {**joints, "x_m": 0.0, "y_m": 0.0, "z_m": float(d["distance"]), "rotation_deg": float(d["rotation"]),
                 "height_m": h, "albedo": float(d["mannequin_albedo"])}
        truth = {k: truth[k] for k in list(JOINTS) + ["x_m", "y_m", "z_m", "rotation_deg", "height_m", "albedo"]}
    return mesh, truth


def _surface_chamfer(a, b, n: int = 20000, seed: int = 0) -> dict:
    from scipy.spatial import cKDTree
    from trimesh.sample import sample_surface

    pa, _ = sample_surface(a, n, seed=seed)
    pb, _ = sample_surface(b, n, seed=seed + 1)
    acc = float(np.mean(cKDTree(pb).query(pa)[0]))
    comp = float(np.mean(cKDTree(pa).query(pb)[0]))
    return {"chamfer_mesh_m": 0.5 * (acc + comp), "accuracy_mesh_m": acc, "completeness_mesh_m": comp}


def _voxel_metrics(mesh, rec_bp, gt_mesh) -> dict:
    from recon.metrics import GroundTruth, compute_metrics, mesh_occupancy
    from recon.result import Reconstruction

    occ = mesh_occupancy(mesh, rec_bp.grid).astype(np.float32)
    rec = Reconstruction(raw=occ, grid=rec_bp.grid, method="fit")
    m = compute_metrics(rec, GroundTruth(mesh=gt_mesh, source="capture scene"))
    keys = ("chamfer_m", "accuracy_m", "completeness_m", "iou", "depth_mae_m", "silhouette_iou", "visible_chamfer_m")
    return {k: m.get(k) for k in keys}


def _loss_figure(path: Path, state: FitState) -> None:
    from transient_mi.reporting import save_figure, subplots

    h = np.asarray(state.history, dtype=np.float64).reshape(-1, 4)
    fig, ax = subplots(1, 1, figsize=(6.4, 3.4))
    it = np.arange(1, len(h) + 1)
    ax.semilogy(it, h[:, 3], lw=0.6, color="C0", label=f"objective at the final blur ({h[-1, 1]:.0f} ps)")
    if len(h) >= 10:
        k = max(5, len(h) // 20)
        smooth = np.convolve(h[:, 3], np.ones(k) / k, mode="valid")
        ax.semilogy(it[k - 1:], smooth, lw=1.5, color="C3", label=f"running mean ({k} iterations)")
    ax.semilogy(it, h[:, 0], lw=0.8, color="C2", alpha=0.7, label="objective descended (current blur)")
    ax.set_xlabel("iteration")
    ax.set_ylabel("objective")
    ax2 = ax.twinx()
    ax2.plot(it, h[:, 1], color="0.5", lw=1, ls="--")
    ax2.set_ylabel("temporal blur sigma (ps)", color="0.4")
    ax.legend(loc="upper right", fontsize=8)
    save_figure(fig, path, dpi=100)


def _front_figure(path: Path, rec_bp, gt_mesh, mesh, metrics) -> None:
    from recon.metrics import mesh_depth_map
    from recon.filters import depth_map
    from transient_mi.reporting import save_figure, subplots

    g = rec_bp.grid
    panels = []
    if gt_mesh is not None:
        panels.append(("ground truth", mesh_depth_map(gt_mesh, g)))
    bp = depth_map(rec_bp.volume, g)
    panels.append(("backprojection (paper's filter)", bp))
    panels.append(("fit", mesh_depth_map(mesh, g)))
    fig, axes = subplots(1, len(panels), figsize=(3.2 * len(panels), 3.4))
    axes = np.atleast_1d(axes)
    ext = (g.x_m[0], g.x_m[-1], g.y_m[0], g.y_m[-1])
    z0, z1 = g.z_m[0], g.z_m[-1]
    for ax, (title, d) in zip(axes, panels):
        im = ax.imshow(d, origin="lower", extent=ext, vmin=z0, vmax=z1, cmap="viridis")
        key = {"fit": "fit", "backprojection (paper's filter)": "backprojection"}.get(title)
        if key and key in metrics:
            m = metrics[key]
            title += f"\nChamfer {100 * m['chamfer_m']:.1f} cm, IoU {m['iou']:.2f}"
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("x (m)")
    axes[0].set_ylabel("y (m)")
    fig.colorbar(im, ax=list(axes), shrink=0.8, label="depth z (m)")
    save_figure(fig, path, dpi=100)


def mesh_metrics(mesh, rec_bp, gt_mesh) -> dict:
    """A fitted (or start) mesh against the truth: voxel metrics on the backprojection's grid and the
    surface-to-surface Chamfer (metres)."""
    return {**_voxel_metrics(mesh, rec_bp, gt_mesh), **_surface_chamfer(mesh, gt_mesh)}


def backprojection_metrics(rec_bp, gt_mesh) -> dict:
    """The starting backprojection's metrics against the truth, on its own grid (metres; IoU)."""
    from recon.metrics import GroundTruth, compute_metrics

    bp = compute_metrics(rec_bp, GroundTruth(mesh=gt_mesh, source="capture scene"))
    keys = ("chamfer_m", "accuracy_m", "completeness_m", "iou", "depth_mae_m", "silhouette_iou", "visible_chamfer_m")
    return {k: bp.get(k) for k in keys}
