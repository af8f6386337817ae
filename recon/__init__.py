"""recon: non-line-of-sight reconstruction from transient captures.

numpy/scipy (and numba for the hot loops) only: this package never imports
Mitsuba or drjit, so users with measured data can use it without a renderer.

Public API (imported lazily, so ``import recon`` stays cheap)::

    load_capture, Capture                    recon.capture
    VoxelGrid, make_grid, default_bounds     recon.grid
    backprojection, filtered_backprojection  recon.backprojection
    lct, fk_migration                        recon.confocal
    phasor_fields                            recon.phasor
    midpoint_confocal                        recon.midpoint
    paper_filter, projections, depth_map     recon.filters
    reconstruct, run                         recon.pipeline
    Reconstruction                           recon.result
    compute_metrics, load_ground_truth       recon.metrics
    write_outputs, load_volume               recon.output
    read_ytal, write_ytal                    recon.io.ytal
    remove_first_last, pileup_correction,
    crop_time, downsample_time               recon.preprocess
"""

from __future__ import annotations

from transient_core import __version__  # the distribution's version
from transient_core.lazy_exports import lazy_exports

_EXPORTS = {
    "Capture": "capture", "load_capture": "capture",
    "VoxelGrid": "grid", "make_grid": "grid", "default_bounds": "grid",
    "backprojection": "backprojection", "filtered_backprojection": "backprojection",
    "lct": "confocal", "fk_migration": "confocal",
    "phasor_fields": "phasor", "midpoint_confocal": "midpoint",
    "paper_filter": "filters", "projections": "filters", "depth_map": "filters",
    "reconstruct": "pipeline", "run": "pipeline", "METHODS": "pipeline",
    "Reconstruction": "result",
    "compute_metrics": "metrics", "load_ground_truth": "metrics",
    "write_outputs": "output", "load_volume": "output",
    "read_ytal": "io.ytal", "write_ytal": "io.ytal",
    "remove_first_last": "preprocess", "pileup_correction": "preprocess", "crop_time": "preprocess",
    "downsample_time": "preprocess",
}

__all__ = sorted(_EXPORTS) + ["__version__"]


# Public names load their module on first use, so the import is cheap and a user of one part does not
# pay for the others (numba kernels, scipy).
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals())
