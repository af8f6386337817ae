"""The reference experiment (shared/PAPER.md) as reusable steps.

One ideal render per configuration (expensive), then any number of detector
settings (cheap) and reconstructions, scored against the mannequin mesh that
was rendered. ``transient-mi demo``, the studies and the notebooks are built
from these functions:

=====================  ====================================================
:class:`PaperConfig`   scene parameters of ``scenes/paper_mannequin.xml``
:func:`paper_detector` the paper's SPAD + TCSPC settings (auto gate)
:func:`render_ideal`   ideal capture (expected photons per pulse per bin)
:func:`detect_counts`  counts capture for a photon budget
:func:`reconstruct`    backprojection + the paper's filter, with metrics
:func:`ground_truth`   the rendered mannequin as a mesh
=====================  ====================================================
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: Array sizes compared in the paper (Fig. 4 and Fig. 5).
PAPER_ARRAY_SIZES = (4, 8, 16, 32)
#: Reconstruction volume: the wall's extent in x and y, 25 cm to 75 cm in front of it.
PAPER_BOUNDS_M = (-0.5, 0.5, -0.5, 0.5, 0.25, 0.75)


@dataclass(frozen=True)
class PaperConfig:
    """Parameters of ``scenes/paper_mannequin.xml`` (see the scene file).

    Attributes
    ----------
    array : int
        SPAD array side (pixels); each pixel sees 1 cm^2 of wall, the array
        spans the 1 m wall.
    spots : int
        Laser scan grid side (spots spread over ``scan_extent_m`` of wall,
        default 2 x 2 over 1 m).
    scan_extent_m : float
        Side of the wall square the laser scan covers.
    distance_m, pose, rotation_deg
        The mannequin: depth of its centre (m), pose, rotation about y.
    power_w : float
        Laser average power (50 MHz, 1550 nm).
    spp : int
        Samples per pixel per laser spot.
    t0_ps, n_bins, bin_width_ps
        Time axis (t = 0: the pulse leaves the laser).
    max_depth : int
        4 = three-bounce light (the paper's model), -1 = every bounce.
    """

    array: int = 16
    spots: int = 2
    scan_extent_m: float = 1.0
    distance_m: float = 0.5
    pose: str = "arms_down"
    rotation_deg: float = 0.0
    power_w: float = 0.01
    spp: int = 1024
    t0_ps: float = 12500.0
    n_bins: int = 11500
    bin_width_ps: float = 1.0
    max_depth: int = 4

    def defines(self) -> dict[str, str]:
        """The ``-D`` values for ``scenes/paper_mannequin.xml``."""
        return {
            "array": str(self.array), "spots": str(self.spots), "scan_extent": repr(float(self.scan_extent_m)), "distance": repr(float(self.distance_m)),
            "pose": self.pose, "rotation": repr(float(self.rotation_deg)), "power_w": repr(float(self.power_w)),
            "spp": str(self.spp), "t0_ps": repr(float(self.t0_ps)), "n_bins": str(self.n_bins),
            "bin_width_ps": repr(float(self.bin_width_ps)), "max_depth": str(self.max_depth),
        }

    def replace(self, **changes) -> "PaperConfig":
        return dataclasses.replace(self, **changes)


def scene_file() -> Path:
    """``scenes/paper_mannequin.xml``."""
    from transient_mi.scenes import scene_path

    return scene_path("paper_mannequin")


def paper_detector(**overrides):
    """The paper's detector: 70 % PDE, 25 ps FWHM jitter, < 25 cps dark counts, a gate with
    120 ps transitions opened automatically between the earliest and latest three-bounce
    arrivals from the hidden volume 25-75 cm in front of the wall (which keeps the wall's
    first-bounce return out), TCSPC limited to 20 MHz; ``overrides`` replace any field of
    :class:`spad_detector.DetectorParams`."""
    from spad_detector import DetectorParams

    base = dict(pde=0.70, jitter_ps=25.0, dark_count_rate_cps=25.0, gate_transition_ps=120.0, auto_gate=True,
                auto_gate_depth_min_m=PAPER_BOUNDS_M[4], auto_gate_depth_max_m=PAPER_BOUNDS_M[5],
                tcspc_max_count_rate_hz=20e6)
    base.update(overrides)
    return DetectorParams(**base).validate()


def ground_truth(cfg: PaperConfig):
    """The mannequin the scene renders (``trimesh.Trimesh``), for metrics and figures."""
    from transient_mi.scenes.mannequin import make_mannequin

    return make_mannequin(pose=cfg.pose, rotation_deg=cfg.rotation_deg, position=(0.0, 0.0, cfg.distance_m))


def write_ground_truth(cfg: PaperConfig, path) -> Path:
    """Write :func:`ground_truth` as PLY (atomically)."""
    from transient_mi.scenes.mannequin import write_mannequin

    return write_mannequin(path, pose=cfg.pose, rotation_deg=cfg.rotation_deg, position=(0.0, 0.0, cfg.distance_m))


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
                  seed: int = 0, progress: bool = True) -> Path:
    """Counts capture of ``ideal_dir`` for a photon budget (``pulses`` or ``exposure_s`` per spot)."""
    from spad_detector import detect_stack

    return detect_stack(ideal_dir, out_dir, params if params is not None else paper_detector(), pulses=pulses,
                        exposure_s=exposure_s, seed=seed, progress=progress)


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


def summed_histogram(capture_dir) -> tuple[np.ndarray, np.ndarray]:
    """``(t_ns, values)``: a capture's histograms summed over spots and pixels."""
    from transient_core.stack import iter_spots, read_manifest

    m = read_manifest(capture_dir)
    t = m["time"]
    total = np.zeros(t["n_bins"], dtype=np.float64)
    for _, data in iter_spots(capture_dir):
        total += data.reshape(-1, t["n_bins"]).sum(axis=0, dtype=np.float64)
    t_ns = (t["t0_ps"] + (np.arange(t["n_bins"]) + 0.5) * t["bin_width_ps"]) / 1000.0
    return t_ns, total
