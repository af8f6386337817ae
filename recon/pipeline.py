"""One call from a capture to a filtered reconstruction (what ``transient-mi recon`` runs)."""

from __future__ import annotations

import time
from pathlib import Path

from .capture import Capture, load_capture
from transient_core.lock import output_lock
from transient_core.errors import UserInputError
from .filters import DEFAULT_THRESHOLD, no_filter, paper_filter
from .grid import VoxelGrid, make_grid
from .result import Reconstruction

__all__ = ["METHODS", "FILTERS", "reconstruct", "run"]

METHODS = ("bp", "fbp", "lct", "fk", "phasor", "midpoint-lct", "midpoint-fk")
FILTERS = ("paper", "none")
#: The filter each method gets when none is asked for: the paper's Gaussian + Laplacian + threshold sharpens
#: plain backprojection (the paper's method); the other methods filter in their own way (FBP's time filter,
#: LCT's Wiener deconvolution, f-k's migration, phasor fields' band-pass virtual wave), and the Laplacian of
#: their output moves the maximum: on a 4 cm patch 45 cm from the wall, phasor fields with the paper filter
#: peaked 1.8 cm (1.5 voxels) too close to the wall (tests/test_recon_default_filters.py).
DEFAULT_FILTER = {"bp": "paper", "fbp": "none", "lct": "none", "fk": "none", "phasor": "none",
                  # measured with the paper filter on the mannequin leaderboard (docs/recon.md)
                  "midpoint-lct": "paper", "midpoint-fk": "paper"}
CONFOCAL_ONLY = ("lct", "fk")
#: Default threshold of the paper's filter per method (others: ``filters.DEFAULT_THRESHOLD``, rel:0.3).
#: midpoint-fk's volume is an intensity ``|rho|^2``, whose dynamic range is the square of an amplitude's:
#: rel:0.1 keeps about what rel:0.3 keeps of an amplitude; measured on the paper mannequin (32x32 array,
#: paper budget) it keeps the arms and legs that rel:0.3 drops (docs/recon.md).
METHOD_THRESHOLDS = {"midpoint-fk": "rel:0.1"}


def default_threshold(method: str) -> str:
    """The paper filter's default threshold for ``method``."""
    return METHOD_THRESHOLDS.get(method, DEFAULT_THRESHOLD)


def reconstruct(capture: Capture, method: str = "bp", grid: VoxelGrid | None = None, *,
                bounds=None, voxels=None, voxel_size_m=None, filter: str | None = None, sigma_m: float | None = None,
                threshold=None, complete=None, **options) -> Reconstruction:
    """Reconstruct ``capture`` with ``method`` and filter the result.

    Parameters
    ----------
    capture : Capture
    method : {"bp", "fbp", "lct", "fk", "phasor", "midpoint-lct", "midpoint-fk"}
        Backprojection, filtered backprojection, light-cone transform
        (confocal), f-k migration (confocal), phasor fields, and LCT / f-k of
        an array capture converted to approximately confocal data
        (:func:`recon.midpoint.midpoint_confocal`).
    grid : VoxelGrid, optional
        Default :func:`recon.grid.make_grid` from ``bounds``, ``voxels``,
        ``voxel_size_m``.
    filter : {"paper", "none"}, optional
        ``paper``: Gaussian, negative Laplacian, threshold
        (:func:`recon.filters.paper_filter`); ``none``: ``volume = raw``.
        Default :data:`DEFAULT_FILTER` of the method (``paper`` for bp, ``none`` for the others), then
        the default threshold ``rel:0.3`` either way.
    sigma_m : float, optional
        Gaussian sigma of the paper filter, metres (default one voxel).
    threshold : str, optional
        Threshold spec (default :func:`default_threshold`: ``rel:0.3``, except ``rel:0.1`` for midpoint-fk;
        ``none`` when ``filter="none"`` is asked for explicitly).
    complete : "auto" or float, optional
        Close the filtered front surface behind itself under a stated prior
        (elliptical cross-sections of aspect ``complete``, or estimated from the
        front with ``"auto"``; :func:`recon.completion.complete_surface`). The back
        of an object is not in three-bounce data: this is an assumption, recorded in
        ``params["completion"]``. Default None: the measured front only.
    **options
        Method options: ``voxel_integration`` (bp), ``fbp_sigma_m`` (fbp),
        ``snr`` (lct, midpoint-lct), ``wavelength_m``, ``pulse_sigma_m``, ``phasor_method`` (phasor),
        ``midpoint_pitch_m`` (``midpoint-*``).
    """
    if method not in METHODS:
        raise UserInputError(f"--method {method!r}: allowed {', '.join(METHODS)}")
    if filter is None:
        filter = DEFAULT_FILTER[method]
        if threshold is None:
            threshold = default_threshold(method)  # occupancy for metrics and pictures, whichever filter
    if complete is not None:
        from .completion import check_aspect

        check_aspect(complete)
    if filter not in FILTERS:
        raise UserInputError(f"--filter {filter!r}: allowed {', '.join(FILTERS)}")
    if method in CONFOCAL_ONLY and capture.mode != "confocal":
        raise UserInputError(
            f"--method {method} needs a confocal capture (laser on each pixel's wall patch); "
            f"{capture.source or 'this capture'} is an {capture.describe()}: use bp, fbp or phasor, or "
            f"midpoint-{method} (converts it to approximately confocal data)")
    if method.startswith("midpoint-") and capture.mode != "array":
        raise UserInputError(f"--method {method} converts an array capture; this is a {capture.mode} capture: "
                             f"use {method.split('-', 1)[1]}")
    if grid is None:
        grid = make_grid(capture, bounds=bounds, voxels=voxels, voxel_size_m=voxel_size_m)
    allowed = {"bp": {"voxel_integration"}, "fbp": {"fbp_sigma_m"}, "lct": {"snr"}, "fk": set(),
               "phasor": {"wavelength_m", "pulse_sigma_m", "phasor_method"},
               "midpoint-lct": {"snr", "midpoint_pitch_m"}, "midpoint-fk": {"midpoint_pitch_m"}}[method]
    opts = {k: v for k, v in options.items() if v is not None}
    bad = sorted(set(opts) - allowed)
    if bad:
        raise UserInputError(f"option(s) {', '.join(bad)} do not apply to --method {method}")
    if method == "bp":
        from .backprojection import backprojection

        rec = backprojection(capture, grid, **opts)
    elif method == "fbp":
        from .backprojection import filtered_backprojection

        rec = filtered_backprojection(capture, grid, sigma_m=opts.get("fbp_sigma_m"))
    elif method == "lct":
        from .confocal import lct

        rec = lct(capture, grid, **opts)
    elif method == "fk":
        from .confocal import fk_migration

        rec = fk_migration(capture, grid)
    elif method.startswith("midpoint-"):
        rec = _midpoint(capture, grid, method, opts)
    else:
        from .phasor import phasor_fields

        rec = phasor_fields(capture, grid, wavelength_m=opts.get("wavelength_m"),
                            pulse_sigma_m=opts.get("pulse_sigma_m"), method=opts.get("phasor_method", "auto"))
    if filter == "paper":
        rec = paper_filter(rec, sigma_m=sigma_m, threshold=default_threshold(method) if threshold is None else threshold)
    else:
        rec = no_filter(rec, threshold="none" if threshold is None else threshold)
    if complete is not None:
        from .completion import complete_surface

        rec = complete_surface(rec, complete)
    return rec


def _midpoint(capture: Capture, grid: VoxelGrid, method: str, opts: dict) -> Reconstruction:
    """LCT or f-k of the midpoint conversion of an array capture, with a time axis just deep enough for ``grid``."""
    import math

    import numpy as np

    from .confocal import fk_migration, lct
    from .midpoint import default_midpoint_bin_width_ps, midpoint_confocal
    from transient_core.units import C_M_PER_PS

    w_ps = default_midpoint_bin_width_ps(capture, grid)
    # deepest round trip the volume needs: from the farthest midpoint to the farthest voxel corner
    mids = (capture.spots[:, None, :2] + capture.pixel_centers.reshape(-1, 3)[None, :, :2]).reshape(-1, 2) / 2
    b = np.array(grid.bounds).reshape(3, 2)
    lat = max(float(np.max(np.abs(mids[:, 0, None] - b[0][None]))), float(np.max(np.abs(mids[:, 1, None] - b[1][None]))))
    r_need = math.sqrt(b[2, 1] ** 2 + 2 * lat ** 2)
    n_bins = int(math.ceil(2 * r_need / (w_ps * C_M_PER_PS))) + 2
    conf = midpoint_confocal(capture, pitch_m=opts.get("midpoint_pitch_m"), bin_width_ps=w_ps, n_bins=n_bins)
    if method == "midpoint-lct":
        rec = lct(conf, grid, **({"snr": opts["snr"]} if "snr" in opts else {}))
    else:
        rec = fk_migration(conf, grid)
    rec.method = method
    rec.params = {**rec.params, **conf.manifest["midpoint"], "bin_width_ps": w_ps,
                  "midpoint_grid": [conf.height, conf.width]}
    rec.params.pop("source_capture", None)
    return rec


def run(capture_path, out_dir, method: str = "bp", *, bounds=None, voxels=None, voxel_size_m=None,
        filter: str | None = None, sigma_m=None, threshold=None, complete=None, ground_truth=None,
        pileup_correction: bool = False,
        pulses=None, blind_cycles=None, time_crop_ps=None, time_downsample: int | None = None, overwrite: bool = False,
        plots: bool = True, seed: int = 0, **options) -> tuple[Reconstruction, dict | None, Path]:
    """Load, preprocess, reconstruct, filter, score and write (the ``recon`` command).

    Returns ``(reconstruction, metrics or None, output directory)``. The output's lock
    (:mod:`transient_core.lock`) is held from the first check to the last write: a second run into the same
    directory is refused.
    """
    from .output import check_output_dir

    if time_downsample is not None and (isinstance(time_downsample, bool) or int(time_downsample) != time_downsample
                                        or time_downsample < 1):
        raise UserInputError(f"--time-downsample {time_downsample!r}: must be a whole number >= 1 (bins summed "
                             "per output bin; 1 keeps every bin)")
    check_output_dir(out_dir, overwrite)  # fail before any work (and before taking the lock)
    with output_lock(out_dir):
        return _run_locked(capture_path, out_dir, method, bounds=bounds, voxels=voxels, voxel_size_m=voxel_size_m,
                           filter=filter, sigma_m=sigma_m, threshold=threshold, complete=complete,
                           ground_truth=ground_truth,
                           pileup_correction=pileup_correction, pulses=pulses, blind_cycles=blind_cycles,
                           time_crop_ps=time_crop_ps, time_downsample=time_downsample, overwrite=overwrite,
                           plots=plots, seed=seed, **options)


def _run_locked(capture_path, out_dir, method, *, bounds, voxels, voxel_size_m, filter, sigma_m, threshold,
                complete, ground_truth, pileup_correction, pulses, blind_cycles, time_crop_ps, time_downsample, overwrite,
                plots, seed, **options):
    from . import preprocess
    from .metrics import compute_metrics, load_ground_truth
    from .output import check_output_dir, write_outputs

    t_start = time.perf_counter()
    check_output_dir(out_dir, overwrite)  # fail before any work
    gt = load_ground_truth(ground_truth) if ground_truth is not None else None  # fail early
    cap = load_capture(capture_path)
    if pileup_correction:
        cap = preprocess.pileup_correction(cap, n_cycles=pulses, blind_cycles=blind_cycles)
    elif pulses is not None or blind_cycles is not None:
        raise UserInputError("--pulses and --blind-cycles are only used with --pileup-correction")
    if time_crop_ps is not None:
        cap = preprocess.crop_time(cap, *time_crop_ps)
    if time_downsample is not None:
        cap = preprocess.downsample_time(cap, int(time_downsample))
    t_load = time.perf_counter()
    rec = reconstruct(cap, method, bounds=bounds, voxels=voxels, voxel_size_m=voxel_size_m, filter=filter,
                      sigma_m=sigma_m, threshold=threshold, complete=complete, **options)
    t_rec = time.perf_counter()
    metrics = compute_metrics(rec, gt, seed=seed) if gt is not None else None
    t_metrics = time.perf_counter()
    meta = {
        "capture": {"source": str(capture_path), "description": cap.describe(), "mode": cap.mode, "kind": cap.kind,
                    "processing": list(cap.processing)},
        "timings_s": {"load_and_preprocess": t_load - t_start, "reconstruct_and_filter": t_rec - t_load,
                      "metrics": t_metrics - t_rec},
    }
    out = write_outputs(out_dir, rec, meta=meta, metrics=metrics, overwrite=overwrite, plots=plots)
    return rec, metrics, out
