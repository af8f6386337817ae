"""The methods study: a leaderboard of every reconstruction method x SPAD array size x photon budget.

For every array size: render the scene's ideal capture once (``-D array=N``,
or ``-D width=N -D height=N``), by default until its rendering noise is at most
0.1 x the photon noise of the largest exposure, 0.01 x where the deterministic
quadrature renders it (``noise_target``; for Monte Carlo the scene's
spp is the pilot; rows record the samples used, ``render_spp``, and each
exposure's measured ratio, ``render_noise_ratio``); for every exposure detect it in memory
(:class:`~transient_mi.study.detection.Detection`, detection seed
``seed + 1``, the same counts ``transient-mi detect`` writes); reconstruct
the counts with every method (+ the paper's filter with each method's default threshold)
on the same voxel grid and score each against the ground truth
(:func:`recon.metrics.compute_metrics`: Chamfer, completeness, IoU, depth
MAE, the visible-surface distances, silhouette IoU, normal error). Each
reconstruction is timed (wall clock, in this process, after an untimed
warm-up of every method so numba's compilation is not charged) and its
peak memory measured with :mod:`tracemalloc` (numpy's allocations; FFT
scratch inside scipy is not traced, so this is a lower bound of the
process's peak).

With ``fit`` (a model of :mod:`transient_mi.fit`), each array x exposure (of the
arrays in ``fit_arrays``, default all) also gets the analysis-by-synthesis fit (what ``transient-mi fit`` runs, with its
default optimiser settings unless ``fit_iterations`` is given) of the same
detected counts (written once with ``transient-mi detect``'s writer, the same
detection seed), as a row ``fit:<model>``: its fitted surface, voxelised on the
study's grid (the voxels it passes through), is scored like the methods' volumes.
Its time is the fit's wall clock (backprojection start, optimisation, outputs);
its traced memory sees numpy only, not Dr.Jit's buffers. A model fit
(``mannequin``, ``patches``) knows the object's kind, so the targets that name
non-fitting methods exclude it (:func:`is_fit`); ``fit:mesh`` (a free mesh
from the front surface of :data:`FIT_MESH_START`'s reconstruction of the same counts,
:mod:`transient_mi.fit.mesh_fit`) knows no kind, and is marked by the same
prefix.

Ground truth: the paper scene knows its mannequin; for other scenes the
study builds it from the scene itself (every mesh shape except the relay
wall, :func:`scene_ground_truth`), unless one is given.

Outputs (``out_dir``, atomic): ``leaderboard.csv``/``leaderboard.json``
(one row per scene x array x exposure x method; metrics and time/memory),
``leaderboard.png`` (Chamfer, visible completeness and time against array
size per method, at each exposure), ``reconstructions.png`` (front views of
every method at the largest array and exposure), ``summary.md`` (the ranked
table).
"""

from __future__ import annotations

import shutil
import time
import tracemalloc
from dataclasses import asdict
from pathlib import Path

import numpy as np

from transient_core.progress import progress_bar
from transient_core.errors import UserInputError
from transient_mi.noise_target import rendered_spp
from transient_mi.reporting import atomic_output_dir, markdown_table, write_csv, write_json

from . import validate as V
from .common import (bar_enabled, capture_estimator, front_view, noise_target_spec, quiet_inner_bars, render,
                     resolve_noise_target)
from .methods_fit import (FIT_BIN_WIDTH_PS, FIT_MESH_START, FIT_MODELS, FIT_PREFIX, fit_bin_width_ps,  # noqa: F401
                          fit_row, is_fit)
from .methods_fit import fit_arrays as check_fit_arrays
from .methods_fit import fit_models
from .methods_fit import fit_settings as check_fit_settings
from .metrics_rows import LEADERBOARD_METRICS, score as _metrics
from .scene import array_size_defines, base_detector, load_study_ground_truth, reconstruction_bounds, study_scene

#: Every method that reconstructs array captures.
DEFAULT_METHODS = ("bp", "fbp", "phasor", "midpoint-lct", "midpoint-fk")
DEFAULT_ARRAYS = (8, 16, 32)
#: Per laser spot: a tenth of the paper's budget, the paper's (10 ms = 5e5 pulses at 50 MHz).
DEFAULT_EXPOSURES_S = (0.001, 0.01)
#: Suffix of the method name in rows of completed reconstructions (``complete=...``).
COMPLETION_SUFFIX = "+completion"
ROW_COLUMNS = ("scene", "array", "exposure_s", "method", "counts_per_pixel_per_spot", "render_spp",
               "render_noise_ratio") + LEADERBOARD_METRICS + (
    "reconstruct_s", "peak_traced_mb")


def scene_ground_truth(scene) -> object:
    """The hidden geometry of a scene as a ``recon.metrics.GroundTruth``: every mesh shape but ``relay_wall``.

    Loads the scene with Mitsuba (its ``-D`` values applied) and joins the
    world-space triangles of every shape that is a mesh (Mitsuba's
    rectangles, discs and PLY/OBJ shapes are) other than the relay wall and windows
    (:func:`transient_mi.integrators._device_legs.is_window_bsdf`: a glass pane in front of the device).
    """
    import transient_mi  # noqa: F401  (sets the variant before mitsuba is used)
    import mitsuba as mi
    import trimesh

    from recon.metrics import GroundTruth
    from transient_mi.integrators._device_legs import is_window_bsdf
    from transient_mi.scene_io import load_scene

    sc = load_scene(scene.path, scene.defines)
    parts = []
    for shape in sc.shapes():
        if shape.id() == "relay_wall" or not isinstance(shape, mi.Mesh) or is_window_bsdf(shape.bsdf()):
            continue
        v = np.array(shape.vertex_positions_buffer(), dtype=np.float64).reshape(-1, 3)
        f = np.array(shape.faces_buffer(), dtype=np.int64).reshape(-1, 3)
        parts.append(trimesh.Trimesh(v, f, process=False))
    if not parts:
        raise UserInputError(f"SCENE {scene.path.name}: no mesh shape besides relay_wall to score against; "
                             "pass a ground truth")
    return GroundTruth(mesh=trimesh.util.concatenate(parts), source=f"{scene.path.name} (its shapes)")


def run_methods_study(scene="paper_mannequin", out_dir="out/study-methods", *, arrays=DEFAULT_ARRAYS,
                      exposures_s=DEFAULT_EXPOSURES_S, methods=DEFAULT_METHODS, defines=None, voxels=(64, 64, 32),
                      seed: int = 0, quick: bool = False, progress: bool | None = None, ground_truth=None,
                      bounds=None, threshold: str | None = None, complete=None, fit=None,
                      fit_iterations=None, fit_arrays=None,
                      noise_target: float | None | str = "auto", overwrite: bool = False, log=None):
    """Run the methods study (see the module docstring); returns ``(out_dir, rows)``.

    Parameters
    ----------
    scene : str or path
        Shipped scene name or XML file with ``array`` or ``width``/``height``.
    arrays : sequence of int
        SPAD array sides.
    exposures_s : sequence of float
        Exposure per laser spot, seconds.
    methods : sequence of str
        :data:`recon.pipeline.METHODS` that accept array captures.
    defines : dict, optional
        Scene parameters (``-D``), e.g. ``{"spp": 16384, "bin_width_ps": 4, "n_bins": 2875}``.
    threshold : str, optional
        Threshold of the paper's filter for every method; default each method's
        own (:func:`recon.pipeline.default_threshold`).
    complete : "auto" or float, optional
        Also score every reconstruction closed behind its front under the
        completion prior (:func:`recon.completion.complete_surface`), as rows
        named ``<method>+completion`` whose time includes the completion's.
    fit : {"mannequin", "patches", "mesh"} or sequence of them, optional
        Also fit this model (or each of these models, in order) of :mod:`transient_mi.fit` to every array x
        exposure's counts (row ``fit:<model>``; see the module docstring). Minutes per fit.
    fit_iterations : int or dict, optional
        The fit's iterations (default :class:`transient_mi.fit.FitSettings`'s): one count for every model, or
        ``{model: count}`` (e.g. ``{"mesh": 40}``; the models it leaves out keep the default).
    fit_arrays : sequence of int or dict, optional
        The arrays whose counts are fitted (default every one of ``arrays``): one list for every model or
        ``{model: list}``. A fit's cost grows with pixels x spots, so a free mesh (``fit="mesh"``) may be fitted
        on the smaller arrays only.
    noise_target : float, None or "auto"
        Render each array's ideal capture until its rendering variance is at most this share of the photon
        variance at the largest exposure (every smaller exposure then has a smaller ratio); the scene's spp is
        the pilot (:mod:`transient_mi.noise_target`). ``"auto"``: 0.1 (0.01 where the quadrature renders the scene:
        :data:`~transient_mi.study.common.QUADRATURE_AUTO_TARGET`), or None with ``quick``. None renders the
        scene's spp as it is. Either way every row records the measured ratio (``render_noise_ratio``,
        :mod:`spad_detector.render_noise`) and the samples used (``render_spp``).
    voxels, seed, quick, progress, ground_truth, bounds, overwrite, log
        As for :func:`~transient_mi.study.run_array_size_study`.
    """
    log = log or (lambda msg: None)
    arrays = tuple(sorted(V.integers_list(arrays, "arrays", 1, 257)))
    exposures = tuple(sorted(V.numbers_list(exposures_s, "exposures_s")))
    methods = tuple(V.method(m) for m in methods)
    if not methods:
        raise UserInputError("methods: give at least one reconstruction method")
    from recon.pipeline import CONFOCAL_ONLY

    bad = [m for m in methods if m in CONFOCAL_ONLY]
    if bad:
        raise UserInputError(f"methods: {', '.join(bad)} need confocal captures; the study renders array captures "
                             f"(use midpoint-{bad[0]})")
    vox = V.voxels(voxels)
    if complete is not None:
        from recon.completion import check_aspect

        check_aspect(complete)
    seed = V.integer(seed, "seed", 0, 2**32)
    fits = fit_models(fit)
    fit_settings = check_fit_settings(fits, fit_iterations)
    fit_arrays = check_fit_arrays(fits, fit_arrays, arrays)
    progress = V.progress(progress)
    quick = V.flag(quick, "quick")
    given_target = noise_target
    noise_target = resolve_noise_target(noise_target, quick)
    sc = study_scene(scene, defines, quick=quick)
    if any(k in (defines or {}) for k in array_size_defines(sc, arrays[0])):
        raise UserInputError(f"defines: {', '.join(array_size_defines(sc, arrays[0]))} are set by the study; "
                             "choose the sizes with arrays (--arrays)")
    if ground_truth is None and not sc.is_paper:
        gt, gt_desc = scene_ground_truth(sc), f"{sc.path.name}: its shapes except the relay wall"
    else:
        gt, gt_desc = load_study_ground_truth(sc, ground_truth)
    bnds = reconstruction_bounds(sc, bounds)
    params = base_detector(sc)
    spec = noise_target_spec(given_target, noise_target, params, max(exposures))
    out = Path(out_dir)
    t_start = time.perf_counter()
    rows, previews = [], []
    n_steps = len(arrays) * (1 + len(exposures) * len(methods)) + sum(map(len, fit_arrays.values())) * len(exposures)
    with atomic_output_dir(out, V.flag(overwrite, "overwrite")) as tmp, quiet_inner_bars():
        with progress_bar("methods study", total=n_steps, disable=not bar_enabled(progress)) as advance:
            warmed = False
            estimators = {}  # array -> the estimator that made its ideal capture
            for n in arrays:
                log(f"{n}x{n}: render")
                cap_dir = tmp / "captures" / f"array_{n:02d}"
                cap_dir.mkdir(parents=True)
                ideal_dir = render(sc.with_defines(**array_size_defines(sc, n)), cap_dir / "ideal", seed,
                                   noise_target=spec)
                estimator = capture_estimator(ideal_dir)
                estimators[n] = estimator
                spp = None if estimator == "quadrature" else rendered_spp(ideal_dir, sc.spp)  # no samples to count
                advance(1)
                for e in exposures:
                    cap, counts_per, noise_ratio = _detect(ideal_dir, params, e, seed + 1)
                    if spec is not None and noise_ratio is not None and noise_ratio > spec.target:
                        log(f"{n}x{n}, {e * 1e3:g} ms per spot: rendering noise {noise_ratio:.3g}x the photon noise, "
                            f"above the target {spec.target:g} (the render stopped at its "
                            + ("refinement rounds)" if estimator == "quadrature" else "spp cap)"))
                    base = {"scene": sc.path.stem, "array": n, "exposure_s": e,
                            "counts_per_pixel_per_spot": counts_per, "render_spp": spp,
                            "render_noise_ratio": noise_ratio}
                    if bnds is None:
                        from recon.grid import default_bounds

                        bnds = tuple(float(b) for b in default_bounds(cap))
                    if not warmed:   # numba compiles on first use: not charged to the first timed method
                        for m in methods:
                            _reconstruct(cap, m, bnds, vox, threshold)
                        warmed = True
                    recs = {}
                    for m in methods:
                        log(f"{n}x{n}, {e * 1e3:g} ms per spot: {m}")
                        rec, dt, peak = _reconstruct(cap, m, bnds, vox, threshold)
                        recs[m] = rec
                        metrics = _metrics(rec, gt, seed)
                        rows.append({**base, "method": m, **{k: metrics.get(k) for k in LEADERBOARD_METRICS},
                                     "reconstruct_s": dt, "peak_traced_mb": peak / 2**20})
                        if n == arrays[-1] and e == exposures[-1]:
                            previews.append((m, front_view(rec)))
                        if complete is not None:
                            rows.append(_completed_row(rows[-1], rec, complete, gt, seed))
                        advance(1)
                    for model in fits:
                        if n not in fit_arrays[model]:
                            continue
                        log(f"{n}x{n}, {e * 1e3:g} ms per spot: fit {model}")
                        # scored on the grid the methods just used
                        row, frec = fit_row(tmp / "fit_work", ideal_dir, params, e, seed + 1, model,
                                             fit_settings[model], rec.grid, gt, base, start=recs.get(FIT_MESH_START))
                        rows.append(row)
                        if n == arrays[-1] and e == exposures[-1]:
                            previews.append((row["method"], front_view(frec)))
                        advance(1)
                shutil.rmtree(tmp / "captures" / f"array_{n:02d}")
        shutil.rmtree(tmp / "captures", ignore_errors=True)
        settings = {"scene": sc.name, "scene_file": sc.path.name, "defines": dict(sorted(sc.defines.items())),
                    "spp": sc.spp, "arrays": list(arrays), "exposures_s": list(exposures), "methods": list(methods),
                    "voxels": list(vox), "bounds_m": list(bnds) if bnds is not None else None,
                    "threshold": threshold or "each method's default (recon.pipeline.default_threshold)",
                    "completion": None if complete is None else str(complete),
                    "noise_target": None if spec is None else spec.target,
                    "estimators": {str(k): v for k, v in estimators.items()},
                    "fit": _fit_record(fits, fit_arrays, fit_settings, methods),
                    "render_seed": seed, "detection_seed": seed + 1,
                    "detector": params.to_dict(), "ground_truth": gt_desc,
                    "total_s": time.perf_counter() - t_start}
        write_csv(tmp / "leaderboard.csv", rows, ROW_COLUMNS)
        write_json(tmp / "leaderboard.json", {"study": "methods", "settings": settings, "rows": rows})
        if gt is not None and gt.mesh is not None:
            gt.mesh.export(tmp / "ground_truth.ply")
        leaderboard_figure(tmp / "leaderboard.png", rows)
        from .figures import reconstruction_strip

        reconstruction_strip(tmp / "reconstructions.png", previews, gt.mesh if gt is not None else None,
                             title=f"{sc.path.stem}: {arrays[-1]}x{arrays[-1]} array, {exposures[-1] * 1e3:g} ms "
                                   "per spot, filtered front views per method")
        (tmp / "summary.md").write_text(summary_markdown(rows, settings))
    log(f"wrote {out} in {time.perf_counter() - t_start:.1f} s")
    return out, rows


def _fit_record(fits: tuple, fit_arrays: dict, fit_settings: dict, methods: tuple):
    """The leaderboard's ``settings["fit"]``: None without fits; one model's settings as a dict (``model``,
    ``arrays``, the optimiser's settings and, for a free mesh, its ``start``); a list of such dicts for several."""
    # (a free mesh always renders by the quadrature, whatever FitSettings.estimator says: transient_mi.fit.mesh_fit)
    recs = [{"model": m, "arrays": list(fit_arrays[m]), **asdict(fit_settings[m]),
             **({"estimator": "quadrature", "start": f"{FIT_MESH_START}'s front surface" if FIT_MESH_START in methods
                 else "the backprojection's front surface"} if m == "mesh" else {})} for m in fits]
    if not recs:
        return None
    return recs[0] if len(recs) == 1 else recs


def fit_records(settings: dict) -> list:
    """Every fit of a leaderboard's settings as a list of dicts (:func:`_fit_record`'s one or several)."""
    f = settings.get("fit")
    return [] if not f else ([f] if isinstance(f, dict) else list(f))


def _detect(ideal_dir: Path, params, exposure_s: float, seed: int):
    from .detection import Detection, IdealCapture

    det = Detection(IdealCapture(ideal_dir), params, exposure_s=exposure_s)
    cap = det.capture(seed)
    data = cap.data   # detect every spot once; the methods then share the cached counts
    n_px = cap.height * cap.width * cap.n_files
    return cap, float(data.sum(dtype=np.int64)) / n_px, det.render_noise().get("ratio")


def _reconstruct(cap, method: str, bounds, voxels, threshold: str):
    import recon

    tracemalloc.start()
    try:
        t0 = time.perf_counter()
        rec = recon.reconstruct(cap, method, bounds=bounds, voxels=voxels, filter="paper", threshold=threshold)
        dt = time.perf_counter() - t0
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    return rec, dt, peak


def _completed_row(row: dict, rec, complete, gt, seed: int) -> dict:
    """The row of ``rec`` closed behind its front (:func:`recon.completion.complete_surface`)."""
    from recon.completion import complete_surface

    t0 = time.perf_counter()
    done = complete_surface(rec, complete)
    dt = time.perf_counter() - t0
    metrics = _metrics(done, gt, seed)
    aspects = [a["aspect"] for a in done.params["completion"]["aspects"]]
    return {**row, "method": row["method"] + COMPLETION_SUFFIX, **{k: metrics.get(k) for k in LEADERBOARD_METRICS},
            "reconstruct_s": row["reconstruct_s"] + dt, "completion_aspects": aspects}


# ------------------------------------------------------------------ reporting


def ranked(rows: list[dict], key: str = "chamfer_m") -> list[dict]:
    """Rows sorted by ``key`` (missing values last)."""
    return sorted(rows, key=lambda r: (r.get(key) is None, r.get(key) if r.get(key) is not None else 0.0))


def summary_markdown(rows: list[dict], settings: dict) -> str:
    """The leaderboard as markdown: per scene, the largest array at each exposure, ranked by Chamfer."""
    def cm(v):
        return "-" if v is None else f"{100 * v:.2f}"

    def f3(v):
        return "-" if v is None else f"{v:.3f}"

    headers = ["scene", "array", "ms/spot", "method", "Chamfer (cm)", "completeness (cm)", "IoU", "depth MAE (cm)",
               "visible Chamfer (cm)", "visible compl. (cm)", "visible IoU", "silhouette IoU", "normal err (deg)",
               "time (s)",
               "peak MB"]
    table = []
    for r in ranked(rows):
        table.append([r["scene"], f"{r['array']}x{r['array']}", f"{r['exposure_s'] * 1e3:g}", r["method"],
                      cm(r["chamfer_m"]), cm(r["completeness_m"]), f3(r["iou"]), cm(r["depth_mae_m"]),
                      cm(r["visible_chamfer_m"]), cm(r["visible_completeness_m"]), f3(r.get("visible_iou")),
                      f3(r["silhouette_iou"]),
                      "-" if r["normal_error_deg"] is None else f"{r['normal_error_deg']:.1f}",
                      f"{r['reconstruct_s']:.2f}", f"{r['peak_traced_mb']:.0f}"])
    s = settings
    ratios = [r["render_noise_ratio"] for r in rows if r.get("render_noise_ratio") is not None]
    worst = max(ratios) if ratios else None
    if s.get("noise_target") is not None:
        noise_note = (f" Each array's ideal capture was rendered until its rendering noise was at most "
                      f"{s['noise_target']:g} x the photon noise at the largest exposure; "
                      f"measured at every point: at most {worst:.3g} x.") if worst is not None else ""
    else:
        noise_note = ("" if worst is None else
                      f" Ideal captures rendered at {s['spp']} spp without a noise target: rendering noise up to "
                      f"{worst:.3g} x the photon noise" + (" (above the usual 0.1: read small differences with care)."
                                                            if worst > 0.1 else "."))
    est = sorted(set((s.get("estimators") or {}).values()))
    if est:  # which estimator made the ideal captures (a one-line note)
        noise_note += (" Ideal captures rendered by " + " and ".join(est) +
                       (" (deterministic three-bounce quadrature, its stated error standing for the rendering noise; "
                        "docs/quadrature.md)." if est == ["quadrature"] else "."))
    fit_note = "".join(_fit_note(f) for f in fit_records(s))
    return f"""# Methods study (leaderboard)

Scene `{s['scene_file']}` (-D {', '.join(f'{k}={v}' for k, v in s['defines'].items()) or 'defaults'}), arrays
{', '.join(f'{a}x{a}' for a in s['arrays'])}, exposures {', '.join(f'{e * 1e3:g} ms' for e in s['exposures_s'])}
per laser spot, methods {', '.join(s['methods'])}; {s['voxels'][0]}x{s['voxels'][1]}x{s['voxels'][2]} voxels over
{s['bounds_m']} m, the paper's filter (threshold `{s['threshold']}`). Ground truth: {s['ground_truth']}.
Total {s['total_s']:.0f} s.

Ranked by Chamfer distance. "visible" distances use only the surface the relay wall sees (the back of an
object sends no three-bounce light; definitions in `recon/metrics.py`). Rows `<method>+completion` are closed
behind the front under a stated prior (elliptical cross-sections, `recon/completion.py`), not measured.{fit_note} Time: wall clock of reconstruction +
filter in this process; peak MB: numpy allocations traced by tracemalloc (a lower bound of the process's peak).{noise_note}

{markdown_table(headers, table)}
"""


def _fit_note(fit: dict) -> str:
    """The summary's sentence on one fit's rows: a model fit knows the object's kind; a free mesh does not."""
    arrays = ", ".join(f"{n}x{n}" for n in fit.get("arrays") or [])
    head = (f" Rows `{FIT_PREFIX}{fit['model']}` are the analysis-by-synthesis fit of a {fit['model']} model "
            f"(`transient-mi fit`, {fit['iterations']} iterations; arrays {arrays}) to the same counts, its surface "
            "voxelised on the grid: ")
    if fit["model"] == "mesh":
        return head + (f"a free mesh from {fit.get('start', 'its start')}, which knows no kind of object, so a "
                       "reconstruction from the counts alone. Its time is the fit's; its peak MB misses Dr.Jit's "
                       "buffers.")
    return head + ("model-based (it knows what kind of object hides), so not a reconstruction method; the mannequin "
                   "model starts from the paper's pose, which is this scene's unless `-D pose`/`joints` change it. "
                   "Its time is the fit's; its peak MB misses Dr.Jit's buffers.")


def leaderboard_figure(path: Path, rows: list[dict]) -> Path:
    """Chamfer, visible completeness and time against array size, one line per method, per exposure (completed
    rows dashed, in their method's colour)."""
    from transient_mi.reporting import save_figure, subplots

    exposures = sorted({r["exposure_s"] for r in rows})
    methods = list(dict.fromkeys(r["method"] for r in rows))
    bases = list(dict.fromkeys(m.removesuffix(COMPLETION_SUFFIX) for m in methods))
    keys = (("chamfer_m", "Chamfer (cm)", 100), ("visible_completeness_m", "visible completeness (cm)", 100),
            ("reconstruct_s", "reconstruction time (s)", 1))
    fig, axes = subplots(len(exposures), len(keys), figsize=(4.4 * len(keys), 3.4 * len(exposures)), squeeze=False)
    for i, e in enumerate(exposures):
        for k, (key, label, scale) in enumerate(keys):
            ax = axes[i, k]
            for j, m in enumerate(methods):
                rr = sorted((r for r in rows if r["exposure_s"] == e and r["method"] == m), key=lambda r: r["array"])
                xs = [r["array"] for r in rr]
                ys = [np.nan if r.get(key) is None else scale * r[key] for r in rr]
                done = m.endswith(COMPLETION_SUFFIX)   # a completed row: its method's colour, dashed
                ax.plot(xs, ys, marker="o", label=m, color=f"C{bases.index(m.removesuffix(COMPLETION_SUFFIX))}",
                        linestyle="--" if done else "-", markerfacecolor="white" if done else None)
            ax.set_xscale("log", base=2)
            xs = sorted({r["array"] for r in rows})
            ax.set_xticks(xs, [f"{a}x{a}" for a in xs])
            ax.set_ylabel(label)
            ax.set_title(f"{e * 1e3:g} ms per spot", fontsize=9)
            if key == "reconstruct_s":
                ax.set_yscale("log")
            ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7)
    for ax in axes[-1]:
        ax.set_xlabel("SPAD array side (pixels)")
    fig.tight_layout()
    return save_figure(fig, path)
