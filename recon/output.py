"""Writing a reconstruction directory (DESIGN.md, "Reconstruction outputs").

::

    OUT/
      volume.npz        volume (filtered, float32, [z, y, x]), raw, x_m, y_m, z_m
      projection_z.png  maximum-intensity projection along z (front view, [y, x]): raw | filtered
      projection_y.png  along y (top view, [z, x])
      projection_x.png  along x (side view, [z, y])
      depth_map.png     depth (z) of each column's maximum of the filtered volume
      surface.ply       isosurface of the filtered volume (surface nets, metres; recon.surface)
      maps.npz          depth_m [y, x] and normals [y, x, 3] (facing the wall), x_m, y_m
      recon.json        method, parameters, grid, capture, timings
      metrics.json      only with a ground truth

The directory is written under a temporary sibling name and renamed into
place, so ``OUT`` either does not exist or is complete.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np

from transient_core.atomic import check_output_location, replace_dir, temp_dir_beside
from transient_core._json import to_json
from transient_core.errors import UserInputError
from .filters import depth_map, projections
from .result import Reconstruction

__all__ = ["write_outputs", "save_volume", "load_volume"]


def save_volume(path: str | os.PathLike, rec: Reconstruction) -> Path:
    """Write ``volume.npz`` (``volume``, ``raw``, ``x_m``, ``y_m``, ``z_m``)."""
    p = Path(path)
    with open(p, "wb") as f:
        np.savez_compressed(f, volume=rec.volume.astype(np.float32), raw=rec.raw.astype(np.float32),
                            x_m=np.asarray(rec.x_m, dtype=np.float64), y_m=np.asarray(rec.y_m, dtype=np.float64),
                            z_m=np.asarray(rec.z_m, dtype=np.float64))
    return p


def load_volume(path: str | os.PathLike) -> Reconstruction:
    """Read a ``volume.npz`` (or a reconstruction directory) back into a :class:`Reconstruction`."""
    from .grid import VoxelGrid

    p = Path(path)
    if p.is_dir():
        p = p / "volume.npz"
    with np.load(p) as z:
        grid = VoxelGrid(z["x_m"], z["y_m"], z["z_m"])
        method = "unknown"
        meta = p.parent / "recon.json"
        if meta.is_file():
            method = json.loads(meta.read_text()).get("method", method)
        return Reconstruction(raw=z["raw"], grid=grid, method=method, volume=z["volume"])


def _extent(a: np.ndarray) -> tuple[float, float]:
    d = (a[1] - a[0]) / 2 if len(a) > 1 else 0.5
    return float(a[0] - d), float(a[-1] + d)


def _plots(d: Path, rec: Reconstruction, title: str) -> list[str]:
    # The object-oriented API without pyplot: saving needs no backend, and the session's backend
    # (Jupyter's inline one, a GUI) is left alone.
    import matplotlib
    from matplotlib.figure import Figure

    g = rec.grid
    xe, ye, ze = _extent(g.x_m), _extent(g.y_m), _extent(g.z_m)
    raw_p, vol_p = projections(rec.raw), projections(rec.volume)
    specs = {
        "z": ("front view (max along z)", "x [m]", "y [m]", (*xe, *ye), False),
        "y": ("top view (max along y)", "x [m]", "z [m]", (*xe, *ze), False),
        "x": ("side view (max along x)", "y [m]", "z [m]", (*ye, *ze), False),
    }
    names = []
    for axis, (label, xl, yl, extent, _) in specs.items():
        fig = Figure(figsize=(10, 4.4), constrained_layout=True)
        axs = fig.subplots(1, 2)
        for ax, img, what in ((axs[0], raw_p[axis], "raw"), (axs[1], vol_p[axis], "filtered")):
            im = ax.imshow(img, origin="lower", extent=extent, aspect="equal", cmap="inferno")
            ax.set_title(f"{what}: {label}")
            ax.set_xlabel(xl)
            ax.set_ylabel(yl)
            fig.colorbar(im, ax=ax, shrink=0.85)
        fig.suptitle(title)
        name = f"projection_{axis}.png"
        fig.savefig(d / name, dpi=110)
        names.append(name)
    dm = depth_map(rec.volume, g)
    fig = Figure(figsize=(5.6, 4.6), constrained_layout=True)
    ax = fig.subplots()
    cmap = matplotlib.colormaps["viridis"].copy()
    cmap.set_bad("lightgrey")
    im = ax.imshow(np.ma.masked_invalid(dm), origin="lower", extent=(*xe, *ye), aspect="equal", cmap=cmap,
                   vmin=ze[0], vmax=ze[1])
    ax.set_title("depth map (z of each column's maximum; grey: empty)")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    fig.colorbar(im, ax=ax, label="z [m]", shrink=0.85)
    fig.suptitle(title)
    fig.savefig(d / "depth_map.png", dpi=110)
    names.append("depth_map.png")
    return names


def _surface_outputs(d: Path, rec: Reconstruction) -> list[str]:
    """``surface.ply`` (isosurface of the filtered volume) and ``maps.npz`` (``depth_m [y, x]``,
    ``normals [y, x, 3]``, ``x_m``, ``y_m``); see :mod:`recon.surface`."""
    from .surface import normal_map, reconstruction_surface, write_ply

    verts, faces = reconstruction_surface(rec)
    write_ply(d / "surface.ply", verts, faces)
    dm = depth_map(rec.volume, rec.grid)
    np.savez_compressed(d / "maps.npz", depth_m=dm.astype(np.float32),
                        normals=normal_map(dm, rec.grid).astype(np.float32), x_m=rec.grid.x_m, y_m=rec.grid.y_m)
    return ["surface.ply", "maps.npz"]


def check_output_dir(out_dir: str | os.PathLike, overwrite: bool = False) -> Path:
    """Check (creating nothing) that a reconstruction can be written to ``out_dir``; return its parent.

    Missing parents are created when writing.
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise UserInputError(f"-o {str(out)!r} exists and is a file; choose a directory name")
    if out.is_dir() and any(out.iterdir()) and not overwrite:
        raise UserInputError(f"-o {str(out)!r} exists and is not empty; pass --overwrite to replace it")
    return check_output_location(out)


def write_outputs(out_dir: str | os.PathLike, rec: Reconstruction, meta: dict | None = None,
                  metrics: dict | None = None, overwrite: bool = False, plots: bool = True) -> Path:
    """Write a reconstruction directory atomically (see the module docstring).

    Parameters
    ----------
    out_dir : path
        Directory to create. Its parent must exist.
    rec : Reconstruction
    meta : dict, optional
        Extra content for ``recon.json`` (capture, parameters, timings).
    metrics : dict, optional
        Written as ``metrics.json``.
    overwrite : bool
        Replace an existing ``out_dir``; otherwise an existing non-empty one is an error.
    plots : bool
        Write the PNG pictures.
    """
    out = Path(out_dir)
    parent = check_output_dir(out, overwrite)
    parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_dir_beside(out)
    try:
        save_volume(tmp / "volume.npz", rec)
        files = ["volume.npz"] + _surface_outputs(tmp, rec)
        if plots:
            files += _plots(tmp, rec, f"{rec.method}: {(meta or {}).get('capture', {}).get('source', '')}")
        info = {"method": rec.method, "params": rec.params, "filter": rec.filter,
                "grid": {"shape_zyx": list(rec.grid.shape), "bounds_m": list(rec.grid.bounds),
                         "voxel_size_m": list(rec.grid.voxel_size_m)},
                "files": files + ["recon.json"] + (["metrics.json"] if metrics is not None else [])}
        info.update(meta or {})
        (tmp / "recon.json").write_text(json.dumps(to_json(info), indent=1) + "\n")
        if metrics is not None:
            (tmp / "metrics.json").write_text(json.dumps(to_json(metrics), indent=1) + "\n")
        replace_dir(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out
