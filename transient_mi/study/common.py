"""Steps both studies share: render, reconstruct and score, quiet inner progress bars, metric columns."""

from __future__ import annotations

import os
import time
from contextlib import contextmanager
from pathlib import Path

from transient_mi.reporting import METRIC_KEYS

#: Metric columns of the study tables (``recon.metrics``; ``None`` without ground truth).
METRIC_COLUMNS = METRIC_KEYS + ("depth_rmse_m", "localisation_error_m", "occupied_voxels")


def render(scene, out_dir, seed: int, noise_target=None, log=None) -> Path:
    """Render ``scene``'s ideal capture into ``out_dir`` (no progress bar of its own).

    ``noise_target``: a :class:`transient_mi.noise_target.NoiseTargetSpec` (the scene's spp is then the pilot).
    """
    from transient_mi.render_capture import prepare_render, run_render

    job = prepare_render(scene.path, out_dir, defines=scene.defines, spp=scene.spp, seed=seed,
                         noise_target=noise_target)
    return run_render(job, progress=False, log=log or (lambda line: None))


def capture_estimator(ideal_dir) -> str:
    """Which estimator made a rendered ideal capture: ``quadrature`` or ``monte_carlo`` (its manifest's
    ``render.estimator``; camera captures are Monte Carlo)."""
    from transient_core.stack import read_manifest

    return (read_manifest(ideal_dir).get("render") or {}).get("estimator", "monte_carlo")


#: A study's ``noise_target="auto"`` where the scene renders with the deterministic quadrature (issue 27: its
#: captures at 0.01 x the photon noise; Monte Carlo keeps 0.1, :data:`spad_detector.render_noise.DEFAULT_THRESHOLD`,
#: whose samples grow as 1 / target).
QUADRATURE_AUTO_TARGET = 0.01


def resolve_noise_target(noise_target, quick: bool) -> float | None:
    """The study's noise target: ``"auto"`` is 0.1 (:data:`spad_detector.render_noise.DEFAULT_THRESHOLD`;
    :data:`QUADRATURE_AUTO_TARGET` for a scene the quadrature renders, :func:`noise_target_spec`), or None with
    ``quick``; None renders the scene's spp as it is; a number must be finite and > 0."""
    from spad_detector.render_noise import DEFAULT_THRESHOLD

    from . import validate as V

    if isinstance(noise_target, str) and noise_target == "auto":
        return None if quick else DEFAULT_THRESHOLD
    if noise_target is None:
        return None
    return V.numbers_list([noise_target], "noise_target")[0]


def noise_target_spec(given, target: float | None, params, exposure_s: float):
    """The :class:`~transient_mi.noise_target.NoiseTargetSpec` of a study's render (None without a target):
    ``target`` (:func:`resolve_noise_target` of ``given``) for the detector ``params`` at ``exposure_s``; where
    ``given`` was ``"auto"``, the quadrature is held to :data:`QUADRATURE_AUTO_TARGET` instead. Read the target
    the render met from the spec after it (``spec.target``)."""
    if target is None:
        return None
    from transient_mi.noise_target import NoiseTargetSpec

    auto = isinstance(given, str) and given == "auto"
    return NoiseTargetSpec(target=target, params=params, exposure_s=exposure_s,
                           quadrature_target=QUADRATURE_AUTO_TARGET if auto else None)


def bar_enabled(progress: bool | None) -> str:
    """How a study reports its progress (``transient_core.progress.progress_mode``): ``progress`` True/False forces the
    bar on/off; None: a bar on a terminal, periodic lines otherwise. Decided before the inner bars are quieted."""
    from transient_core.progress import progress_mode

    return progress_mode(None if progress is None else not progress)


@contextmanager
def quiet_inner_bars(active: bool = True):
    """Silence the progress bars of inner steps (render, detection, backprojection) while a study draws its own."""
    if not active:
        yield
        return
    old = os.environ.get("TRANSIENT_MI_PROGRESS")
    os.environ["TRANSIENT_MI_PROGRESS"] = "0"
    try:
        yield
    finally:
        if old is None:
            os.environ.pop("TRANSIENT_MI_PROGRESS", None)
        else:
            os.environ["TRANSIENT_MI_PROGRESS"] = old


def reconstruct(capture, *, method: str, bounds, voxels, threshold: str, ground_truth, seed: int):
    """Reconstruct (method + the paper's filter) and score; returns ``(rec, metrics or None, t_rec_s, t_metrics_s)``."""
    import recon
    from recon.metrics import compute_metrics

    t0 = time.perf_counter()
    rec = recon.reconstruct(capture, method, bounds=bounds, voxels=voxels, filter="paper", threshold=threshold)
    t1 = time.perf_counter()
    metrics = compute_metrics(rec, ground_truth, seed=seed) if ground_truth is not None else None
    return rec, metrics, t1 - t0, time.perf_counter() - t1


def check_method_fits(method: str, manifest: dict) -> None:
    """``lct``/``fk`` need a confocal capture: refuse them for array captures (before reconstructing)."""
    from transient_core.errors import UserInputError
    from recon.pipeline import CONFOCAL_ONLY

    if method in CONFOCAL_ONLY and manifest.get("capture") != "confocal":
        raise UserInputError(f"method={method!r} needs a confocal capture; the scene renders an "
                             f"{manifest.get('capture')!r} capture: use bp, fbp or phasor")


def metric_values(metrics: dict | None) -> dict:
    """The :data:`METRIC_COLUMNS` of ``metrics`` (all ``None`` without metrics)."""
    m = metrics or {}
    return {k: m.get(k) for k in METRIC_COLUMNS}


def front_view(rec) -> dict:
    """The filtered volume's maximum along z (``image[y, x]``) and its axes, for figures."""
    g = rec.grid
    return {"image": rec.volume.max(axis=0), "x_m": g.x_m, "y_m": g.y_m,
            "extent": (float(g.x_m[0]), float(g.x_m[-1]), float(g.y_m[0]), float(g.y_m[-1]))}
