"""The analysis-by-synthesis fit as a row of the methods study (:func:`~transient_mi.study.methods.run_methods_study`
with ``fit``): the fit's settings and arrays, its time bins, and :func:`fit_row`, which detects the array's ideal
capture, fits a model of :mod:`transient_mi.fit` to the counts and scores the fitted surface on the study's grid."""

from __future__ import annotations

import shutil
import time
import tracemalloc
from dataclasses import replace
from pathlib import Path

import numpy as np

from transient_core.errors import UserInputError

from . import validate as V
from .metrics_rows import LEADERBOARD_METRICS, score

#: Prefix of the method name in rows of fits (``fit=...``): ``fit:mannequin``.
FIT_PREFIX = "fit:"
#: Models ``fit`` accepts (:mod:`transient_mi.fit.models`).
FIT_MODELS = ("mannequin", "patches", "mesh")
#: The method whose reconstruction (of the same counts) the free mesh (``fit="mesh"``) starts from, as its front
#: surface, when the study runs it (the leaderboards' best non-fitting method); else the fit's own start (the
#: backprojection's front surface, :mod:`transient_mi.fit.mesh_start`).
FIT_MESH_START = "midpoint-fk"
#: The fit's time bins reach at least this, ps (:func:`fit_bin_width_ps`).
FIT_BIN_WIDTH_PS = 10.0

def fit_models(fit) -> tuple:
    """The models to fit, in the order given: none for ``fit=None``; ``fit`` one model of :data:`FIT_MODELS` or a
    sequence of them (each at most once)."""
    if fit is None:
        return ()
    models = (fit,) if isinstance(fit, str) else tuple(fit)
    if not models:
        raise UserInputError(f"fit={fit!r}: give a model ({', '.join(FIT_MODELS)}) or several, or none")
    for m in models:
        if m not in FIT_MODELS:
            raise UserInputError(f"fit={m!r}: allowed {', '.join(FIT_MODELS)}")
    if len(set(models)) != len(models):
        raise UserInputError(f"fit={list(models)!r}: each model at most once")
    return models


def _per_model(value, models: tuple, name: str) -> dict:
    """``value`` for every model: a mapping ``{model: value}`` (models it does not name: None) or one value for
    all."""
    if isinstance(value, dict):
        unknown = [k for k in value if k not in models]
        if unknown:
            raise UserInputError(f"{name}={value!r}: {unknown[0]!r} is not one of the fitted models "
                                 f"{', '.join(models) or '(none: give fit)'}")
        return {m: value.get(m) for m in models}
    return {m: value for m in models}


def fit_settings(models: tuple, fit_iterations) -> dict:
    """``{model: FitSettings}`` of every model of ``models`` (:func:`fit_models`'s; empty without one).
    ``fit_iterations``: one count for every model, or ``{model: count}`` (the others: the fit's default)."""
    if not models:
        if fit_iterations is not None:
            raise UserInputError(f"fit_iterations={fit_iterations!r}: needs fit (a model: {', '.join(FIT_MODELS)})")
        return {}
    from transient_mi.fit import FitSettings

    out = {}
    for m, n in _per_model(fit_iterations, models, "fit_iterations").items():
        out[m] = FitSettings() if n is None else FitSettings(
            iterations=V.integer(n, "fit_iterations" + ("" if len(models) == 1 else f" of {m}"), 1, 100_000))
    return out


def fit_arrays(models: tuple, fit_arrays, arrays) -> dict:
    """``{model: arrays}``: the array sides each model of ``models`` (:func:`fit_models`'s) is fitted on (empty
    without one; default every one of ``arrays``); ``fit_arrays`` one list for every model or ``{model: list}``;
    each must be one of ``arrays``."""
    if not models:
        if fit_arrays is not None:
            raise UserInputError(f"fit_arrays={fit_arrays!r}: needs fit (a model: {', '.join(FIT_MODELS)})")
        return {}
    out = {}
    for m, given in _per_model(fit_arrays, models, "fit_arrays").items():
        if given is None:
            out[m] = tuple(arrays)
            continue
        chosen = tuple(sorted(V.integers_list(given, "fit_arrays", 1, 257)))
        bad = [n for n in chosen if n not in arrays]
        if bad or not chosen:
            raise UserInputError(f"fit_arrays={list(chosen)!r}: each must be one of the study's arrays "
                                 f"{', '.join(str(n) for n in arrays)}")
        out[m] = chosen
    return out


def is_fit(method: str) -> bool:
    """Whether a leaderboard row's method is a model fit (``fit:<model>``), not a reconstruction method."""
    return str(method).startswith(FIT_PREFIX)


def fit_bin_width_ps(capture_bin_width_ps: float, n_bins: int) -> float:
    """The fit's bin width for a capture: the smallest whole multiple ``k`` of its bin width that is
    >= :data:`FIT_BIN_WIDTH_PS` and divides its ``n_bins`` (the fit sums ``k`` bins into one); ps."""
    import math

    k = max(1, math.ceil(FIT_BIN_WIDTH_PS / float(capture_bin_width_ps) - 1e-9))
    while n_bins % k:
        k += 1
    return float(capture_bin_width_ps) * k


def fit_row(work: Path, ideal_dir: Path, params, exposure_s: float, seed: int, model: str, settings, grid, gt,
             base: dict, start=None):
    """Detect ``ideal_dir`` to a counts capture, fit ``model`` to it, score the fitted surface on ``grid``
    (``model="mesh"`` starts from ``start``'s front surface, a :class:`recon.result.Reconstruction` of the same
    counts, where given).

    Returns ``(row, reconstruction)``; the reconstruction's volume marks the voxels the fitted surface passes
    through (:func:`recon.metrics.mesh_occupancy`).
    """
    from spad_detector import detect_stack
    from transient_mi.fit import fit_capture
    from transient_core.stack import read_manifest

    counts = detect_stack(ideal_dir, work / "counts", params, exposure_s=exposure_s, seed=seed, progress=False)
    t = read_manifest(counts)["time"]
    bw = fit_bin_width_ps(float(t["bin_width_ps"]), int(t["n_bins"]))
    tracemalloc.start()
    try:
        t0 = time.perf_counter()
        mesh = (_mesh_start(work, start, settings.n_iterations("adam")) if model == "mesh" and start is not None
                else None)
        res = fit_capture(counts, work / "fit", model=model, settings=settings, bin_width_ps=bw, progress=False,
                          log=lambda *a: None, mesh=mesh)
        dt = time.perf_counter() - t0
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    iterations = (res.get("optimizer") or {}).get("iterations") or res["config"]["settings"]["iterations"]
    rec = mesh_reconstruction(work / "fit" / "fitted.ply", grid, FIT_PREFIX + model,
                              {"fit": {"model": model, "iterations": iterations, "bin_width_ps": bw}})
    metrics = score(rec, gt, 0)
    m = res.get("metrics") or {}
    row = {**base, "method": FIT_PREFIX + model, **{k: metrics.get(k) for k in LEADERBOARD_METRICS},
           "reconstruct_s": dt, "peak_traced_mb": peak / 2**20, "fit_iterations": iterations,
           "fit_bin_width_ps": bw, "fit_poisson_nll": res["poisson_nll"],
           "fit_joint_error_max_deg": m.get("joint_error_max_deg"), "fit_position_error_m": m.get("position_error_m")}
    shutil.rmtree(work)
    return row, rec


def mesh_reconstruction(path: Path, grid, method: str, params: dict):
    """A mesh file (a fit's ``fitted.ply``) as a :class:`recon.result.Reconstruction` on ``grid``: its volume marks
    the voxels the surface passes through (:func:`recon.metrics.mesh_occupancy`), so it is scored as the methods'
    reconstructions are."""
    import trimesh
    from recon.metrics import mesh_occupancy
    from recon.result import Reconstruction

    occ = mesh_occupancy(trimesh.load(path, force="mesh", process=False), grid).astype(np.float32)
    return Reconstruction(raw=occ, grid=grid, method=method, volume=occ, params=params)


def _mesh_start(work: Path, rec, iterations: int):
    """The free mesh's settings (its defaults) with its start the front surface of ``rec`` at the default cell size,
    written to ``work / "start_mesh.ply"``; its carving takes at most ``iterations`` steps, the fit's own count (a
    small fit stays small)."""
    from recon.surface import write_ply
    from transient_mi.fit.mesh_settings import MeshSettings, carve_iterations
    from transient_mi.fit.mesh_start import front_surface

    mesh = MeshSettings()
    mesh = replace(mesh, carve=min(carve_iterations(mesh), int(iterations)))
    v, f = front_surface(np.asarray(rec.volume), rec.grid, mesh.cell_m)
    work.mkdir(parents=True, exist_ok=True)
    write_ply(work / "start_mesh.ply", v, f)
    return replace(mesh, start_mesh=str(work / "start_mesh.ply"))
