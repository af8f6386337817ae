"""Import and export of the y-tal HDF5 capture layout (``HDF5_TAL``), with h5py.

Facts about the layout (read from y-tal 0.20.0's documentation and file
reader; no y-tal code is used here):

- top-level datasets only, exactly these keys (y-tal rejects unknown keys):
  ``H``, ``H_format``, ``sensor_xyz``, ``sensor_grid_xyz``,
  ``sensor_grid_normals``, ``sensor_grid_format``, ``laser_xyz``,
  ``laser_grid_xyz``, ``laser_grid_normals``, ``laser_grid_format``,
  ``volume_format``, ``delta_t``, ``t_start``,
  ``t_accounts_first_and_last_bounces``, ``scene_info``;
- ``H`` is time-first: ``(T, Sx, Sy)`` (``H_format`` = ``T_Sx_Sy`` = 1: one
  laser spot, or confocal when the laser grid equals the sensor grid) or
  ``(T, Lx, Ly, Sx, Sy)`` (``T_Lx_Ly_Sx_Sy`` = 2: exhaustive);
- grids are ``(X, Y, 3)`` (``GridFormat.X_Y_3`` = 2): first index along x,
  second along y; normals likewise;
- ``sensor_xyz`` / ``laser_xyz``: the detector and laser origins;
- ``delta_t`` (bin width) and ``t_start`` (start of bin 0) are optical path
  lengths in metres;
- ``t_accounts_first_and_last_bounces``: whether the laser -> wall and
  wall -> sensor segments are in the path length;
- enums are HDF5 enum datasets of shape (1,) over int32; absent values are
  empty datasets; ``scene_info`` is a YAML string.

Our axes are ``[spot, pixel_y, pixel_x, time]`` with ``pixel_centers[y, x]``;
y-tal's are ``[T, (Lx, Ly,) Sx, Sy]`` with ``grid[x, y]``: the export
transposes, the import transposes back. Exhaustive spots are stored on the
``spot_grid`` ``(ny, nx)`` (row-major scan order) as ``(Lx, Ly)``.

Round trip: the full stack manifest travels in ``scene_info`` under
``transient_mi_manifest``, so EXR stack -> capture -> HDF5 -> capture keeps
the exact time axis (ps), kind and metadata; counts are written as float32
when every value is below 2^24 (exact) and as float64 otherwise.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from transient_core.atomic import atomic_file
from transient_core.errors import UserInputError
from transient_core.units import C_M_PER_PS

__all__ = ["write_ytal", "read_ytal", "HFORMAT", "GRIDFORMAT"]

#: y-tal's HFormat enum (name -> value).
HFORMAT = {"UNKNOWN": 0, "T_Sx_Sy": 1, "T_Lx_Ly_Sx_Sy": 2, "T_Si": 3, "T_Li_Si": 4,
           "F_Sx_Sy": 10, "F_Lx_Ly_Sx_Sy": 11, "F_Si": 12, "F_Li_Si": 13}
#: y-tal's GridFormat enum.
GRIDFORMAT = {"UNKNOWN": 0, "N_3": 1, "X_Y_3": 2}
#: y-tal's VolumeFormat enum.
VOLUMEFORMAT = {"UNKNOWN": 0, "N_3": 1, "X_Y_Z_3": 2, "X_Y_3": 3}
KEYS = ("H", "H_format", "sensor_xyz", "sensor_grid_xyz", "sensor_grid_normals", "sensor_grid_format",
        "laser_xyz", "laser_grid_xyz", "laser_grid_normals", "laser_grid_format", "volume_format",
        "delta_t", "t_start", "t_accounts_first_and_last_bounces", "scene_info")
MANIFEST_KEY = "transient_mi_manifest"


def _enum(f, key: str, mapping: dict, value: int | None) -> None:
    import h5py

    if value is None:
        f[key] = h5py.Empty("f")
        return
    dt = h5py.enum_dtype(dict(mapping), basetype="i")
    ds = f.create_dataset(key, (1,), dtype=dt)
    ds[0] = int(value)


def _xy(arr_yx: np.ndarray) -> np.ndarray:
    """``[y, x, ...]`` -> ``[x, y, ...]``."""
    return np.ascontiguousarray(np.swapaxes(arr_yx, 0, 1))


def write_ytal(capture, path: str | os.PathLike, compression: int = 0) -> Path:
    """Export a capture to a y-tal HDF5 file (written atomically).

    Parameters
    ----------
    capture : Capture
        Array (one spot -> ``T_Sx_Sy``; several -> ``T_Lx_Ly_Sx_Sy`` on the
        spot grid) or confocal (``T_Sx_Sy`` with the laser grid equal to the
        sensor grid).
    path : path
        Output ``.h5`` / ``.hdf5`` file.
    compression : int
        gzip level 0-9 for ``H`` (0: none).

    Notes
    -----
    Streams one laser spot at a time into ``H``.
    """
    import h5py
    import yaml

    if not (isinstance(compression, int) and 0 <= compression <= 9):
        raise UserInputError(f"compression={compression!r} must be an integer 0-9")
    p = Path(path)
    H, W, T = capture.height, capture.width, capture.n_bins
    n_files = capture.n_files
    # dtype: float32 unless counts too large to be exact
    exhaustive = capture.mode == "array" and capture.n_spots > 1
    if exhaustive:
        ny, nx = capture.spot_grid
        shape = (T, nx, ny, W, H)
    else:
        shape = (T, W, H)
    dtype = np.float32
    if capture.kind == "counts":
        big = any(float(np.max(capture.spot(j), initial=0)) >= 2 ** 24 for j in range(n_files))
        dtype = np.float64 if big else np.float32
    manifest = dict(capture.manifest)
    manifest["status"] = "complete"
    scene_info = {
        "original_format": "TRANSIENT_MI_STACK",
        "transient_mi_version": _version(),
        MANIFEST_KEY: manifest,
    }
    with atomic_file(p) as tmp:
        with h5py.File(tmp, "w") as f:
            kw = {"compression": "gzip", "compression_opts": compression} if compression else {}
            ds = f.create_dataset("H", shape=shape, dtype=dtype, **kw)
            for j in range(n_files):
                h = np.asarray(capture.spot(j))            # (H, W, T)
                block = np.transpose(h, (2, 1, 0)).astype(dtype)  # (T, W=Sx, H=Sy)
                if exhaustive:
                    iy, ix = divmod(j, nx)
                    ds[:, ix, iy, :, :] = block
                else:
                    ds[...] = block
            _enum(f, "H_format", HFORMAT, HFORMAT["T_Lx_Ly_Sx_Sy"] if exhaustive else HFORMAT["T_Sx_Sy"])
            f["sensor_xyz"] = _origin(capture.detector_origin)
            f["sensor_grid_xyz"] = _xy(capture.pixel_centers)
            f["sensor_grid_normals"] = _xy(capture.pixel_normals)
            _enum(f, "sensor_grid_format", GRIDFORMAT, GRIDFORMAT["X_Y_3"])
            f["laser_xyz"] = _origin(capture.laser_origin)
            if capture.mode == "confocal":
                lg, ln = _confocal_laser_grid(capture)
            elif exhaustive:
                lg = _xy(capture.spots.reshape(ny, nx, 3))
                ln = _xy(capture.spot_normals.reshape(ny, nx, 3))
            else:
                lg = capture.spots.reshape(1, 1, 3)
                ln = capture.spot_normals.reshape(1, 1, 3)
            f["laser_grid_xyz"] = lg
            f["laser_grid_normals"] = ln
            _enum(f, "laser_grid_format", GRIDFORMAT, GRIDFORMAT["X_Y_3"])
            f["volume_format"] = h5py.Empty("f")
            f["delta_t"] = np.float64(capture.bin_width_ps * C_M_PER_PS)
            f["t_start"] = np.float64(capture.t0_ps * C_M_PER_PS)
            f["t_accounts_first_and_last_bounces"] = bool(capture.include_first_last)
            f["scene_info"] = yaml.safe_dump(scene_info, sort_keys=False)
    return p


#: A confocal capture's laser spots closer than this to its pixel centres (m) are stored as exactly the sensor
#: grid: ray-traced spots differ from the patch centres by float32 rounding (~1e-7 m), which made y-tal's
#: ``is_confocal()`` (an exact comparison) false and its f-k refuse the file. 10 um is 0.03 ps of path.
CONFOCAL_SNAP_M = 1e-5


def _confocal_laser_grid(capture) -> tuple[np.ndarray, np.ndarray]:
    """``(laser_grid_xyz, laser_grid_normals)`` of a confocal capture, X_Y_3: the sensor grid itself when every
    spot lies within :data:`CONFOCAL_SNAP_M` of its pixel centre, else the spots as they are."""
    H, W = capture.height, capture.width
    spots = capture.spots.reshape(H, W, 3)
    if float(np.max(np.abs(spots - capture.pixel_centers))) <= CONFOCAL_SNAP_M:
        return _xy(capture.pixel_centers), _xy(capture.pixel_normals)
    return _xy(spots), _xy(capture.spot_normals.reshape(H, W, 3))


def _origin(v):
    import h5py

    return h5py.Empty("f") if v is None else np.asarray(v, dtype=np.float64)


def _version() -> str:
    try:
        from transient_core import __version__

        return __version__
    except Exception:  # pragma: no cover
        return "unknown"


def _read(f, key):
    import h5py

    if key not in f:
        return None
    ds = f[key]
    if ds.shape is None:  # empty dataspace
        return None
    v = ds[()]
    if isinstance(v, h5py.Empty):
        return None
    return v


def _enum_value(v, key: str, where: str) -> int | None:
    if v is None:
        return None
    a = np.asarray(v).reshape(-1)
    if a.size != 1:
        raise UserInputError(f"{where}: {key} has {a.size} values, expected one enum value")
    return int(a[0])


def read_ytal(path: str | os.PathLike):
    """Import a y-tal HDF5 capture (``T_Sx_Sy`` single-spot or confocal, ``T_Lx_Ly_Sx_Sy`` exhaustive).

    Histograms are read lazily, one laser spot at a time.

    Returns
    -------
    Capture

    Raises
    ------
    UserInputError
        Unsupported ``H_format`` (e.g. frequency-domain data or ``N_3``
        grids), inconsistent shapes, or first/last bounces without origins.
    """
    import h5py
    import yaml

    from .._capture_type import Capture

    p = Path(path)
    where = str(p)
    try:
        f = h5py.File(p, "r")
    except OSError as e:
        raise UserInputError(f"{where}: not a readable HDF5 file ({e})") from None
    with f:
        if "H" not in f:
            raise UserInputError(f"{where}: no dataset 'H'; not a y-tal capture (HDF5_TAL layout)")
        unknown = sorted(set(f.keys()) - set(KEYS))
        if unknown:
            raise UserInputError(f"{where}: unexpected keys {unknown[:5]} for the y-tal HDF5_TAL layout")
        hshape = f["H"].shape
        hfmt = _enum_value(_read(f, "H_format"), "H_format", where)
        names = {v: k for k, v in HFORMAT.items()}
        if hfmt not in (HFORMAT["T_Sx_Sy"], HFORMAT["T_Lx_Ly_Sx_Sy"]):
            raise UserInputError(f"{where}: H_format={names.get(hfmt, hfmt)!r} is not supported; "
                                 "import handles T_Sx_Sy (single spot or confocal) and T_Lx_Ly_Sx_Sy (exhaustive)")
        for key in ("sensor_grid_format", "laser_grid_format"):
            g = _enum_value(_read(f, key), key, where)
            if g not in (None, GRIDFORMAT["X_Y_3"]):
                raise UserInputError(f"{where}: {key}={g} is not supported; import handles X_Y_3 grids")
        sg = _read(f, "sensor_grid_xyz")
        sn = _read(f, "sensor_grid_normals")
        lg = _read(f, "laser_grid_xyz")
        ln = _read(f, "laser_grid_normals")
        sensor = _read(f, "sensor_xyz")
        laser = _read(f, "laser_xyz")
        delta_t = _read(f, "delta_t")
        t_start = _read(f, "t_start")
        fl = _read(f, "t_accounts_first_and_last_bounces")
        info = _read(f, "scene_info")
    if sg is None or lg is None:
        raise UserInputError(f"{where}: sensor_grid_xyz and laser_grid_xyz are required")
    sg = np.asarray(sg, dtype=np.float64)
    lg = np.asarray(lg, dtype=np.float64)
    if sg.ndim != 3 or sg.shape[-1] != 3:
        raise UserInputError(f"{where}: sensor_grid_xyz has shape {sg.shape}, expected (Sx, Sy, 3)")
    Sx, Sy = sg.shape[:2]
    if delta_t is None or not float(delta_t) > 0:
        raise UserInputError(f"{where}: delta_t={delta_t!r} must be a positive bin width (metres of path)")
    if info is not None:
        try:
            info = yaml.safe_load(info.decode() if isinstance(info, bytes) else info)
        except yaml.YAMLError as e:
            raise UserInputError(f"{where}: scene_info is not valid YAML ({e})") from None
    info = info if isinstance(info, dict) else {}
    manifest = info.get(MANIFEST_KEY)
    T = hshape[0]
    if hfmt == HFORMAT["T_Lx_Ly_Sx_Sy"]:
        if len(hshape) != 5 or hshape[3:] != (Sx, Sy):
            raise UserInputError(f"{where}: H has shape {hshape}, expected (T, Lx, Ly, {Sx}, {Sy})")
        Lx, Ly = hshape[1:3]
        if lg.shape != (Lx, Ly, 3):
            raise UserInputError(f"{where}: laser_grid_xyz has shape {lg.shape}, expected ({Lx}, {Ly}, 3)")
        mode = "array"
        spots = np.swapaxes(lg, 0, 1).reshape(-1, 3)           # row-major over (ly, lx)
        spot_normals = None if ln is None else np.swapaxes(np.asarray(ln, float), 0, 1).reshape(-1, 3)
        spot_grid = (Ly, Lx)
        n_files = Lx * Ly

        def loader(j, _p=p, _Lx=Lx):
            iy, ix = divmod(j, _Lx)
            with h5py.File(_p, "r") as g:
                return np.transpose(g["H"][:, ix, iy, :, :], (2, 1, 0))
    else:
        if len(hshape) != 3 or hshape[1:] != (Sx, Sy):
            raise UserInputError(f"{where}: H has shape {hshape}, expected (T, {Sx}, {Sy})")
        paired = lg.shape == sg.shape
        if paired and not np.allclose(lg, sg, rtol=0, atol=1e-9) and Sx * Sy > 1:
            raise UserInputError(f"{where}: each sensor point has its own laser point but they differ "
                                 "(non-confocal paired data) which this import does not support")
        if paired and Sx * Sy > 1:
            mode = "confocal"
            spots = np.swapaxes(lg, 0, 1).reshape(-1, 3)
            spot_normals = None if ln is None else np.swapaxes(np.asarray(ln, float), 0, 1).reshape(-1, 3)
            spot_grid = None
        else:
            if lg.size != 3:
                raise UserInputError(f"{where}: H_format T_Sx_Sy with {lg.size // 3} laser points: expected 1 "
                                     "(single spot) or one per sensor point (confocal)")
            mode = "array"
            spots = lg.reshape(1, 3)
            spot_normals = None if ln is None else np.asarray(ln, float).reshape(1, 3)
            spot_grid = (1, 1)
        n_files = 1

        def loader(j, _p=p):
            with h5py.File(_p, "r") as g:
                return np.transpose(g["H"][...], (2, 1, 0))

    pixel_centers = np.swapaxes(sg, 0, 1)
    pixel_normals = None if sn is None else np.swapaxes(np.asarray(sn, float), 0, 1)
    # time axis: exact values from our manifest when it matches the file
    t0_ps = float(t_start or 0.0) / C_M_PER_PS
    bw_ps = float(delta_t) / C_M_PER_PS
    kind = "ideal"
    if isinstance(manifest, dict) and isinstance(manifest.get("time"), dict):
        mt = manifest["time"]
        if (mt.get("n_bins") == T and math.isclose(mt.get("bin_width_ps", -1), bw_ps, rel_tol=1e-9, abs_tol=1e-12)
                and math.isclose(mt.get("t0_ps", math.inf), t0_ps, rel_tol=1e-9, abs_tol=1e-9)):
            t0_ps, bw_ps = float(mt["t0_ps"]), float(mt["bin_width_ps"])
            kind = manifest.get("kind", "ideal")
        else:
            manifest = None
    else:
        manifest = None
    include = bool(fl) if fl is not None else False

    if kind == "counts":
        base = loader

        def loader(j, _base=base):
            a = np.asarray(_base(j))
            return a.astype(np.uint32)
    else:
        base = loader

        def loader(j, _base=base):
            return np.asarray(_base(j), dtype=np.float32)

    if manifest is not None:
        cap = Capture.from_manifest(manifest, loader, source=where)
        # geometry of the file wins if the manifest disagrees (it was edited)
        if (cap.pixel_centers.shape != pixel_centers.shape or not np.array_equal(cap.pixel_centers, pixel_centers)
                or not np.array_equal(cap.spots, spots) or cap.mode != mode):
            manifest = None
        else:
            return cap
    extra = {"geometry": {}, "ytal": {k: v for k, v in info.items() if k != MANIFEST_KEY and _plain(v)}}
    return _capture_from_parts(
        mode=mode, kind=kind, spots=spots, spot_normals=spot_normals, pixel_centers=pixel_centers,
        pixel_normals=pixel_normals, laser_origin=laser, detector_origin=sensor, t0_ps=t0_ps,
        bin_width_ps=bw_ps, n_bins=T, include_first_last=include, n_files=n_files, spot_grid=spot_grid,
        loader=loader, source=where, extra=extra)


def _plain(v) -> bool:
    """True if ``v`` is plain JSON-able data (kept in the imported manifest)."""
    import json

    try:
        json.dumps(v)
        return True
    except (TypeError, ValueError):
        return False


def _capture_from_parts(*, mode, kind, spots, spot_normals, pixel_centers, pixel_normals, laser_origin,
                        detector_origin, t0_ps, bin_width_ps, n_bins, include_first_last, n_files, spot_grid,
                        loader, source, extra):
    from .._capture_type import _build

    lo = None if laser_origin is None else np.asarray(laser_origin, dtype=np.float64).reshape(3)
    do = None if detector_origin is None else np.asarray(detector_origin, dtype=np.float64).reshape(3)
    return _build(mode=mode, kind=kind, spots=spots, pixel_centers=pixel_centers, pixel_normals=pixel_normals,
                  spot_normals=spot_normals, laser_origin=lo, detector_origin=do, t0_ps=t0_ps,
                  bin_width_ps=bin_width_ps, n_bins=n_bins, include_first_last=include_first_last,
                  n_files=n_files, spot_grid=spot_grid, quantity="radiance" if kind == "ideal" else "counts",
                  loader=loader, source=source, manifest_extra=extra)
