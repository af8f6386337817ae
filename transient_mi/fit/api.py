"""``fit_capture``: analysis by synthesis of an NLOS counts capture (what ``transient-mi fit`` runs).

1. Backprojection of the counts (the paper's filter) gives the starting position (and, for
   ``--model patches``, the patches' centres: the strongest regions of the volume).
2. The objective of :mod:`transient_mi.fit.capture_model` minimised by Gauss-Newton steps on the deterministic
   quadrature (:mod:`transient_mi.fit.gauss_newton`; the default wherever the capture's scene allows the
   quadrature) or by Adam (:mod:`transient_mi.fit.optimize`; with Monte Carlo), with checkpoints (``--resume``
   continues from them).
3. Outputs in the output directory (each file written atomically, ``fit.json`` last):

   ``fit.json``       parameters (start, fitted, truth where known), settings, the estimator used (the
                      quadrature where the scene allows it, else Monte Carlo, and why) and the optimiser (with
                      the pixels and the twin's detail it used), the objective per
                      iteration, time, the Poisson NLL of the counts under the start and the fit, metrics
   ``fitted.ply``     the fitted mesh (the mannequin as ``transient-mi mannequin`` builds it: watertight)
   ``loss.png``       the objective per iteration and the temporal blur
   ``fit.png``        front views (depth maps) of ground truth, backprojection and fit
   ``checkpoint.json`` the optimiser's state (parameters, Adam moments, history)

Metrics against ground truth (the capture's hidden shapes, rendered again from its scene file):
``chamfer_mesh_m`` (symmetric mean distance between the fitted and true surfaces, area-uniform samples),
and the voxel metrics the demo reports for backprojection (:func:`recon.metrics.compute_metrics`:
``chamfer_m``, ``iou``, ``depth_mae_m``, ...) of the fitted surface voxelised on the backprojection's
grid, next to the backprojection's own. For the paper's scene the true pose is known (its ``-D`` values):
per-parameter errors.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from transient_core.errors import UserInputError
from transient_core.lock import output_lock

from .optimize import FitSettings, FitState, run_adam
from .outputs import (_backprojection, _bounds, _front_figure, _ground_truth, _loss_figure, _write_text,
                      backprojection_metrics, claim_output, fit_bins_capture, mesh_metrics)

__all__ = ["fit_capture", "FitSettings"]

_OUTPUTS = ("fit.json", "fitted.ply", "loss.png", "fit.png", "checkpoint.json", "config.json")


def _check_settings(model: str, settings: FitSettings, n_patches: int, patch_side_m: float) -> None:
    from .models import MODELS

    if model not in MODELS:
        raise UserInputError(f"--model {model!r} is not known; allowed: {', '.join(MODELS)}")
    from .optimize import OPTIMIZERS

    if settings.optimizer not in OPTIMIZERS:
        raise UserInputError(f"optimizer={settings.optimizer!r}: expected {', '.join(OPTIMIZERS)}")
    iters = settings.n_iterations("adam")
    for name, v, lo in (("iterations", iters, 1), ("spp", settings.spp, 0),
                        ("spp_residual", settings.spp_residual, 0), ("checkpoint_every", settings.checkpoint_every, 1)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
            raise UserInputError(f"{name}={v!r}: expected a whole number >= {lo}")
    for name in ("sigma_start_ps", "sigma_end_ps"):
        v = getattr(settings, name)
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
            raise UserInputError(f"{name}={v!r}: expected a finite number of ps >= 0")
    if not (isinstance(n_patches, (int, np.integer)) and 1 <= n_patches <= 16):
        raise UserInputError(f"n_patches={n_patches!r}: expected a whole number from 1 to 16")
    if not (math.isfinite(patch_side_m) and 0 < patch_side_m <= 2.0):
        raise UserInputError(f"patch_side_m={patch_side_m!r}: expected a side in metres, > 0 and <= 2")


def _strongest_regions(rec, k: int) -> np.ndarray:
    """``k`` centres: weighted k-means (a few Lloyd steps, deterministic start) of the occupied voxels."""
    occ = rec.volume > 0
    pts = rec.grid.centers()[occ]
    w = rec.volume[occ].astype(np.float64)
    if len(pts) < k:
        raise UserInputError(f"the backprojection holds {len(pts)} occupied voxels, fewer than the {k} patches asked "
                             "for: nothing to start from")
    order = np.argsort(-w)
    centres = [pts[order[0]]]
    for _ in range(1, k):  # farthest-point start among the strong voxels
        strong = pts[order[: max(k, len(pts) // 4)]]
        d = np.min(np.linalg.norm(strong[:, None, :] - np.array(centres)[None], axis=-1), axis=1)
        centres.append(strong[int(np.argmax(d))])
    c = np.array(centres)
    for _ in range(20):
        lab = np.argmin(np.linalg.norm(pts[:, None, :] - c[None], axis=-1), axis=1)
        c = np.array([np.average(pts[lab == j], axis=0, weights=w[lab == j]) if np.any(lab == j) else c[j]
                      for j in range(k)])
    return c


def _start_position(rec) -> tuple[float, float, float]:
    """Body centre from the backprojection: the occupied voxels' weighted centroid in x and y; in z their
    weighted depth plus 5 cm (the volume holds the front surface; the body's centre lies behind it)."""
    occ = rec.volume > 0
    if not occ.any():
        raise UserInputError("the backprojection of the capture is empty: nothing to start the fit from")
    pts = rec.grid.centers()[occ]
    w = rec.volume[occ].astype(np.float64)
    x, y, z = np.average(pts, axis=0, weights=w)
    return float(x), float(y), float(z + 0.05)


def _fitted_mesh(model, theta):
    if model.name == "mannequin":
        from transient_mi.scenes.mannequin import make_mannequin

        return make_mannequin(**model.mesh_kwargs(theta))
    return model.mesh(theta)


def fit_capture(capture, out_dir, *, model: str = "mannequin", settings: FitSettings | None = None,
                bin_width_ps: float = 10.0, n_patches: int = 3, patch_side_m: float = 0.2, detail: int | None = None,
                resume: bool = False, overwrite: bool = False, progress: bool | None = None, log=print,
                mesh=None) -> dict:
    """Fit a model of the hidden scene to a counts capture; returns the content of ``fit.json``.

    Parameters
    ----------
    capture : path
        Counts capture (``transient-mi detect`` / ``demo`` output) of an NLOS scene.
    out_dir : path
        Output directory (see the module docstring); one writer at a time.
    model : str
        ``mannequin``, ``patches`` (:mod:`transient_mi.fit.models`) or ``mesh`` (a free mesh:
        :mod:`transient_mi.fit.mesh_fit`).
    settings : FitSettings
        Iterations, samples per pixel, temporal blur, seed (default :class:`FitSettings`).
    bin_width_ps : float
        The fit's time bins (a whole multiple of the capture's), ps.
    n_patches, patch_side_m : int, float
        ``patches``: how many, and their side (m).
    detail : int, optional
        ``mannequin``: tessellation of the twin (as ``transient-mi mannequin --detail``; default 20 with Adam,
        :data:`~transient_mi.fit.gauss_newton.GN_DETAIL` with Gauss-Newton).
    resume : bool
        Continue from ``out_dir/checkpoint.json`` (same capture and settings).
    overwrite : bool
        Replace an existing output directory.
    mesh : MeshSettings, optional
        ``mesh``: start, resolution, stages and regularisers (:class:`~transient_mi.fit.mesh_settings.MeshSettings`;
        default its defaults); see :func:`~transient_mi.fit.mesh_fit.fit_mesh_capture`.
    """
    from transient_core.progress import progress_bar
    from transient_core.stack import read_manifest

    settings = settings or FitSettings()
    _check_settings(model, settings, n_patches, patch_side_m)
    if model == "mesh":
        from .mesh_fit import fit_mesh_capture

        return fit_mesh_capture(capture, out_dir, settings=settings, bin_width_ps=bin_width_ps, mesh=mesh,
                                resume=resume, overwrite=overwrite, progress=progress, log=log)
    capture = Path(capture)
    if not (capture / "manifest.json").is_file():
        raise UserInputError(f"capture {str(capture)!r} is not a capture directory (no manifest.json)")
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise UserInputError(f"-o {out}: exists and is not a directory")
    if detail is not None and not (isinstance(detail, (int, np.integer)) and 8 <= detail <= 64):
        raise UserInputError(f"detail={detail!r}: expected a whole number of segments from 8 to 64")
    config = {"capture": str(capture.resolve()), "model": model, "settings": asdict(settings),
              "bin_width_ps": float(bin_width_ps), "n_patches": int(n_patches), "patch_side_m": float(patch_side_m),
              "detail": None if detail is None else int(detail)}
    with output_lock(out):
        existing = claim_output(out, config, resume, overwrite)
        t_start = time.perf_counter()
        manifest = read_manifest(capture)
        # (read once: the forward model's counts, backprojected; anything but an NLOS counts capture is refused by
        # the forward model below, in its own words)
        nlos_counts = manifest.get("kind") == "counts" and manifest.get("capture") in ("array", "confocal")
        binned, shared = fit_bins_capture(capture, bin_width_ps) if nlos_counts else (None, None)
        mdl, cap, optimizer = _forward_model(capture, manifest, model, settings, bin_width_ps, n_patches,
                                             patch_side_m, detail, shared)
        n_iter = settings.n_iterations(optimizer)
        bounds = _bounds(manifest)
        rec_bp = _backprojection(binned if binned is not None else capture, bounds)
        del binned, shared
        # (everything checked: only now is anything written)
        if existing and overwrite and not resume:
            for name in _OUTPUTS + ("start.json",):
                (out / name).unlink(missing_ok=True)
        out.mkdir(parents=True, exist_ok=True)
        ckpt = out / "checkpoint.json"
        if resume and ckpt.is_file():
            state = FitState.load(ckpt)
            theta0 = np.asarray(json.loads((out / "start.json").read_text())["theta"])
        else:
            if model == "mannequin":
                theta0 = mdl.initial(_start_position(rec_bp))
            else:
                theta0 = mdl.initial(_strongest_regions(rec_bp, n_patches))
            theta0 = _match_brightness(mdl, cap, theta0, settings)
            _write_text(out / "start.json", json.dumps({"theta": theta0.tolist()}) + "\n")
            _write_text(out / "config.json", json.dumps(config, indent=1) + "\n")
            state = FitState(theta=theta0.tolist())
        with progress_bar(f"fit {model} ({optimizer.replace('_', '-')})", n_iter,
                          disable=None if progress is None else not progress) as advance:
            if state.iteration:
                advance(state.iteration)
            if optimizer == "gauss_newton":
                from .gauss_newton import run_gauss_newton

                run_gauss_newton(mdl, cap, state, settings, n_iter, progress=lambda i, n, obj: advance(1),
                                 checkpoint=lambda s: s.save(ckpt))
            else:
                run_adam(mdl, cap, state, settings, progress=lambda i, n, obj: advance(1),
                         checkpoint=lambda s: s.save(ckpt))
        fit_s = time.perf_counter() - t_start
        theta = state.result()
        result = _finish(out, mdl, cap, manifest, rec_bp, theta0, theta, state, settings, config, fit_s, optimizer)
        log(f"fit {model}: {n_iter} iterations ({optimizer}) in {state.elapsed_s:.0f} s of optimisation "
            f"({fit_s:.0f} s in all); wrote {out}/fit.json, fitted.ply, loss.png, fit.png")
        return result


def _forward_model(capture: Path, manifest: dict, model: str, settings: FitSettings, bin_width_ps: float,
                   n_patches: int, patch_side_m: float, detail: int | None, counts=None):
    """``(model, CaptureModel, optimizer)``: the optimiser (``auto``: Gauss-Newton with the quadrature, Adam with
    Monte Carlo) and what it needs: with Gauss-Newton the twin at :data:`~.gauss_newton.GN_DETAIL` and every
    :func:`~.gauss_newton.pixel_step`-th pixel; with Adam the twin at detail 20 and every pixel. With ``auto``
    Gauss-Newton is assumed first (the quadrature is the default forward model); a capture the quadrature cannot
    render is then set up again for Adam. ``counts``: the capture's counts in the fit's bins, ``[G, H, W, T]``, if
    already read (:func:`~.outputs.fit_bins_capture`)."""
    from .capture_model import FIT_QUADRATURE, CaptureModel
    from .gauss_newton import GN_DETAIL, pixel_step
    from .models import MannequinModel, PatchesModel

    def build(optimizer: str):
        gn = optimizer == "gauss_newton"
        mdl = (MannequinModel(detail if detail is not None else (GN_DETAIL if gn else 20)) if model == "mannequin"
               else PatchesModel(n_patches, patch_side_m))
        step = pixel_step(int(manifest["width"]), int(manifest["height"])) if gn else 1
        cap = CaptureModel(capture, mdl.faces, mdl.n_vertices, bin_width_ps=bin_width_ps,
                           estimator=settings.estimator, element_size_m=settings.element_size_m, pixel_step=step,
                           counts=counts, **FIT_QUADRATURE)
        return mdl, cap

    if settings.optimizer == "adam" or settings.estimator == "monte_carlo":
        if settings.optimizer == "gauss_newton":
            raise UserInputError("optimizer=gauss_newton needs the deterministic forward model (estimator quadrature "
                                 "or auto); with estimator=monte_carlo use optimizer adam or auto")
        return (*build("adam"), "adam")
    mdl, cap = build("gauss_newton")
    if cap.estimator == "quadrature":
        return mdl, cap, "gauss_newton"
    if settings.optimizer == "gauss_newton":
        raise UserInputError(f"optimizer=gauss_newton needs the deterministic forward model, and the capture's scene "
                             f"cannot be rendered by it: {cap.estimator_reason}; use optimizer adam or auto")
    return (*build("adam"), "adam")  # (auto, a scene the quadrature cannot render: Monte Carlo and Adam)


def _match_brightness(mdl, cap, theta0: np.ndarray, settings: FitSettings) -> np.ndarray:
    """Start with the reflectance that gives the model as many counts as the capture holds."""
    theta = theta0.copy()
    cap.set_mesh(mdl.vertices(theta), mdl.albedo(theta))
    from .optimize import resolve_spp

    spp = resolve_spp(settings, cap.width * cap.height)[1]
    cap.set_element_size(2.0 * settings.element_size_m)  # (the first iterations' elements)
    mu = cap.expected_counts(cap.ideal(settings.seed + 7919, spp, cap.jitter_sigma_ps))
    total = float(mu.sum())
    if total > 0:
        theta[-1] = float(np.clip(theta[-1] * cap.counts.sum() / total, mdl.lower[-1], mdl.upper[-1]))
    return theta


def _finish(out, mdl, cap, manifest, rec_bp, theta0, theta, state, settings, config, fit_s, optimizer) -> dict:
    from transient_mi.scenes._ply import write_ply

    from .optimize import resolve_spp

    spp_eval = 4 * resolve_spp(settings, cap.width * cap.height)[1]
    cap.set_element_size(settings.element_size_m)
    nll = {}
    for label, th in (("start", theta0), ("fit", theta)):
        cap.set_mesh(mdl.vertices(th), mdl.albedo(th))
        mu = cap.expected_counts(cap.ideal(settings.seed + 104729, spp_eval, cap.jitter_sigma_ps))
        nll[label] = cap.poisson_nll(mu)
    mesh = _fitted_mesh(mdl, theta)
    write_ply(out / "fitted.ply", mesh.vertices, mesh.faces)
    gt_mesh, truth = _ground_truth(manifest)
    metrics = {}
    if gt_mesh is not None:
        metrics = {"fit": mesh_metrics(mesh, rec_bp, gt_mesh),
                   "backprojection": backprojection_metrics(rec_bp, gt_mesh)}
    errors = None
    if truth is not None and mdl.name == "mannequin":
        fitted = mdl.as_dict(theta)
        errors = {k: fitted[k] - truth[k] for k in truth}
        joints = [abs(errors[k]) for k in truth if k.endswith(("_right", "_left"))]
        metrics["joint_error_max_deg"] = float(max(joints))
        metrics["joint_error_mean_deg"] = float(np.mean(joints))
        metrics["position_error_m"] = float(np.linalg.norm([errors["x_m"], errors["y_m"], errors["z_m"]]))
    _loss_figure(out / "loss.png", state)
    _front_figure(out / "fit.png", rec_bp, gt_mesh, mesh, metrics)
    result = {
        "status": "complete", "format": "transient-mi-fit", "format_version": 1, "config": config,
        "parameters": {"names": mdl.names, "start": mdl.as_dict(theta0), "fit": mdl.as_dict(theta),
                       "truth": truth, "error": errors},
        "estimator": {"requested": settings.estimator, "used": cap.estimator, "why_not_quadrature":
                      cap.estimator_reason, "element_size_m": cap.element_size_m if cap.estimator == "quadrature"
                      else None},
        "optimizer": {"requested": settings.optimizer, "used": optimizer,
                      "iterations": settings.n_iterations(optimizer),
                      "detail": getattr(getattr(mdl, "twin", None), "detail", None),
                      "pixel_step": cap.pixel_step, "pixels_used": [cap.height, cap.width]},
        "poisson_nll": {**nll, "spp": spp_eval if cap.estimator == "monte_carlo" else None,
                        "counts": float(cap.counts.sum()), "pixel_step": cap.pixel_step},
        "metrics": metrics,
        "history": {"objective": [h[0] for h in state.history], "sigma_ps": [h[1] for h in state.history],
                    "seconds": [h[2] for h in state.history],
                    "objective_end_blur": [h[3] for h in state.history]},
        "time_s": {"optimisation": state.elapsed_s, "total": fit_s},
        "bounds": list(_bounds(manifest)),
    }
    _write_text(out / "fit.json", json.dumps(result, indent=1) + "\n")
    return result

