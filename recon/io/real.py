"""Readers for public NLOS captures: the Stanford f-k ``.mat`` confocal layout and ZNLOS HDF5.

Both return a :class:`recon.capture.Capture` in transient-mi's world frame
(relay wall in z = 0, hidden space z > 0, metres, picoseconds), so every
``recon`` method runs on them. See docs/real_data.md.

**Stanford f-k** (Lindell, Wetzstein, O'Toole 2019, "Wave-based NLOS imaging
using fast f-k migration"; README and ``cnlos_reconstruction.m`` of
github.com/computational-imaging/nlos-fk): a measurement file
``meas_*.mat`` holds ``meas``, confocal histograms ``[y, x, t]`` (512 x 512
x 2048 for the planar scenes, 32 ps bins, a 2 m x 2 m scanned wall), and a
calibration file ``tof.mat`` holds ``tofgrid`` ``[y, x]``: the time of flight
in picoseconds from the scanner to each scan point and back. The released
code shifts each histogram ``floor(tofgrid / bin)`` bins earlier so that t = 0
is the moment light leaves the wall; this reader does the same, filling with
zeros instead of wrapping around (``circshift``), so the capture excludes the
first and last segments (``include_first_last`` false, ``t0_ps`` 0). MATLAB
v5 files are read with scipy, v7.3 files (HDF5 inside) with h5py (whose axis
order is reversed). The scan grid is regular: ``N`` points per side over
``wall_size_m``; row 0 is the top of the wall (y = +wall/2), column 0 the
left (x = -wall/2), as the images in the f-k paper are shown. The files do
not record the mirror convention of the scanner, so a reconstruction may be
mirrored relative to a photograph (``flip_x`` / ``flip_y`` flip the grid).

**ZNLOS** (the Zaragoza NLOS synthetic dataset, Galindo et al. 2019): an HDF5
file with ``data`` (5-D confocal, 7-D exhaustive with 6 bounce bins; colour,
time, bounce and grid axes in either of the two orders y-tal's converter
accepts, read exactly as it reads them), ``deltaT`` and ``t0`` (metres of optical path),
``cameraPosition``, ``cameraGridPositions``, ``cameraGridNormals``,
``laserPosition``, ``laserGridPositions``, ``laserGridNormals`` (grids stored
``(3, y, x)`` or ``(x, y, 3)``) and ``isConfocal``. Axis conventions follow
y-tal's converter (``tal.io.format``), the reference consumer of these files.
Colour channels and bounces are summed; times include the first and last
segments. Only the hidden-space side of the relay wall matters to recon: the
grids are used as stored.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from transient_core.errors import UserInputError
from transient_core.units import C_M_PER_PS

__all__ = ["read_fk_mat", "read_znlos", "FK_BIN_WIDTH_PS", "FK_WALL_SIZE_M"]

#: Bin width of the released f-k measurements (README: "The time resolution of the measurements is 32 ps").
FK_BIN_WIDTH_PS = 32.0
#: Length of the bounce axis of exhaustive ZNLOS ``data`` (how y-tal's converter finds its axis order).
ZNLOS_BOUNCES = 6
#: Side of the scanned wall of the f-k planar scenes ("Scanned Area: 2 m x 2 m").
FK_WALL_SIZE_M = 2.0


def _load_mat(path: Path, name: str) -> np.ndarray:
    """Variable ``name`` of a MATLAB file (v5 via scipy, v7.3 via h5py), in MATLAB's index order."""
    import h5py

    where = str(path)
    if h5py.is_hdf5(path):  # v7.3: HDF5 with MATLAB's column-major arrays -> reversed axes in h5py
        try:
            with h5py.File(path, "r") as f:
                if name not in f:
                    raise UserInputError(f"{where}: no variable {name!r} (has {sorted(f.keys())[:8]})")
                return np.asarray(f[name][()]).transpose()
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise UserInputError(f"{where}: not a readable MATLAB v7.3 (HDF5) file ({e})") from None
    import scipy.io

    try:
        d = scipy.io.loadmat(path, variable_names=[name])
    except UserInputError:
        raise
    except Exception as e:  # scipy's MatReadError, IndexError, ValueError, ... on a file that is not MATLAB's
        raise UserInputError(f"{where}: not a readable MATLAB file ({type(e).__name__}: {e}); expected a MATLAB "
                             "v5 or v7.3 .mat file") from None
    if name not in d:
        raise UserInputError(f"{where}: no variable {name!r}")
    return np.asarray(d[name])


def read_fk_mat(meas_path: str | os.PathLike, tof_path: str | os.PathLike | None = None, *,
                wall_size_m: float = FK_WALL_SIZE_M, bin_width_ps: float = FK_BIN_WIDTH_PS,
                crop_bins: int | None = None, flip_x: bool = False, flip_y: bool = False):
    """Read a Stanford f-k confocal measurement (``meas`` [y, x, t]) as a confocal capture.

    Parameters
    ----------
    meas_path : path
        ``meas_*.mat`` (variable ``meas``); may also hold ``tofgrid``.
    tof_path : path, optional
        ``tof.mat`` (variable ``tofgrid`` [y, x], picoseconds). Default: ``tof.mat`` beside
        ``meas_path`` if it exists, else ``tofgrid`` inside ``meas_path``, else none (the
        histograms are taken as already rectified).
    wall_size_m : float
        Side of the scanned square, metres (2 for the released planar scenes).
    bin_width_ps : float
        Bin width, ps (32 for the released scenes).
    crop_bins : int, optional
        Keep the first ``crop_bins`` bins after rectification (the released code keeps 512).
    flip_x, flip_y : bool
        Mirror the scan grid (the files do not record the scanner's orientation).

    Returns
    -------
    Capture
        Confocal, ``kind="counts"``, ``include_first_last=False``, ``t0_ps=0``.
    """
    from .ytal import _capture_from_parts

    mp = Path(meas_path)
    if not mp.is_file():
        raise UserInputError(f"f-k measurement {str(mp)!r} does not exist")
    if not (np.isfinite(wall_size_m) and wall_size_m > 0):
        raise UserInputError(f"wall_size_m={wall_size_m!r}: must be > 0 (metres)")
    if not (np.isfinite(bin_width_ps) and bin_width_ps > 0):
        raise UserInputError(f"bin_width_ps={bin_width_ps!r}: must be > 0")
    meas = _load_mat(mp, "meas")
    if meas.ndim != 3 or meas.shape[0] != meas.shape[1]:
        raise UserInputError(f"{mp}: meas has shape {meas.shape}; expected [N, N, T] (y, x, time) confocal "
                             "histograms on a square scan grid")
    N, _, T = meas.shape
    tof = None
    if tof_path is not None:
        tof = _load_mat(Path(tof_path), "tofgrid")
    elif (mp.parent / "tof.mat").is_file():
        tof = _load_mat(mp.parent / "tof.mat", "tofgrid")
    else:
        try:
            tof = _load_mat(mp, "tofgrid")
        except UserInputError:
            tof = None
    data = np.asarray(meas, dtype=np.float64)
    if tof is not None:
        tof = np.asarray(tof, dtype=np.float64)
        if tof.shape != (N, N):
            raise UserInputError(f"tofgrid has shape {tof.shape}; expected ({N}, {N}) like meas")
        shift = np.floor(tof / bin_width_ps).astype(np.int64)  # as cnlos_reconstruction.m
        if np.any(shift < 0) or np.any(shift >= T):
            raise UserInputError(f"tofgrid: delays {tof.min():g}..{tof.max():g} ps fall outside the {T} bins of "
                                 f"{bin_width_ps:g} ps")
        out = np.zeros_like(data)
        for (i, j), s in np.ndenumerate(shift):
            out[i, j, :T - s] = data[i, j, s:]
        data = out
    if crop_bins is not None:
        if not (isinstance(crop_bins, (int, np.integer)) and 1 <= crop_bins <= T):
            raise UserInputError(f"crop_bins={crop_bins!r}: must be a whole number in 1..{T}")
        data = data[..., :crop_bins]
        T = int(crop_bins)
    pitch = wall_size_m / N
    coord = -wall_size_m / 2 + (np.arange(N) + 0.5) * pitch
    # meas row 0 is the top of the wall and column 0 its left; captures store rows in increasing y
    if not flip_y:
        data = data[::-1]
    if flip_x:
        data = data[:, ::-1]
    gx, gy = np.meshgrid(coord, coord, indexing="xy")
    pc = np.stack([gx, gy, np.zeros((N, N))], axis=-1)  # [y, x, 3], increasing x and y
    normals = np.broadcast_to(np.array([0.0, 0.0, 1.0]), pc.shape).copy()
    kind = "counts" if np.all(data == np.round(data)) and data.min(initial=0) >= 0 else "ideal"
    arr = data.astype(np.uint32 if kind == "counts" else np.float32)

    def loader(j, _a=arr):
        return _a

    extra = {"geometry": {"wall_size_m": [wall_size_m, wall_size_m], "pixel_footprint_m": pitch},
             "source_layout": {"format": "stanford-fk-mat", "meas": str(mp), "rectified_by_tofgrid": tof is not None,
                               "flip_x": flip_x, "flip_y": flip_y}}
    return _capture_from_parts(
        mode="confocal", kind=kind, spots=pc.reshape(-1, 3), spot_normals=normals.reshape(-1, 3),
        pixel_centers=pc, pixel_normals=normals, laser_origin=None, detector_origin=None, t0_ps=0.0,
        bin_width_ps=float(bin_width_ps), n_bins=T, include_first_last=False, n_files=1, spot_grid=None,
        loader=loader, source=str(mp), extra=extra)


def _grid_xy3(arr, name: str, where: str) -> np.ndarray:
    """A ZNLOS grid as ``(X, Y, 3)`` (stored ``(3, Y, X)`` or ``(X, Y, 3)``), as y-tal converts it: a first
    axis of length 3 means ``(3, Y, X)`` (so a grid with X = 3 must be stored that way)."""
    a = np.asarray(arr, dtype=np.float64)
    if a.ndim == 3 and a.shape[0] == 3:
        a = np.transpose(a)
    if a.ndim == 2 and a.shape[0] == 3:  # one point stored (3, 1) or (3,)
        a = a.T.reshape(1, 1, 3) if a.shape[1] == 1 else a.T.reshape(-1, 1, 3)
    if a.ndim != 3 or a.shape[-1] != 3:
        raise UserInputError(f"{where}: {name} has shape {np.shape(arr)}; expected (3, Y, X) or (X, Y, 3)")
    return a


def read_znlos(path: str | os.PathLike):
    """Read a ZNLOS HDF5 capture (confocal or exhaustive) as a Capture (see the module docstring)."""
    import h5py

    from .ytal import _capture_from_parts

    p = Path(path)
    where = str(p)
    try:
        f = h5py.File(p, "r")
    except OSError as e:
        raise UserInputError(f"{where}: not a readable HDF5 file ({e})") from None
    with f:
        need = ("data", "deltaT", "cameraGridPositions", "laserGridPositions")
        missing = [k for k in need if k not in f]
        if missing:
            raise UserInputError(f"{where}: not a ZNLOS file (missing {', '.join(missing)})")
        H = np.asarray(f["data"][()], dtype=np.float64)
        delta_t = float(np.asarray(f["deltaT"][()]).reshape(-1)[0])
        t0 = float(np.asarray(f["t0"][()]).reshape(-1)[0]) if "t0" in f else 0.0
        sg = _grid_xy3(f["cameraGridPositions"][()], "cameraGridPositions", where)
        sn = _grid_xy3(f["cameraGridNormals"][()], "cameraGridNormals", where) if "cameraGridNormals" in f \
            else None
        lg = _grid_xy3(f["laserGridPositions"][()], "laserGridPositions", where)
        ln = _grid_xy3(f["laserGridNormals"][()], "laserGridNormals", where) if "laserGridNormals" in f else None
        cam = np.asarray(f["cameraPosition"][()], np.float64).reshape(3) if "cameraPosition" in f else None
        las = np.asarray(f["laserPosition"][()], np.float64).reshape(3) if "laserPosition" in f else None
    if not delta_t > 0:
        raise UserInputError(f"{where}: deltaT={delta_t!r} must be a positive bin width (metres of path)")
    # axis orders exactly as y-tal's converter (tal.io.format) reads ZNLOS files, to (colors, bounces, t, ...)
    if H.ndim == 5:
        if H.shape[0] == H.shape[1]:
            H = np.moveaxis(H, range(5), (3, 4, 1, 2, 0))
        elif H.shape[3] == H.shape[4]:
            H = np.moveaxis(H, range(5), (0, 2, 1, 4, 3))
        else:
            raise UserInputError(f"{where}: data has shape {H.shape}; not a ZNLOS confocal layout (a square scan "
                                 "grid in the first or last two axes)")
    elif H.ndim == 7:
        if H.shape[4] == ZNLOS_BOUNCES:
            H = np.moveaxis(H, range(7), (4, 3, 6, 5, 1, 2, 0))
        elif H.shape[2] == ZNLOS_BOUNCES:
            H = np.moveaxis(H, range(7), (0, 2, 1, 6, 5, 4, 3))
        else:
            raise UserInputError(f"{where}: data has shape {H.shape}; not a ZNLOS exhaustive layout (bounce axis "
                                 f"of length {ZNLOS_BOUNCES} at position 2 or 4)")
    else:
        raise UserInputError(f"{where}: data has {H.ndim} dimensions; ZNLOS captures have 5 (confocal) or 7")
    H = H.sum(axis=(0, 1))  # colours and bounces -> (t, [lx, ly,] sx, sy)
    Sx, Sy = sg.shape[:2]
    T = H.shape[0]
    pixel_centers = np.swapaxes(sg, 0, 1)  # [y, x, 3]
    pixel_normals = None if sn is None else np.swapaxes(sn, 0, 1)
    if H.ndim == 3:
        if H.shape[1:] != (Sx, Sy):
            raise UserInputError(f"{where}: data gives {H.shape[1:]} sensor points, cameraGridPositions "
                                 f"{(Sx, Sy)}")
        data = np.transpose(H, (2, 1, 0))[None]  # [1, y, x, t]
        confocal = lg.shape == sg.shape and Sx * Sy > 1
        mode = "confocal" if confocal else "array"
        spots = np.swapaxes(lg, 0, 1).reshape(-1, 3) if confocal else lg.reshape(-1, 3)[:1]
        spot_normals = None if ln is None else (np.swapaxes(ln, 0, 1).reshape(-1, 3) if confocal
                                                else ln.reshape(-1, 3)[:1])
        spot_grid = None if confocal else (1, 1)
    else:
        Lx, Ly = H.shape[1:3]
        if H.shape[3:] != (Sx, Sy) or lg.shape[:2] != (Lx, Ly):
            raise UserInputError(f"{where}: data shape {H.shape} does not match the grids {lg.shape}, {sg.shape}")
        data = np.transpose(H, (2, 1, 4, 3, 0)).reshape(Ly * Lx, Sy, Sx, T)  # spots row-major over (ly, lx)
        mode = "array"
        spots = np.swapaxes(lg, 0, 1).reshape(-1, 3)
        spot_normals = None if ln is None else np.swapaxes(ln, 0, 1).reshape(-1, 3)
        spot_grid = (Ly, Lx)
    arr = data.astype(np.float32)

    def loader(j, _a=arr):
        return _a[j]

    extra = {"geometry": {}, "source_layout": {"format": "znlos-hdf5", "file": where}}
    return _capture_from_parts(
        mode=mode, kind="ideal", spots=spots, spot_normals=spot_normals, pixel_centers=pixel_centers,
        pixel_normals=pixel_normals, laser_origin=las, detector_origin=cam, t0_ps=t0 / C_M_PER_PS,
        bin_width_ps=delta_t / C_M_PER_PS, n_bins=T, include_first_last=True, n_files=len(arr),
        spot_grid=spot_grid, loader=loader, source=where, extra=extra)
