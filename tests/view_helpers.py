"""Small data trees for the viewer tests and benchmark: closed-form captures (no rendering)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

POINT = (0.05, -0.05, 0.45)


def ideal_capture(path: Path, *, pixels: int = 16, spots: int = 2, n_bins: int = 256, bin_width_ps: float = 16.0,
                  mode: str = "array") -> Path:
    """An ideal capture of one point reflector (recon.synthetic) written as an EXR stack at ``path``."""
    from transient_core import stack
    from recon.synthetic import point_capture, wall_grid

    kw = {}
    if mode == "array":
        s = wall_grid(spots, spots, 0.4).reshape(-1, 3)
        kw = dict(spots=s, spot_grid=(spots, spots))
    cap = point_capture([POINT], mode=mode, pixels=pixels, wall_size_m=0.6, sigma_ps=30.0,
                        bin_width_ps=bin_width_ps, n_bins=n_bins, t0_ps=2000.0, photons_scale=2e-5, **kw)
    m = dict(cap.manifest)
    m["laser"] = {"wavelength_nm": 1550.0, "repetition_rate_hz": 50e6}
    stack.write_stack(path, m, cap.data)
    return path


def ground_truth_mesh(path: Path, side: float = 0.08) -> Path:
    """A small cube around :data:`POINT` as PLY."""
    import trimesh

    box = trimesh.creation.box(extents=(side, side, side))
    box.apply_translation(POINT)
    box.export(path)
    return path


def view_tree(root: Path) -> Path:
    """``root/{ideal, counts, recon_bp, ground_truth.ply, notes/secret.txt}``: what the viewer tests open."""
    from recon.pipeline import run

    from spad_detector import DetectorParams, detect_stack

    root.mkdir(parents=True, exist_ok=True)
    ideal_capture(root / "ideal")
    detect_stack(root / "ideal", root / "counts", DetectorParams(), pulses=10 ** 6, seed=0, progress=False)
    ground_truth_mesh(root / "ground_truth.ply")
    run(root / "ideal", root / "recon_bp", "bp", voxels=24, plots=True)
    return root


def camera_capture(path: Path, h: int = 12, w: int = 16, n_bins: int = 40) -> Path:
    """A camera (transient video) capture: a bright disc expanding over time."""
    from transient_core import stack

    yy, xx = np.mgrid[0:h, 0:w]
    r = np.hypot(yy - h / 2, xx - w / 2)
    t = np.arange(n_bins)
    data = np.exp(-((r[..., None] - t * 0.3) ** 2)).astype(np.float32)[None]
    m = stack.new_manifest(kind="ideal", capture="camera", width=w, height=h, n_files=1, t0_ps=0.0,
                           bin_width_ps=30.0, n_bins=n_bins, quantity="radiance")
    stack.write_stack(path, m, data)
    return path
