r"""``fit_capture(..., model="mesh")``: 3-D reconstruction of any hidden shape by analysis by synthesis of a free
triangle mesh (what ``transient-mi fit --model mesh`` runs).

1. Start: a reconstruction's surface (:mod:`~transient_mi.fit.mesh_start`: the backprojection's front surface
   by default, a closed surface around its occupied voxels, or any mesh file such as a ``recon`` method's
   ``surface.ply``), at ``cell_m``, less any face across the device's view of the wall
   (:func:`~transient_mi.fit.mesh_start.clear_view`); its reflectance is set so the model holds as many counts as the capture.
2. Alignment (``align`` iterations, 8 by default; :mod:`~transient_mi.fit.mesh_align`): the start mesh's global
   affine map and its reflectance by Levenberg-Marquardt, from the start blur to the end blur: depth, tilt,
   extent and reflectance are coupled in the data, which a per-vertex first-order method follows slowly.
3. Carving (``carve`` iterations, 40 by default with one reflectance; :mod:`~transient_mi.fit.mesh_carve`): the
   aligned mesh grown by ``grow`` rings of faces ``cell_m`` wide around its open boundary (two by default:
   :func:`~transient_mi.fit.mesh_start.grow_ring`; a reconstruction's start also under-covers, where its edges fall
   below its threshold; docs/fit.md has what the rings gain), subdivided once, one reflectance per face fitted with
   the geometry held under a total-variation prior, the dark faces dropped (a start from a reconstruction
   over-covers; the vertex stage keeps its topology). Then, with one reflectance, the alignment again on the carved
   mesh (:func:`~transient_mi.fit.mesh_align.realign_carved`, half the first's iterations): the first aligned a
   start that covered too little or too much and took part of the difference for a tilt or a shift (the tilted plane's
   16 x 16 capture: 2.8 degrees and 6 mm off; 0.2 degrees and 0.7 mm after the realignment, a scratch run).
4. Stages: Adam on the regularised objective (:mod:`~transient_mi.fit.mesh_optimize`), the mesh subdivided in
   four between stages; the forward model is the capture's (:class:`~transient_mi.fit.capture_model.CaptureModel`:
   its scene, detector, gate, dark counts, pile-up, dead time, jitter) with the deterministic three-bounce
   estimator (``estimator="quadrature"``, always, whatever ``FitSettings.estimator`` or ``--estimator`` say),
   whose vertex derivative holds the area change a free deformation makes (the Monte Carlo renderer's does not);
   a capture the quadrature cannot render is refused in one line. Every stage renders and compares every
   ``pixel_step``-th pixel along each axis (:func:`~transient_mi.fit.mesh_settings.resolve_pixel_step`: by default
   8 pixels per side kept, as the Gauss-Newton fit).
5. Outputs in the output directory, each file written atomically, ``fit.json`` last:

   ``fit.json``        settings, the start and the fit summarised (vertices, faces, bounding box, reflectance),
                       the objective per iteration (data + regularisers), the Poisson NLL of the counts under
                       the start and the fit, metrics of the fit, of the start (its mesh voxelised on the same
                       grid) and of the backprojection against the scene's hidden shapes
   ``fitted.ply``      the fitted mesh (with ``reflectance="face"`` each face carries its fitted reflectance,
                       the float property ``reflectance_0``, Mitsuba's name for a one-channel attribute: its PLY
                       loader makes it the face attribute ``face_reflectance``, which a ``mesh_attribute``
                       texture reads); ``start.ply`` the start mesh; ``aligned.ply`` the start after the
                       alignment
   ``loss.png``        the objective per iteration and the temporal blur
   ``fit.png``         front views (depth maps): ground truth, backprojection, fit; ``views.png`` start, fit and
                       ground truth from the front, the top and the side
   ``checkpoint.json`` the optimiser's state; ``stage.json`` the current stage's start mesh (``--resume``)
   ``align.json``      the aligned vertices, reflectance, objective per iteration and time of the alignment
   ``carve.json``      the carved mesh (realigned; ``cut_vertices`` as cut), every subdivided face's reflectance
                       and whether it was kept, the objective per iteration and the time, the realignment
                       (``realigned``: iterations, reflectance, history, time); ``carved.ply`` the carved mesh
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from transient_core.errors import UserInputError
from transient_core.lock import output_lock

from .mesh_align import realign_iterations
from .mesh_regularizers import RegularizerWeights
from .mesh_settings import MeshSettings, carve_iterations, check_mesh_options, grow_rings, resolve_pixel_step
from .optimize import FitState

__all__ = ["MeshSettings", "fit_mesh_capture"]

#: A face grown around the aligned start (``grow``) starts the carving at this share of the aligned faces' median
#: reflectance (the aligned ones at theirs).
GROWN_SHARE = 0.5
#: fitted.ply's face property of a per-face reflectance (Mitsuba's PLY loader: the attribute ``face_reflectance``).
FACE_PLY_PROPERTY = "reflectance_0"

_OUTPUTS = ("fit.json", "fitted.ply", "start.ply", "aligned.ply", "carved.ply", "start.json", "align.json",
            "carve.json", "loss.png", "fit.png", "views.png", "checkpoint.json", "stage.json", "config.json")
def _check(mesh: MeshSettings, settings) -> None:
    check_mesh_options(mesh)
    if settings.iterations < mesh.stages:
        raise UserInputError(f"iterations={settings.iterations}: fewer than the {mesh.stages} stages")


def stage_starts(n: int, stages: int) -> list[int]:
    """First iteration of each stage: the last stage takes the second half, earlier ones split the first."""
    if stages == 1:
        return [0]
    half = n // 2
    return [round(half * k / (stages - 1)) for k in range(stages - 1)] + [half]


def _capture_model(capture, v, f, settings, bin_width_ps, reflectance: str = "global", pixel_step: int = 1):
    from .capture_model import CaptureModel

    try:  # (always the quadrature, whatever settings.estimator says: see the module docstring)
        return CaptureModel(capture, np.asarray(f, dtype=np.uint32), len(v), bin_width_ps=bin_width_ps,
                            estimator="quadrature", element_size_m=settings.element_size_m, dead_time="renewal",
                            reflectance=reflectance, pixel_step=pixel_step)
    except UserInputError as e:
        if not str(e).startswith("estimator=quadrature:"):
            raise
        why = str(e).split(": ", 2)[-1]
        raise UserInputError(f"--model mesh needs the quadrature forward model (its vertex derivative holds a free "
                             f"deformation's area change); this capture cannot use it: {why}") from None


def _model(v, f, albedo, mesh: MeshSettings, reg_scale: float):
    from .mesh_model import MeshModel

    w = RegularizerWeights(laplacian=mesh.laplacian, edge=mesh.edge, normal=mesh.normal,
                           albedo=mesh.albedo_smoothness)
    model = MeshModel(v, f, albedo, smoothing=mesh.smoothing, weights=w, step_m=mesh.step_m, reg_scale=reg_scale,
                      reflectance=mesh.reflectance)
    model.moments = mesh.moments
    return model


def _start_mesh(mesh: MeshSettings, rec_bp):
    from .mesh_start import closed_surface, front_surface, load_mesh

    if mesh.start_mesh:
        return load_mesh(mesh.start_mesh, mesh.cell_m)
    if mesh.start == "closed":
        return closed_surface(rec_bp.volume, rec_bp.grid, mesh.cell_m)
    return front_surface(rec_bp.volume, rec_bp.grid, mesh.cell_m)


def _match_albedo(model, cap, settings) -> float:
    """The reflectance that gives the start mesh as many counts as the capture holds."""
    from .optimize import element_size

    th = model.initial()
    cap.set_mesh(model.vertices(th), model.albedo(th))
    if hasattr(cap, "set_element_size"):
        cap.set_element_size(element_size(0, settings.iterations, settings.element_size_m))
    mu = cap.expected_counts(cap.ideal(0, 0, cap.jitter_sigma_ps))
    total = float(mu.sum())
    a = model.albedo_ref * cap.counts.sum() / total if total > 0 else model.albedo_ref
    return float(np.clip(a, 0.01, 1.0))


def _albedo_json(albedo):
    """A reflectance for the stage file: a float, or a list (one per face)."""
    a = np.asarray(albedo, dtype=np.float64)
    return float(a) if a.ndim == 0 else a.ravel().tolist()


def _write_stage(path: Path, stage: int, v, f, albedo, reg_scale: float) -> None:
    from .outputs import _write_text

    _write_text(path, json.dumps({"stage": int(stage), "vertices": np.asarray(v).tolist(),
                                  "faces": np.asarray(f, dtype=np.int64).tolist(), "albedo": _albedo_json(albedo),
                                  "reg_scale": float(reg_scale)}) + "\n")


def fit_mesh_capture(capture, out_dir, *, settings, bin_width_ps: float = 10.0, mesh: MeshSettings | None = None,
                     resume: bool = False, overwrite: bool = False, progress: bool | None = None, log=print) -> dict:
    """Fit a free mesh to a counts capture (module docstring); returns the content of ``fit.json``. Arguments as
    :func:`~transient_mi.fit.api.fit_capture`; ``mesh`` the model's settings (:class:`MeshSettings`)."""
    from transient_core.progress import progress_bar
    from transient_core.stack import read_manifest

    from .outputs import _backprojection, _bounds, claim_output, _write_text
    from .mesh_optimize import run_mesh_adam

    mesh = mesh or MeshSettings()
    settings = replace(settings, iterations=settings.n_iterations("adam"))  # (the mesh's Adam: 300)
    _check(mesh, settings)
    capture = Path(capture)
    if not (capture / "manifest.json").is_file():
        raise UserInputError(f"capture {str(capture)!r} is not a capture directory (no manifest.json)")
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise UserInputError(f"-o {out}: exists and is not a directory")
    config = {"capture": str(capture.resolve()), "model": "mesh", "settings": asdict(settings),
              "bin_width_ps": float(bin_width_ps), "mesh": asdict(mesh)}
    with output_lock(out):
        existing = claim_output(out, config, resume, overwrite)
        t_start = time.perf_counter()
        manifest = read_manifest(capture)
        mesh = resolve_pixel_step(mesh, int(manifest["width"]), int(manifest["height"]))
        bounds = _bounds(manifest)
        rec_bp = _backprojection(capture, bounds)
        ckpt, stage_file = out / "checkpoint.json", out / "stage.json"
        resuming = resume and ckpt.is_file() and stage_file.is_file()
        if not resuming:
            v0, f0 = _start_mesh(mesh, rec_bp)
        else:
            st = json.loads(stage_file.read_text())
            v0, f0 = np.asarray(st["vertices"]), np.asarray(st["faces"])
        cap = _capture_model(capture, v0, f0, settings, bin_width_ps, mesh.reflectance, mesh.pixel_step)
        if not resuming:  # (the start's faces across the device's lines of sight dropped: mesh_start)
            from .mesh_start import clear_view, device_sight_lines, encloses_volume

            sight = device_sight_lines(cap.sensor, cap.scene, cap.width, cap.height)  # (the device's: no mesh in it)
            v1, f1 = clear_view(v0, f0, *sight)
            if len(f1) != len(f0):
                v0, f0 = v1, f1
                cap = _capture_model(capture, v0, f0, settings, bin_width_ps, mesh.reflectance, mesh.pixel_step)
            if mesh.carve is None and encloses_volume(v0, f0):  # (a closed start is not carved: mesh_settings)
                mesh = replace(mesh, carve=0)
                log("fit mesh: the start encloses a volume: no carving")
        # (everything checked: only now is anything written)
        if existing and overwrite and not resume:
            for name in _OUTPUTS:
                (out / name).unlink(missing_ok=True)
        out.mkdir(parents=True, exist_ok=True)
        end = max(settings.sigma_end_ps, cap.jitter_sigma_ps)
        starts = stage_starts(settings.iterations, mesh.stages)
        if resuming:
            state = FitState.load(ckpt)
            stage, reg_scale = int(st["stage"]), float(st["reg_scale"])
            model = _model(v0, f0, np.asarray(st["albedo"], dtype=np.float64),
                           replace(mesh, step_m=mesh.step_m / 2 ** stage), reg_scale)
            if len(state.theta) != len(model.initial()):  # (stopped between a stage's mesh and its first checkpoint)
                k = starts[stage]
                state = FitState(theta=model.initial().tolist(), iteration=k, history=state.history[:k],
                                 elapsed_s=state.elapsed_s)
            first = json.loads((out / "start.json").read_text())
            start_v, start_f, start_albedo = np.asarray(first["vertices"]), np.asarray(first["faces"]), first["albedo"]
        else:
            reg_scale = cap.objective(np.zeros_like(cap.counts), end)[0]  # the signal energy (mesh_model)
            model = _model(v0, f0, 0.5, mesh, reg_scale)
            albedo = _match_albedo(model, cap, settings)
            start_v, start_f, start_albedo = v0, f0, albedo
            _write_text(out / "config.json", json.dumps(config, indent=1) + "\n")
            _write_text(out / "start.json", json.dumps({"vertices": np.asarray(v0).tolist(), "faces": np.asarray(
                f0, dtype=np.int64).tolist(), "albedo": albedo}) + "\n")
            align_history, align_s = [], 0.0
            if mesh.align:
                from .mesh_align import align_affine
                from .optimize import element_size

                cap.set_element_size(element_size(0, settings.iterations, settings.element_size_m))
                cap.keep_blur(end)
                t_align = time.perf_counter()
                v0, albedo, align_history = align_affine(cap, v0, albedo, iterations=mesh.align,
                                                         sigma_start_ps=settings.sigma_start_ps, sigma_end_ps=end)
                align_s = time.perf_counter() - t_align
                log(f"fit mesh: aligned (affine map and reflectance, {mesh.align} iterations) in {align_s:.0f} s")
            model = _model(v0, f0, albedo, mesh, reg_scale)
            stage = 0
            _write_text(out / "align.json", json.dumps({"vertices": np.asarray(v0).tolist(), "albedo": albedo,
                                                        "history": align_history, "seconds": align_s}) + "\n")
            if carve_iterations(mesh):
                v0, f0, albedo = _carve(out, capture, v0, f0, albedo, mesh, settings, bin_width_ps, end, log,
                                        progress, sight)
                cap = _capture_model(capture, v0, f0, settings, bin_width_ps, mesh.reflectance, mesh.pixel_step)
                if realign_iterations(mesh.align) and mesh.reflectance == "global":
                    from .mesh_align import realign_carved

                    v0, albedo, rec = realign_carved(cap, v0, albedo, mesh.align, settings, end)
                    carve = json.loads((out / "carve.json").read_text())  # (the realigned mesh beside the cut one)
                    carve.update(cut_vertices=carve["vertices"], vertices=np.asarray(v0).tolist(), realigned=rec)
                    _write_text(out / "carve.json", json.dumps(carve) + "\n")
                    log(f"fit mesh: the carved mesh realigned ({rec['iterations']} iterations) in "
                        f"{rec['seconds']:.0f} s")
                model = _model(v0, f0, albedo, mesh, reg_scale)
            _write_stage(stage_file, 0, v0, f0, albedo, reg_scale)
            state = FitState(theta=model.initial().tolist())
        with progress_bar("fit mesh", settings.iterations,
                          disable=None if progress is None else not progress) as advance:
            if state.iteration:
                advance(state.iteration)
            while True:
                stop = starts[stage + 1] if stage + 1 < len(starts) else settings.iterations
                run_mesh_adam(model, cap, state, settings, stage_start=starts[stage], stop=stop,
                              progress=lambda i, n, obj: advance(1), checkpoint=lambda s: s.save(ckpt))
                if stage + 1 >= len(starts):
                    break
                from .mesh_start import subdivide

                theta = np.asarray(state.theta)
                v1, f1 = subdivide(model.vertices(theta), model.faces)
                a1 = model.albedo(theta)  # (per face: each face's four children, consecutive, inherit it)
                a1 = a1 if mesh.reflectance == "global" else np.repeat(a1, 4)
                stage += 1
                cap = _capture_model(capture, v1, f1, settings, bin_width_ps, mesh.reflectance, mesh.pixel_step)
                model = _model(v1, f1, a1, replace(mesh, step_m=mesh.step_m / 2 ** stage), reg_scale)
                _write_stage(stage_file, stage, v1, f1, a1, reg_scale)
                state = FitState(theta=model.initial().tolist(), iteration=state.iteration, history=state.history,
                                 elapsed_s=state.elapsed_s)
                state.save(ckpt)
        fit_s = time.perf_counter() - t_start
        result = _finish(out, model, cap, manifest, rec_bp, (start_v, start_f, start_albedo), state, settings,
                         config, fit_s, capture, bin_width_ps)
        log(f"fit mesh: {settings.iterations} iterations in {state.elapsed_s:.0f} s of optimisation "
            f"({fit_s:.0f} s in all); wrote {out}/fit.json, fitted.ply, start.ply, loss.png, fit.png, views.png")
        return result


def _carve(out: Path, capture, v, f, albedo, mesh: MeshSettings, settings, bin_width_ps: float, end_ps: float, log,
           progress: bool | None = None, sight=None):
    """The carving step (:mod:`~transient_mi.fit.mesh_carve`): the aligned mesh grown by ``mesh.grow`` rings of
    faces ``mesh.cell_m`` wide around its open boundary (:func:`~transient_mi.fit.mesh_start.grow_ring`; the new
    faces that cross ``sight``, the device's lines of sight, dropped), subdivided once, one reflectance per face fitted
    (``mesh.carve_tv``'s prior), the dark faces dropped. Writes ``carve.json``; returns the kept mesh and its
    reflectance (per face with ``reflectance="face"``, else the median of the kept faces')."""
    from transient_core.progress import progress_bar

    from .mesh_carve import drop_faces, fit_face_reflectance, keep_faces
    from .mesh_start import crossed_faces, grow_ring, subdivide
    from .outputs import _write_text

    t = time.perf_counter()
    v, f = np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64)
    albedo = np.asarray(albedo, dtype=np.float64).ravel()
    n_aligned = len(f)
    rings = grow_rings(mesh)
    for _ in range(rings):
        v, f = grow_ring(v, f, mesh.cell_m)
    if len(f) > n_aligned:
        if sight is not None:  # (the new faces across the device's view go; the aligned ones stay, in their order)
            hit = crossed_faces(v, f, *sight)
            hit[:n_aligned] = False
            if hit.any():
                v, f = drop_faces(v, f, ~hit)
        # (a grown face starts at GROWN_SHARE of the aligned faces' median reflectance: it has to earn its light)
        albedo = np.concatenate([np.broadcast_to(albedo, (n_aligned,)),
                                 np.full(len(f) - n_aligned, GROWN_SHARE * float(np.median(albedo)))])
        log(f"fit mesh: grown by {rings} ring(s) of {100 * mesh.cell_m:.0f} cm: {n_aligned} -> {len(f)} faces")
    vs, fs = subdivide(v, f)
    start = np.broadcast_to(albedo, (len(f),))
    capf = _capture_model(capture, vs, fs, settings, bin_width_ps, "face", mesh.pixel_step)
    capf.keep_blur(end_ps)
    n = carve_iterations(mesh)
    with progress_bar("fit mesh: carve", n, disable=None if progress is None else not progress) as advance:
        rho, history = fit_face_reflectance(capf, vs, np.repeat(start, 4), n, end_ps, progress=lambda i, obj: advance(
            1), faces=fs, tv_weight=mesh.carve_tv)
    del capf
    keep = keep_faces(rho)
    vk, fk = drop_faces(vs, fs, keep)
    seconds = time.perf_counter() - t
    _write_text(out / "carve.json", json.dumps({
        "vertices": vk.tolist(), "faces": fk.tolist(), "aligned_faces": n_aligned, "grown_faces": int(len(f)),
        "subdivided_faces": int(len(fs)), "kept": int(keep.sum()), "reflectance": rho.tolist(), "keep": keep.tolist(),
        "history": history, "seconds": seconds}) + "\n")
    log(f"fit mesh: carved ({len(history) - 1} iterations) in {seconds:.0f} s: {keep.sum()} of {len(fs)} faces kept")
    kept = rho[keep]
    return vk, fk, (kept if mesh.reflectance == "face" else float(np.median(kept)))


def _nll(cap, v, f, albedo) -> float:
    cap.set_mesh(v, albedo)
    return cap.poisson_nll(cap.expected_counts(cap.ideal(0, 0, cap.jitter_sigma_ps)))


def _finish(out, model, cap, manifest, rec_bp, start, state, settings, config, fit_s, capture, bin_width_ps) -> dict:
    import trimesh

    from transient_mi.scenes._ply import write_ply

    from .outputs import _front_figure, _ground_truth, _loss_figure, _write_text, backprojection_metrics, mesh_metrics
    from .mesh_figures import three_view_figure

    from .mesh_optimize import fit_parameters

    theta = fit_parameters(model, cap, state)
    fitted = model.mesh(theta)
    sv, sf, salb = start
    start_mesh = trimesh.Trimesh(vertices=np.asarray(sv), faces=np.asarray(sf, dtype=np.int64), process=False)
    if hasattr(cap, "set_element_size"):
        cap.set_element_size(settings.element_size_m)
    nll = {"fit": _nll(cap, fitted.vertices, fitted.faces, model.albedo(theta))}
    cap0 = _capture_model(capture, sv, sf, settings, bin_width_ps, model.reflectance, cap.pixel_step)
    cap0.set_element_size(settings.element_size_m) if hasattr(cap0, "set_element_size") else None
    nll["start"] = _nll(cap0, np.asarray(sv), sf, float(salb))
    del cap0
    write_ply(out / "fitted.ply", fitted.vertices, fitted.faces,
              {FACE_PLY_PROPERTY: model.albedo(theta)} if model.reflectance == "face" else None)
    write_ply(out / "start.ply", start_mesh.vertices, start_mesh.faces)
    align = json.loads((out / "align.json").read_text())
    aligned = trimesh.Trimesh(vertices=np.asarray(align["vertices"]), faces=np.asarray(sf, dtype=np.int64),
                              process=False)
    write_ply(out / "aligned.ply", aligned.vertices, aligned.faces)
    carve = json.loads((out / "carve.json").read_text()) if (out / "carve.json").is_file() else None
    carved = None
    if carve is not None:
        carved = trimesh.Trimesh(vertices=np.asarray(carve["vertices"]),
                                 faces=np.asarray(carve["faces"], dtype=np.int64), process=False)
        write_ply(out / "carved.ply", carved.vertices, carved.faces)
    gt_mesh, _ = _ground_truth(manifest)
    metrics = {}
    if gt_mesh is not None:
        metrics = {"fit": mesh_metrics(fitted, rec_bp, gt_mesh), "start": mesh_metrics(start_mesh, rec_bp, gt_mesh),
                   "aligned": mesh_metrics(aligned, rec_bp, gt_mesh),
                   "backprojection": backprojection_metrics(rec_bp, gt_mesh)}
        if carved is not None:
            metrics["carved"] = mesh_metrics(carved, rec_bp, gt_mesh)
    _loss_figure(out / "loss.png", state)
    _front_figure(out / "fit.png", rec_bp, gt_mesh, fitted, metrics)
    three_view_figure(out / "views.png", [(sv, sf), (fitted.vertices, fitted.faces),
                                          None if gt_mesh is None else (gt_mesh.vertices, gt_mesh.faces)],
                      ["start", "fit", "ground truth"])
    mcfg = config["mesh"]
    result = {
        "status": "complete", "format": "transient-mi-fit", "format_version": 1, "config": config,
        "parameters": {"names": ["vertices (fitted.ply)", "albedo"],
                       "start": {"albedo": float(salb), "n_vertices": int(len(sv)), "n_faces": int(len(sf)),
                                 "source": mcfg["start_mesh"] or f"backprojection ({mcfg['start']})"},
                       "fit": model.as_dict(theta), "truth": None, "error": None},
        "regularizer": {"scale": model.reg_scale, "parts_at_fit": model.total_regularization(theta)[1]},
        "estimator": {"used": cap.estimator, "element_size_m": cap.element_size_m, "pixel_step": cap.pixel_step,
                      "pixels_used": [cap.height, cap.width]},
        "poisson_nll": {**nll, "counts": float(cap.counts.sum())},
        "metrics": metrics,
        "history": {"objective": [h[0] for h in state.history], "sigma_ps": [h[1] for h in state.history],
                    "seconds": [h[2] for h in state.history],
                    "objective_end_blur": [h[3] for h in state.history]},
        "align": {"iterations": len(align["history"]), "albedo": align["albedo"],
                  "objective": [h[0] for h in align["history"]], "sigma_ps": [h[1] for h in align["history"]]},
        "carve": None if carve is None else {"iterations": len(carve["history"]) - 1, "kept": carve["kept"],
                                             "aligned_faces": carve.get("aligned_faces"),
                                             "grown_faces": carve.get("grown_faces"),
                                             "subdivided_faces": carve["subdivided_faces"],
                                             "objective": [h[0] for h in carve["history"]],
                                             "realigned": None if "realigned" not in carve else {
                                                 k: carve["realigned"][k] for k in ("iterations", "albedo",
                                                                                    "seconds")}},
        "time_s": {"align": align["seconds"], "carve": None if carve is None else carve["seconds"],
                   "realign": None if carve is None or "realigned" not in carve else carve["realigned"]["seconds"],
                   "optimisation": state.elapsed_s, "total": fit_s},
        "bounds": list(_bounds_of(rec_bp)),
    }
    _write_text(out / "fit.json", json.dumps(result, indent=1) + "\n")
    return result


def _bounds_of(rec) -> tuple:
    g = rec.grid
    return (float(g.x_m[0]), float(g.x_m[-1]), float(g.y_m[0]), float(g.y_m[-1]), float(g.z_m[0]),
            float(g.z_m[-1]))
