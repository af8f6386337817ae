"""The reference experiment (shared/PAPER.md) as reusable steps.

One ideal render per configuration (expensive), then any number of detector
settings (cheap) and reconstructions, scored against the mannequin mesh that
was rendered. ``transient-mi demo``, the studies and the notebooks are built
from these functions:

=====================  ====================================================
:class:`PaperConfig`   scene parameters of ``scenes/paper_mannequin.xml`` (from :mod:`.paper`)
:func:`paper_detector` the paper's SPAD + TCSPC settings (auto gate; :mod:`.paper`)
:func:`render_ideal`   ideal capture (expected photons per pulse per bin)
:func:`detect_counts`  counts capture for a photon budget
:func:`reconstruct`    backprojection + the paper's filter, with metrics
:func:`ground_truth`   the rendered mannequin as a mesh
=====================  ====================================================
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .paper import PAPER, PAPER_ARRAY_SIZES, PAPER_BOUNDS_M, PaperConfig, paper_detector, scene_file  # noqa: F401


def ground_truth(cfg: PaperConfig):
    """The mannequin the scene renders (``trimesh.Trimesh``), for metrics and figures."""
    from transient_mi.scenes.mannequin import make_mannequin

    return make_mannequin(pose=cfg.pose, rotation_deg=cfg.rotation_deg, position=(0.0, 0.0, cfg.distance_m),
                          width_m=PAPER.mannequin_width_m, height_m=PAPER.mannequin_height_m, joints=cfg.joints)


def write_ground_truth(cfg: PaperConfig, path) -> Path:
    """Write :func:`ground_truth` as PLY (atomically)."""
    from transient_mi.scenes.mannequin import write_mannequin

    return write_mannequin(path, pose=cfg.pose, rotation_deg=cfg.rotation_deg, position=(0.0, 0.0, cfg.distance_m),
                           width_m=PAPER.mannequin_width_m, height_m=PAPER.mannequin_height_m, joints=cfg.joints)


def render_ideal(cfg: PaperConfig, out_dir, *, seed: int = 0, resume: bool = False,
                 progress: bool | None = None, noise_target: float | None = None, exposure_s: float | None = None,
                 params=None, log=None) -> Path:
    """Render the ideal capture of ``cfg`` into ``out_dir`` (an EXR stack); returns it.

    With ``noise_target`` (e.g. 0.1), ``cfg.spp`` is the pilot and every laser
    spot is rendered until its rendering variance is at most that share of the
    photon variance for ``exposure_s`` per spot and the detector ``params``
    (default :func:`paper_detector`); see :mod:`transient_mi.noise_target`.
    """
    from transient_mi.render_capture import prepare_render, run_render

    spec = None
    if noise_target is not None:
        from transient_mi.noise_target import NoiseTargetSpec

        spec = NoiseTargetSpec(target=noise_target, params=params if params is not None else paper_detector(),
                               exposure_s=exposure_s)
    job = prepare_render(scene_file(), out_dir, defines=cfg.defines(), spp=cfg.spp, seed=seed, resume=resume,
                         noise_target=spec)
    return run_render(job, progress=progress, log=log)


def detect_counts(ideal_dir, out_dir, *, params=None, pulses: int | None = None, exposure_s: float | None = None,
                  seed: int = 0, progress: bool = True, on_spot=None) -> Path:
    """Counts capture of ``ideal_dir`` for a photon budget (``pulses`` or ``exposure_s`` per spot); ``on_spot(j,
    ideal, counts)``: :func:`spad_detector.detect_stack`'s."""
    from spad_detector import detect_stack

    return detect_stack(ideal_dir, out_dir, params if params is not None else paper_detector(), pulses=pulses,
                        exposure_s=exposure_s, seed=seed, progress=progress, on_spot=on_spot)


def reconstruct(capture_dir, *, voxels=(64, 64, 32), bounds=PAPER_BOUNDS_M, method: str = "bp",
                threshold="rel:0.3", sigma_m: float | None = None, mesh=None, seed: int = 0):
    """Backprojection (or another recon method) + the paper's filter, scored against ``mesh``.

    Parameters
    ----------
    capture_dir : path
        Ideal or counts capture.
    voxels : int or (nx, ny, nz)
    bounds : (xmin, xmax, ymin, ymax, zmin, zmax), metres
    method : str
        ``bp`` (the paper), ``fbp``, ``phasor`` (``lct``/``fk`` need confocal captures).
    threshold : str
        Threshold of the paper's filter (``rel:F``, ``abs:V``, ``otsu``).
    mesh : trimesh.Trimesh, optional
        Ground truth; when given, metrics are computed.

    Returns
    -------
    (recon.Reconstruction, dict or None)
        The reconstruction (``raw`` and filtered ``volume``, ``[z, y, x]``)
        and its metrics (Chamfer distance, depth error, IoU, ...).
    """
    import recon
    from recon.metrics import GroundTruth, compute_metrics

    cap = recon.load_capture(capture_dir)
    rec = recon.reconstruct(cap, method, bounds=bounds, voxels=voxels, filter="paper", threshold=threshold,
                            sigma_m=sigma_m)
    metrics = None
    if mesh is not None:
        metrics = compute_metrics(rec, GroundTruth(mesh=mesh, source="mannequin"), seed=seed)
    return rec, metrics


class HistogramSum:
    """Histograms summed over spots and pixels as they come (``add(data [..., n_bins])``, float64, one intensity
    per bin), from arrays already in memory: the demo sums its ideal and counts captures spot by spot as
    ``detect`` makes them (``detect_stack``'s ``on_spot``) instead of reading the files back. ``t_ns``: the bins'
    centres (ns)."""

    def __init__(self, time_axis: dict):
        t = time_axis
        self.n_bins = int(t["n_bins"])
        self.total = np.zeros(self.n_bins, dtype=np.float64)
        self.t_ns = (t["t0_ps"] + (np.arange(self.n_bins) + 0.5) * t["bin_width_ps"]) / 1000.0

    def add(self, data: np.ndarray) -> None:
        self.total += np.asarray(data).reshape(-1, self.n_bins).sum(axis=0, dtype=np.float64)
