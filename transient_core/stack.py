"""EXR histogram stacks: the on-disk contract between rendering, detection and recon.

One module on purpose (over 500 lines): the format's writer and reader -- data, variance, channels,
manifest -- sit side by side so the contract is stated and checked in one place (shared/DESIGN.md:
"the stack format is written once").

A capture is a directory::

    capture/
      manifest.json       everything needed to interpret the data
      spot_00000.exr ...  one file per laser spot, in scan order
      preview.png         optional picture

Each ``spot_NNNNN.exr`` is a scanline EXR image of the sensor (``height`` x
``width`` pixels, EXR row ``y`` is array row ``pixel_y``) with one channel per
time bin. Channels are named ``t00000``, ``t00001``, ... (zero-padded so that
names sort in time order) and hold FLOAT (expected photons or radiance, kind
``ideal``) or UINT (photon counts, kind ``counts``). Key metadata is repeated
as header attributes (prefix ``tmi_``) so one file is self-describing.

Multi-channel captures (colour, Stokes vectors) hold one EXR layer per time
bin: channels ``tNNNNN.R``, ``tNNNNN.G``, ``tNNNNN.B`` (or ``tNNNNN.S0`` ..
``tNNNNN.S3``; a spectral render's wavelength bands: ``tNNNNN.400-500nm`` ...), so a layer-aware viewer
shows one time bin as one image. The
manifest's ``channels`` lists the channel names in order (absent or null:
mono, channels ``tNNNNN``) and ``intensity`` says how one intensity is formed
from them (:func:`intensity`), which is what the detector model and the
reconstruction use. Arrays of such captures carry a last axis for the
channel: ``[pixel_y, pixel_x, time, channel]``.

A confocal capture (laser spot k on pixel k's wall patch) is one file,
``spot_00000.exr``, whose pixel k was recorded with the laser on patch k.

Ideal captures rendered with several independent replicates also hold the
estimated variance of every value (the render's Monte Carlo error)::

    capture/
      variance/spot_00000.exr ...   same layout: channel tNNNNN = variance of
                                    bin NNNNN (unit of the data, squared),
                                    channel ``total`` = variance of the pixel's
                                    sum over all bins (covariances included)

described by the manifest's ``variance`` entry (``directory``,
``replicates``, ``estimator``, ``summary``); it is written before its spot
file, so a complete spot file implies a complete variance file. Readers of
the data ignore the directory.

Writes are atomic: data goes to a temporary name in the same directory and is
renamed into place, so a file with a final name is always complete. Readers
check format version, shapes, channel names and types against the manifest
and raise :class:`StackError` naming the file and the mismatch.

This module needs numpy and OpenEXR only (never Mitsuba): it is the single
reader/writer used by ``transient_mi`` and ``recon`` alike.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
from pathlib import Path
from typing import Any, Iterator

import numpy as np

FORMAT = "transient-mi-stack"
FORMAT_VERSION = 1
MANIFEST_NAME = "manifest.json"
KINDS = ("ideal", "counts")
CAPTURES = ("camera", "array", "confocal")
#: Status of a capture directory: spots may still be missing while "incomplete".
STATUSES = ("incomplete", "complete")

__all__ = [
    "FORMAT", "FORMAT_VERSION", "MANIFEST_NAME", "KINDS", "CAPTURES", "StackError", "spot_filename",
    "channel_names", "dtype_for", "new_manifest", "validate_manifest", "write_manifest", "read_manifest",
    "config_digest", "spot_path", "write_spot", "read_spot", "spot_is_complete", "missing_spots",
    "iter_spots", "read_stack", "write_stack", "VARIANCE_DIR", "TOTAL_CHANNEL", "has_variance",
    "write_variance", "read_variance", "variance_is_complete", "is_error_bound", "ERROR_BOUND_KIND", "ERROR_BOUND_DIR",
    "has_error_bound", "error_bound_view", "write_error_bound", "read_error_bound", "data_shape", "intensity",
    "CHANNEL_SETS",
    "INTENSITY_RULES", "read_intensity", "band_name", "band_edges_nm", "intensity_rule",
]

#: Channel sets a multi-channel capture may hold, and the rule that makes one intensity of them. Besides
#: these, a spectral capture holds wavelength bands (:func:`band_edges_nm`) with the rule ``sum``.
CHANNEL_SETS = {("R", "G", "B"): "luminance", ("S0", "S1", "S2", "S3"): "S0"}
#: Intensity rules: ``luminance`` = CIE Y of linear Rec. 709 RGB (Mitsuba's ``luminance``), ``S0`` = the
#: first Stokes component (total intensity), ``sum`` = the sum of wavelength bands (the quantity
#: integrated over the bands' whole range), ``mono`` = the one channel.
INTENSITY_RULES = ("mono", "luminance", "S0", "sum")
_BAND = re.compile(r"^(\d+)-(\d+)nm$")
#: Rec. 709 / sRGB primaries (linear) to CIE Y, as Mitsuba's ``mi.luminance``.
LUMINANCE_WEIGHTS = (0.212671, 0.715160, 0.072169)

#: Sub-directory of an ideal capture holding the per-bin variance files.
VARIANCE_DIR = "variance"
#: Channel of a variance file holding the variance of each pixel's total over time.
TOTAL_CHANNEL = "total"

_DTYPES = {"ideal": np.dtype(np.float32), "counts": np.dtype(np.uint32)}


from .atomic import atomic_file
from ._json import to_json
from .errors import UserInputError


class StackError(UserInputError):
    """A capture directory or spot file is missing, truncated or inconsistent."""


# --------------------------------------------------------------------------- names


def spot_filename(index: int) -> str:
    """File name of laser spot ``index`` (``spot_00000.exr``)."""
    return f"spot_{int(index):05d}.exr"


def channel_names(n_bins: int, channels=None) -> list[str]:
    """EXR channel names for ``n_bins`` time bins, sorting in time order.

    Mono (``channels`` None): ``t00000``, ``t00001``, ...; multi-channel:
    ``t00000.R``, ``t00000.G``, ... (time major, channel minor).
    """
    width = max(5, len(str(max(n_bins - 1, 0))))
    if not channels:
        return [f"t{b:0{width}d}" for b in range(n_bins)]
    return [f"t{b:0{width}d}.{c}" for b in range(n_bins) for c in channels]


def band_name(lo_nm: float, hi_nm: float) -> str:
    """Channel name of the wavelength band ``[lo_nm, hi_nm)``: ``400-500nm`` (whole nanometres: a dot would
    split the EXR layer name)."""
    return f"{int(lo_nm)}-{int(hi_nm)}nm"


def band_edges_nm(channels) -> list[tuple[float, float]] | None:
    """``[(lo_nm, hi_nm), ...]`` when every name in ``channels`` is a wavelength band (``400-500nm``, whole
    nanometres, lo < hi,
    bands not overlapping, in increasing order), else None."""
    if not channels:
        return None
    edges = []
    for c in channels:
        m = _BAND.match(str(c))
        if m is None:
            return None
        lo, hi = float(m.group(1)), float(m.group(2))
        if not lo < hi or (edges and lo < edges[-1][1]):
            return None
        edges.append((lo, hi))
    return edges


def intensity_rule(channels) -> str | None:
    """The intensity rule of a channel list (None: not a channel list a capture may hold)."""
    if not channels:
        return "mono"
    if tuple(channels) in CHANNEL_SETS:
        return CHANNEL_SETS[tuple(channels)]
    return "sum" if band_edges_nm(channels) is not None else None


def data_shape(manifest: dict) -> tuple[int, ...]:
    """Shape of one spot's array: ``(height, width, n_bins)``, plus ``n_channels`` for multi-channel captures."""
    shape = (manifest["height"], manifest["width"], manifest["time"]["n_bins"])
    ch = manifest.get("channels")
    return shape + (len(ch),) if ch else shape


def intensity(data: np.ndarray, manifest: dict) -> np.ndarray:
    """One intensity per bin: ``data`` itself for mono captures, else the manifest's ``intensity`` rule over
    the last axis (``luminance``: Y of linear Rec. 709 RGB; ``S0``: the Stokes intensity; ``sum``: the sum
    of the wavelength bands). float32 for
    ideal captures; counts are never multi-channel (the detector records one intensity)."""
    ch = manifest.get("channels")
    if not ch:
        return data
    rule = manifest.get("intensity")
    if rule == "luminance":
        w = np.asarray(LUMINANCE_WEIGHTS, dtype=np.float32)
        return np.tensordot(data.astype(np.float32, copy=False), w, axes=([-1], [0])).astype(np.float32)
    if rule == "S0":
        return np.ascontiguousarray(data[..., list(ch).index("S0")])
    if rule == "sum":
        return data.astype(np.float32, copy=False).sum(axis=-1, dtype=np.float64).astype(np.float32)
    raise StackError(f"intensity rule {rule!r} for channels {ch}: allowed {', '.join(INTENSITY_RULES)}")


def dtype_for(kind: str) -> np.dtype:
    """numpy dtype of the stored data: float32 for ``ideal``, uint32 for ``counts``."""
    if kind not in _DTYPES:
        raise StackError(f"kind={kind!r}: allowed {', '.join(KINDS)}")
    return _DTYPES[kind]


# ------------------------------------------------------------------------ manifest


def new_manifest(
    *,
    kind: str,
    capture: str,
    width: int,
    height: int,
    n_files: int,
    t0_ps: float,
    bin_width_ps: float,
    n_bins: int,
    quantity: str,
    include_first_last: bool = False,
    geometry: dict | None = None,
    laser: dict | None = None,
    detector: dict | None = None,
    render: dict | None = None,
    channels=None,
    **extra: Any,
) -> dict:
    """Build a manifest dictionary (validated).

    Parameters
    ----------
    kind : {"ideal", "counts"}
        Expected values (FLOAT) or detected photon counts (UINT).
    capture : {"camera", "array", "confocal"}
        A camera render (one file), an NLOS array capture (one file per laser
        spot) or a confocal NLOS capture (one file).
    width, height : int
        Pixels of the sensor / SPAD array.
    n_files : int
        Number of ``spot_NNNNN.exr`` files.
    t0_ps, bin_width_ps, n_bins
        Time axis: bin ``b`` covers ``[t0_ps + b*bin_width_ps, t0_ps + (b+1)*bin_width_ps)``.
    quantity : str
        What a bin holds, e.g. ``"radiance"`` (camera renders: radiance
        integrated over the bin), ``"photons_per_pulse"`` (ideal NLOS) or
        ``"counts"``.
    include_first_last : bool
        Whether laser->wall and wall->detector segments are in the path length.
    geometry, laser, detector, render : dict, optional
        Scene geometry (positions in metres), laser, detector model
        parameters and provenance; see the README for the keys.
    channels : sequence of str, optional
        Channel names of a multi-channel capture (``("R", "G", "B")`` or
        ``("S0", "S1", "S2", "S3")``, see :data:`CHANNEL_SETS`); None: mono.
        The manifest then also records the ``intensity`` rule.
    **extra
        Further top-level keys, stored verbatim (JSON-serialisable).
    """
    m = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "status": "incomplete",
        "kind": kind,
        "capture": capture,
        "quantity": quantity,
        "width": int(width),
        "height": int(height),
        "n_files": int(n_files),
        "time": {"t0_ps": float(t0_ps), "bin_width_ps": float(bin_width_ps), "n_bins": int(n_bins)},
        "include_first_last": bool(include_first_last),
        "geometry": geometry,
        "laser": laser,
        "detector": detector,
        "render": render,
    }
    if channels:
        m["channels"] = [str(c) for c in channels]
        m["intensity"] = intensity_rule(m["channels"])
    m.update(extra)
    return validate_manifest(_jsonable(m), "manifest")


def _not_finite(value: float):
    raise StackError(f"manifest value {value!r} is not finite")


def _jsonable(obj):
    """Plain JSON types for a manifest or config (numpy scalars and arrays converted); a NaN or
    infinity is an error."""
    return to_json(obj, _not_finite)


def validate_manifest(m: dict, where: str | os.PathLike = "manifest") -> dict:
    """Check the manifest's required keys, types and ranges; return it.

    Raises
    ------
    StackError
        Naming ``where`` and the offending key.
    """

    def bad(msg: str) -> StackError:
        return StackError(f"{where}: {msg}")

    if not isinstance(m, dict):
        raise bad("is not a JSON object")
    if m.get("format") != FORMAT:
        raise bad(f"format={m.get('format')!r}, expected {FORMAT!r}")
    ver = m.get("format_version")
    if ver != FORMAT_VERSION:
        raise bad(f"format_version={ver!r}, this reader supports {FORMAT_VERSION}")
    for key, allowed in (("kind", KINDS), ("capture", CAPTURES), ("status", STATUSES)):
        if m.get(key) not in allowed:
            raise bad(f"{key}={m.get(key)!r}, allowed: {', '.join(allowed)}")
    for key in ("width", "height", "n_files"):
        v = m.get(key)
        if not isinstance(v, int) or isinstance(v, bool) or v <= 0:
            raise bad(f"{key}={v!r} must be a positive integer")
    t = m.get("time")
    if not isinstance(t, dict):
        raise bad("time is missing (expected t0_ps, bin_width_ps, n_bins)")
    n_bins = t.get("n_bins")
    if not isinstance(n_bins, int) or isinstance(n_bins, bool) or n_bins <= 0:
        raise bad(f"time.n_bins={n_bins!r} must be a positive integer")
    bw = t.get("bin_width_ps")
    if not isinstance(bw, (int, float)) or not bw > 0 or not math.isfinite(bw):
        raise bad(f"time.bin_width_ps={bw!r} must be a finite number > 0")
    t0 = t.get("t0_ps")
    if not isinstance(t0, (int, float)) or not math.isfinite(t0):
        raise bad(f"time.t0_ps={t0!r} must be a finite number")
    if not isinstance(m.get("include_first_last"), bool):
        raise bad(f"include_first_last={m.get('include_first_last')!r} must be true or false")
    ch = m.get("channels")
    if ch is not None:
        if not isinstance(ch, list) or intensity_rule(ch) is None:
            raise bad(f"channels={ch!r}, allowed: null (mono), one of "
                      + ", ".join(str(list(k)) for k in CHANNEL_SETS)
                      + " or increasing, non-overlapping wavelength bands such as ['400-500nm', '500-600nm']")
        if m.get("intensity") != intensity_rule(ch):
            raise bad(f"intensity={m.get('intensity')!r} for channels {ch}, expected {intensity_rule(ch)!r}")
        if m["kind"] == "counts":
            raise bad("a counts capture has one intensity per bin: channels must be null")
    if m["capture"] in ("camera", "confocal") and m["n_files"] != 1:
        raise bad(f"n_files={m['n_files']} but a {m['capture']} capture is stored in exactly 1 file")
    geo = m.get("geometry")
    if m["capture"] in ("array", "confocal"):
        if not isinstance(geo, dict):
            raise bad(f"geometry is missing; a {m['capture']} capture needs spot and pixel positions")
        _check_geometry(geo, m, bad)
    return m


def _check_geometry(geo: dict, m: dict, bad) -> None:
    H, W = m["height"], m["width"]
    spots = np.asarray(geo.get("spots", []), dtype=float)
    n_spots = H * W if m["capture"] == "confocal" else m["n_files"]
    if spots.shape != (n_spots, 3):
        raise bad(f"geometry.spots has shape {spots.shape}, expected ({n_spots}, 3)")
    for key in ("pixel_centers", "pixel_normals"):
        arr = np.asarray(geo.get(key, []), dtype=float)
        if arr.shape != (H, W, 3):
            raise bad(f"geometry.{key} has shape {arr.shape}, expected ({H}, {W}, 3)")
    for key in ("laser_origin", "detector_origin"):
        arr = np.asarray(geo.get(key, []), dtype=float)
        if arr.shape != (3,):
            raise bad(f"geometry.{key}={geo.get(key)!r} must be 3 numbers (metres)")


def manifest_path(directory: str | os.PathLike) -> Path:
    return Path(directory) / MANIFEST_NAME


def _atomic_write_bytes(path: Path, data: bytes) -> None:
    with atomic_file(path, fsync=True) as tmp:
        tmp.write_bytes(data)


def write_manifest(directory: str | os.PathLike, manifest: dict) -> Path:
    """Validate and atomically write ``manifest.json`` into ``directory``."""
    path = manifest_path(directory)
    m = validate_manifest(_jsonable(manifest), path)
    _atomic_write_bytes(path, (json.dumps(m, indent=1, sort_keys=False) + "\n").encode())
    return path


def read_manifest(directory: str | os.PathLike) -> dict:
    """Read and validate ``manifest.json`` of a capture directory."""
    d = Path(directory)
    if not d.is_dir():
        raise StackError(f"{d}: not a capture directory (does not exist)" if not d.exists()
                         else f"{d}: not a capture directory (it is a file)")
    path = manifest_path(d)
    if not path.is_file():
        raise StackError(f"{path}: missing; {d} is not a transient-mi capture")
    try:
        m = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise StackError(f"{path}: not valid JSON ({e})") from None
    return validate_manifest(m, path)


def config_digest(config: Any) -> str:
    """SHA-256 of a JSON-serialisable render configuration (for resume checks)."""
    blob = json.dumps(_jsonable(config), sort_keys=True, separators=(",", ":")).encode()
    return hashlib.sha256(blob).hexdigest()


# ----------------------------------------------------------------------- spot files


def _header(manifest: dict, index: int) -> dict:
    import OpenEXR

    t = manifest["time"]
    h = {
        "compression": OpenEXR.ZIP_COMPRESSION,
        "type": OpenEXR.scanlineimage,
        "tmi_format": FORMAT,
        "tmi_format_version": FORMAT_VERSION,
        "tmi_kind": manifest["kind"],
        "tmi_capture": manifest["capture"],
        "tmi_quantity": manifest["quantity"],
        "tmi_spot_index": int(index),
        "tmi_n_files": int(manifest["n_files"]),
        # (t0_ps, bin_width_ps, n_bins) as doubles: EXR float attributes are 32-bit.
        "tmi_time_axis": np.array([t["t0_ps"], t["bin_width_ps"], t["n_bins"]], dtype=np.float64),
        "tmi_include_first_last": int(manifest["include_first_last"]),
    }
    if manifest.get("channels"):
        h["tmi_channels"] = ",".join(manifest["channels"])
    geo = manifest.get("geometry")
    if isinstance(geo, dict) and manifest["capture"] == "array":
        h["tmi_spot_position"] = np.asarray(geo["spots"][index], dtype=np.float64)
    digest = (manifest.get("render") or {}).get("config_sha256")
    if digest:
        h["tmi_config_sha256"] = str(digest)
    return h


def spot_path(directory: str | os.PathLike, index: int) -> Path:
    return Path(directory) / spot_filename(index)


def write_spot(directory: str | os.PathLike, index: int, data: np.ndarray, manifest: dict) -> Path:
    """Atomically write laser spot ``index`` of a capture.

    Parameters
    ----------
    directory : path
        Capture directory (must exist).
    index : int
        Spot index in scan order, ``0 <= index < manifest['n_files']``.
    data : ndarray, shape (height, width, n_bins[, n_channels])
        Values for this spot (a last channel axis for multi-channel captures); cast to float32 (``ideal``) or uint32
        (``counts``). Ideal data must be finite and >= 0; counts must be
        integers in [0, 2**32).
    manifest : dict
        The capture's manifest (gives shape, time axis and metadata).
    """
    import OpenEXR

    d = Path(directory)
    if not 0 <= int(index) < manifest["n_files"]:
        raise StackError(f"spot index {index} out of range [0, {manifest['n_files']})")
    arr = np.asarray(data)
    shape = data_shape(manifest)
    if arr.shape != shape:
        raise StackError(f"{spot_path(d, index)}: data shape {arr.shape}, manifest says {shape}")
    dt = dtype_for(manifest["kind"])
    if manifest["kind"] == "ideal":
        arr = arr.astype(np.float32, copy=False)
        if not np.all(np.isfinite(arr)) or (arr.size and arr.min() < 0):
            raise StackError(f"{spot_path(d, index)}: ideal data must be finite and >= 0")
    else:
        if arr.dtype.kind == "f":
            if not np.all(np.isfinite(arr)) or np.any(arr != np.round(arr)):
                raise StackError(f"{spot_path(d, index)}: counts must be whole numbers")
        if arr.size and (arr.min() < 0 or arr.max() > np.iinfo(np.uint32).max):
            raise StackError(f"{spot_path(d, index)}: counts must lie in [0, 2**32)")
        arr = arr.astype(dt, copy=False)
    channels = _layers(arr, manifest)
    path = spot_path(d, index)
    with atomic_file(path, fsync=True) as tmp:
        OpenEXR.File(_header(manifest, index), channels).write(str(tmp))
    return path


def _layers(arr: np.ndarray, manifest: dict) -> dict:
    """EXR channels (name -> [H, W] array) of one spot's ``arr`` (``data_shape(manifest)``)."""
    T, ch = manifest["time"]["n_bins"], manifest.get("channels")
    names = channel_names(T, ch)
    if not ch:
        return {name: np.ascontiguousarray(arr[:, :, b]) for b, name in enumerate(names)}
    C = len(ch)
    return {name: np.ascontiguousarray(arr[:, :, i // C, i % C]) for i, name in enumerate(names)}


def _unlayer(path: Path, chans: dict, manifest: dict, dt, names_extra=()) -> np.ndarray:
    """Inverse of :func:`_layers`: the spot array from EXR channels, checking names, types and sizes."""
    T, ch = manifest["time"]["n_bins"], manifest.get("channels")
    names = channel_names(T, ch)
    if set(chans) != set(names) | set(names_extra):
        missing = sorted(set(names) - set(chans))[:3]
        extra = sorted(set(chans) - set(names) - set(names_extra))[:3]
        what = f"{T} time bins" + (f" x {len(ch)} channels ({', '.join(ch)})" if ch else "")
        raise StackError(
            f"{path}: has {len(chans) - len(names_extra)} channels, manifest says {what}"
            + (f"; missing e.g. {missing}" if missing else "")
            + (f"; unexpected e.g. {extra}" if extra else "")
        )
    out = np.empty(data_shape(manifest), dtype=dt)
    flat = out.reshape(out.shape[0], out.shape[1], -1)  # [H, W, T * C]: channel names in the same order
    for i, name in enumerate(names):
        px = chans[name].pixels
        if px is None or px.dtype != dt or px.shape != out.shape[:2]:
            got = None if px is None else (px.dtype, px.shape)
            raise StackError(f"{path}: channel {name} is {got}, expected ({dt}, {out.shape[:2]})")
        flat[:, :, i] = px
    return out


def _open_exr(path: Path, header_only: bool) -> tuple[dict, dict | None]:
    """``(header, channels)`` of an EXR file (``channels`` None when header_only).

    Every OpenEXR failure (missing, truncated, corrupt) becomes a StackError
    naming the file.
    """
    import OpenEXR

    if not path.is_file():
        raise StackError(f"{path}: missing")
    try:
        # separate_channels: OpenEXR would otherwise merge tNNNNN.R/G/B into one RGB array
        f = OpenEXR.File(str(path), header_only=header_only, separate_channels=True)
        header = f.header()
        channels = None if header_only else f.channels()
    except Exception as e:  # OpenEXR raises RuntimeError/ValueError/OSError
        raise StackError(f"{path}: not a readable EXR file, truncated or corrupt ({e})") from None
    return header, channels


def _check_header(path: Path, hdr: dict, manifest: dict, index: int) -> None:
    def expect(key, want):
        got = hdr.get(key)
        if got != want:
            raise StackError(f"{path}: header {key}={got!r}, expected {want!r}")

    expect("tmi_format", FORMAT)
    expect("tmi_format_version", FORMAT_VERSION)
    expect("tmi_kind", manifest["kind"])
    expect("tmi_capture", manifest["capture"])
    expect("tmi_spot_index", int(index))
    t = manifest["time"]
    axis = np.asarray(hdr.get("tmi_time_axis", []), dtype=np.float64)
    want = np.array([t["t0_ps"], t["bin_width_ps"], t["n_bins"]], dtype=np.float64)
    if axis.shape != (3,) or not np.array_equal(axis, want):
        raise StackError(
            f"{path}: time axis (t0_ps, bin_width_ps, n_bins)={tuple(axis.tolist())}, "
            f"manifest says {tuple(want.tolist())}"
        )
    want_ch = ",".join(manifest["channels"]) if manifest.get("channels") else None
    if hdr.get("tmi_channels") != want_ch:
        raise StackError(f"{path}: header tmi_channels={hdr.get('tmi_channels')!r}, manifest says {want_ch!r}")
    digest = (manifest.get("render") or {}).get("config_sha256")
    if digest and hdr.get("tmi_config_sha256") != digest:
        raise StackError(f"{path}: written by a different render configuration than {MANIFEST_NAME} describes")
    lo, hi = hdr.get("dataWindow", (np.zeros(2), np.zeros(2)))
    W, H = int(hi[0] - lo[0] + 1), int(hi[1] - lo[1] + 1)
    if (H, W) != (manifest["height"], manifest["width"]):
        raise StackError(f"{path}: image is {W}x{H}, manifest says {manifest['width']}x{manifest['height']}")


def spot_is_complete(directory: str | os.PathLike, index: int, manifest: dict) -> bool:
    """True if spot ``index`` exists and its header matches ``manifest``.

    Files appear under their final name only once fully written (atomic
    rename), so a matching header means a complete file. Used by resume.
    """
    return _matching_header(spot_path(directory, index), manifest, index) is not None


def _matching_header(path: Path, manifest: dict, index: int) -> dict | None:
    """The header of ``path`` if the file exists and matches ``manifest`` (complete: atomic writes), else None."""
    if not path.is_file():
        return None
    try:
        header, _ = _open_exr(path, header_only=True)
        _check_header(path, header, manifest, index)
    except StackError:
        return None
    return header


def read_spot(directory: str | os.PathLike, index: int, manifest: dict | None = None) -> np.ndarray:
    """Read laser spot ``index`` as an array of shape (height, width, n_bins[, n_channels]).

    The dtype is float32 for ``ideal`` and uint32 for ``counts`` captures;
    multi-channel captures have a last channel axis in the manifest's
    ``channels`` order (see :func:`intensity` for one intensity per bin).

    Raises
    ------
    StackError
        If the file is missing, truncated, or disagrees with the manifest
        (format, kind, spot index, time axis, image size, channels).
    """
    d = Path(directory)
    m = read_manifest(d) if manifest is None else manifest
    path = spot_path(d, index)
    header, chans = _open_exr(path, header_only=False)
    _check_header(path, header, m, index)
    return _unlayer(path, chans, m, dtype_for(m["kind"]))


def read_intensity(directory: str | os.PathLike, index: int, manifest: dict | None = None) -> np.ndarray:
    """Spot ``index`` as one intensity per bin, ``[height, width, n_bins]``: :func:`read_spot` reduced by the
    manifest's intensity rule (:func:`intensity`); mono captures are returned as read."""
    m = read_manifest(directory) if manifest is None else manifest
    return intensity(read_spot(directory, index, m), m)


def missing_spots(directory: str | os.PathLike, manifest: dict | None = None) -> list[int]:
    """Indices of spot files that are absent (not a content check)."""
    d = Path(directory)
    m = read_manifest(d) if manifest is None else manifest
    return [j for j in range(m["n_files"]) if not spot_path(d, j).is_file()]


def _require_complete(d: Path, m: dict) -> None:
    missing = missing_spots(d, m)
    if missing:
        shown = ", ".join(spot_filename(j) for j in missing[:5]) + (" ..." if len(missing) > 5 else "")
        raise StackError(
            f"{d}: {len(missing)} of {m['n_files']} spot files missing ({shown}); "
            "the render was interrupted: rerun it with --resume"
        )
    if m["status"] != "complete":
        raise StackError(f"{manifest_path(d)}: status is {m['status']!r}; the render did not finish (rerun with --resume)")


def iter_spots(directory: str | os.PathLike) -> Iterator[tuple[int, np.ndarray]]:
    """Yield ``(index, data[height, width, n_bins[, n_channels]])`` spot by spot (bounded memory)."""
    d = Path(directory)
    m = read_manifest(d)
    _require_complete(d, m)
    for j in range(m["n_files"]):
        yield j, read_spot(d, j, m)


def read_stack(directory: str | os.PathLike) -> tuple[dict, np.ndarray]:
    """Read a whole capture: ``(manifest, data[n_files, height, width, n_bins[, n_channels]])``.

    Holds everything in memory; use :func:`iter_spots` for large captures.
    """
    d = Path(directory)
    m = read_manifest(d)
    _require_complete(d, m)
    data = np.empty((m["n_files"],) + data_shape(m), dtype=dtype_for(m["kind"]))
    for j in range(m["n_files"]):
        data[j] = read_spot(d, j, m)
    return m, data


def write_stack(directory: str | os.PathLike, manifest: dict, data: np.ndarray) -> Path:
    """Write a whole capture held in memory (``data[n_files, H, W, T[, C]]``).

    Creates ``directory`` (its parent must exist), writes the manifest as
    ``incomplete``, every spot, then the manifest as ``complete``.
    """
    d = Path(directory)
    arr = np.asarray(data)
    want = (manifest["n_files"],) + data_shape(manifest)
    if arr.shape != want:
        raise StackError(f"data shape {arr.shape}, expected {want}")
    d.mkdir(exist_ok=True)
    m = dict(manifest, status="incomplete")
    write_manifest(d, m)
    for j in range(arr.shape[0]):
        write_spot(d, j, arr[j], m)
    m["status"] = "complete"
    write_manifest(d, m)
    return d


# ------------------------------------------------------------------------ variance


def has_variance(manifest: dict) -> bool:
    """True if the capture stores per-bin variance files (``manifest['variance']['directory']``).

    The files hold a Monte Carlo variance, or, for a deterministic estimator, an error bound (see
    :func:`is_error_bound`); :func:`read_variance` reads either.
    """
    v = manifest.get("variance")
    return isinstance(v, dict) and bool(v.get("directory"))


#: ``manifest['variance']['kind']`` of a deterministic estimator: the files hold a bound on the absolute error
#: of every value (same unit as the data), not a variance.
ERROR_BOUND_KIND = "error_bound"
#: Directory of the error-bound files of a deterministic estimator's capture.
ERROR_BOUND_DIR = "error_bound"


def is_error_bound(manifest: dict) -> bool:
    """True if the capture's ``variance`` files hold a deterministic error bound (not a variance)."""
    v = manifest.get("variance")
    return isinstance(v, dict) and v.get("kind") == ERROR_BOUND_KIND


def _sibling_bound(manifest: dict) -> dict | None:
    """The manifest's top-level ``error_bound`` block (a capture with two error parts), or None."""
    b = manifest.get("error_bound")
    return b if isinstance(b, dict) and b.get("directory") else None


def has_error_bound(manifest: dict) -> bool:
    """True if the capture stores a deterministic error bound: as its ``variance`` (a pure quadrature capture,
    :func:`is_error_bound`) or beside a Monte Carlo variance (manifest ``error_bound``, a capture of two parts:
    the quadrature's three-bounce light and the Monte Carlo remainder beyond it)."""
    return is_error_bound(manifest) or _sibling_bound(manifest) is not None


def error_bound_view(manifest: dict) -> dict:
    """The manifest as a pure quadrature capture's: ``variance`` is its error-bound block.

    A capture of two parts keeps its Monte Carlo variance in ``variance`` and its error bound in a sibling
    ``error_bound`` block of the same layout as a pure quadrature capture's ``variance`` block (``kind:
    "error_bound"``, ``directory: "error_bound"``); every reader of ``variance`` reads the bound through this view.
    """
    if is_error_bound(manifest):
        return manifest
    b = _sibling_bound(manifest)
    if b is None:
        raise StackError("the capture stores no error bound")
    return dict(manifest, variance=b)


def write_error_bound(directory: str | os.PathLike, index: int, bound: np.ndarray, total_bound: np.ndarray,
                      manifest: dict) -> Path:
    """Atomically write the error bound of spot ``index`` (``error_bound/spot_NNNNN.exr``, as
    :func:`write_variance`)."""
    return write_variance(directory, index, bound, total_bound, error_bound_view(manifest))


def read_error_bound(directory: str | os.PathLike, index: int, manifest: dict | None = None
                     ) -> tuple[np.ndarray, np.ndarray]:
    """``(bound[height, width, n_bins], total_bound[height, width])`` of spot ``index`` (see :func:`read_variance`)."""
    m = read_manifest(Path(directory)) if manifest is None else manifest
    return read_variance(directory, index, error_bound_view(m))


def _variance_dir(directory, manifest: dict) -> Path:
    if not has_variance(manifest):
        raise StackError(f"{directory}: the capture stores no variance (rendered with a single replicate)")
    return Path(directory) / manifest["variance"]["directory"]


def write_variance(directory: str | os.PathLike, index: int, variance: np.ndarray, total_variance: np.ndarray,
                   manifest: dict) -> Path:
    """Atomically write the variance of laser spot ``index`` (``variance/spot_NNNNN.exr``).

    Parameters
    ----------
    variance : ndarray, shape (height, width, n_bins[, n_channels])
        Estimated variance of every stored value (>= 0, finite).
    total_variance : ndarray, shape (height, width[, n_channels])
        Estimated variance of each pixel's sum over time (per channel).
    """
    import OpenEXR

    vd = _variance_dir(directory, manifest)
    vd.mkdir(exist_ok=True)
    shape = data_shape(manifest)
    tot_shape = shape[:2] + shape[3:]
    var = np.asarray(variance, dtype=np.float32)
    tot = np.asarray(total_variance, dtype=np.float32)
    path = vd / spot_filename(index)
    if var.shape != shape or tot.shape != tot_shape:
        raise StackError(f"{path}: variance shapes {var.shape} and {tot.shape}, expected {shape} and {tot_shape}")
    if not (np.all(np.isfinite(var)) and np.all(np.isfinite(tot))) or (var.size and var.min() < 0) \
            or (tot.size and tot.min() < 0):
        raise StackError(f"{path}: variance must be finite and >= 0")
    channels = _layers(var, manifest)
    channels.update(_total_layers(tot, manifest))
    header = dict(_header(manifest, index), tmi_layer="variance")
    with atomic_file(path, fsync=True) as tmp:
        OpenEXR.File(header, channels).write(str(tmp))
    return path


def _total_names(manifest: dict) -> list[str]:
    ch = manifest.get("channels")
    return [f"{TOTAL_CHANNEL}.{c}" for c in ch] if ch else [TOTAL_CHANNEL]


def _total_layers(tot: np.ndarray, manifest: dict) -> dict:
    names = _total_names(manifest)
    if not manifest.get("channels"):
        return {names[0]: np.ascontiguousarray(tot)}
    return {n: np.ascontiguousarray(tot[:, :, c]) for c, n in enumerate(names)}


def variance_is_complete(directory: str | os.PathLike, index: int, manifest: dict) -> bool:
    """True if the variance file of spot ``index`` exists and matches ``manifest`` (used by resume); in a
    capture of two parts (:func:`has_error_bound`), the error-bound file too."""
    if not is_error_bound(manifest) and _sibling_bound(manifest) is not None \
            and not variance_is_complete(directory, index, error_bound_view(manifest)):
        return False
    if not has_variance(manifest):
        return True
    header = _matching_header(_variance_dir(directory, manifest) / spot_filename(index), manifest, index)
    return header is not None and header.get("tmi_layer") == "variance"


def read_variance(directory: str | os.PathLike, index: int, manifest: dict | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
    """``(variance[height, width, n_bins[, C]] float32, total_variance[height, width[, C]] float32)`` of spot ``index``.

    Raises
    ------
    StackError
        If the capture stores no variance, or the file is missing or disagrees with the manifest.
    """
    d = Path(directory)
    m = read_manifest(d) if manifest is None else manifest
    path = _variance_dir(d, m) / spot_filename(index)
    header, chans = _open_exr(path, header_only=False)
    _check_header(path, header, m, index)
    if header.get("tmi_layer") != "variance":
        raise StackError(f"{path}: header tmi_layer={header.get('tmi_layer')!r}, expected 'variance'")
    totals = _total_names(m)
    var = _unlayer(path, chans, m, np.dtype(np.float32), names_extra=totals)
    tot = np.stack([np.asarray(chans[n].pixels, dtype=np.float32) for n in totals], axis=-1)
    return var, (tot if m.get("channels") else tot[..., 0])
