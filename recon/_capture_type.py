"""The :class:`Capture` type and the checks of every geometry it accepts; :mod:`recon.capture` is its public face.

The checks of stack manifests, y-tal files and real captures live with the type: every reconstruction
method relies on them. The readers of other formats (:mod:`recon.io.ytal`, :mod:`recon.io.real`) build
their captures here, and :func:`recon.capture.load_capture`, which opens every format, sits above them,
so no two of these modules import each other.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Callable, Iterator, Sequence

import numpy as np

from transient_core.errors import UserInputError
from transient_core.units import C_M_PER_PS

__all__ = ["Capture", "MODES", "KINDS", "PULSE_KEYS"]

MODES = ("array", "confocal")
KINDS = ("ideal", "counts")

#: Keys under which a counts manifest's ``detector`` section may give the number of laser pulses.
PULSE_KEYS = ("pulses", "n_pulses", "n_cycles", "n_laser_pulses", "pulse_count")


def _vec3(value, name: str, allow_none: bool = False) -> np.ndarray | None:
    if value is None:
        if allow_none:
            return None
        raise UserInputError(f"{name} is missing: expected 3 numbers (metres)")
    a = np.asarray(value, dtype=np.float64)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise UserInputError(f"{name}={np.asarray(value).tolist()!r}: expected 3 finite numbers (metres)")
    return a


def _unit_normals(n: np.ndarray, name: str) -> np.ndarray:
    norm = np.linalg.norm(n, axis=-1)
    if not np.all(np.isfinite(n)) or np.any(norm < 1e-9):
        raise UserInputError(f"{name} has zero-length or non-finite vectors; normals must be unit vectors")
    if np.max(np.abs(norm - 1.0)) > 1e-3:
        raise UserInputError(f"{name} has vectors of length {norm.min():.4g}..{norm.max():.4g}; normals must be unit vectors")
    return n / norm[..., None]


@dataclasses.dataclass(frozen=True, eq=False)
class Capture:
    """One NLOS capture (see the module docstring).

    Attributes
    ----------
    mode : {"array", "confocal"}
        ``array``: every pixel recorded for every laser spot, one file per
        spot (a single-spot capture is an array capture with one spot).
        ``confocal``: one file; pixel ``k`` recorded with the laser on spot ``k``.
    kind : {"ideal", "counts"}
        Expected photons per pulse (float) or detected photon counts.
    spots : ndarray, shape (n_spots, 3)
        Laser spot positions S_j on the wall, metres, scan order (row-major
        over ``spot_grid``). For confocal captures ``n_spots = H*W`` and spot
        ``k`` belongs to pixel ``k`` (row-major).
    spot_normals : ndarray, shape (n_spots, 3)
        Unit wall normals at the spots.
    pixel_centers, pixel_normals : ndarray, shape (H, W, 3)
        Wall patch centre P_k seen by each pixel and its unit normal, metres.
    laser_origin, detector_origin : ndarray, shape (3,), or None
        Laser and detector (lens) positions, metres. Required when
        ``include_first_last`` is true.
    t0_ps, bin_width_ps : float
        Start of bin 0 and bin width, picoseconds (time zero = pulse leaves the laser).
    n_bins : int
        Number of time bins.
    include_first_last : bool
        Whether laser -> S_j and P_k -> detector are in the recorded path length.
    spot_grid : tuple (ny, nx) or None
        Scan grid of an array capture's spots.
    manifest : dict
        The stack manifest (or one built for the arrays), kept verbatim.
    source : str or None
        Where the data came from (a directory or file path).
    processing : tuple of str
        Preprocessing steps applied since loading (for provenance).
    """

    mode: str
    kind: str
    spots: np.ndarray
    spot_normals: np.ndarray
    pixel_centers: np.ndarray
    pixel_normals: np.ndarray
    laser_origin: np.ndarray | None
    detector_origin: np.ndarray | None
    t0_ps: float
    bin_width_ps: float
    n_bins: int
    include_first_last: bool
    n_files: int
    _loader: Callable[[int], np.ndarray] = dataclasses.field(repr=False)
    spot_grid: tuple | None = None
    manifest: dict = dataclasses.field(default_factory=dict, repr=False)
    source: str | None = None
    processing: tuple = ()
    _cache: dict = dataclasses.field(default_factory=dict, repr=False)

    # ------------------------------------------------------------------ shape

    @property
    def height(self) -> int:
        """Pixel rows H."""
        return int(self.pixel_centers.shape[0])

    @property
    def width(self) -> int:
        """Pixel columns W."""
        return int(self.pixel_centers.shape[1])

    @property
    def n_spots(self) -> int:
        """Number of laser spots (``H*W`` for confocal captures)."""
        return int(self.spots.shape[0])

    @property
    def shape(self) -> tuple[int, int, int, int]:
        """``(n_files, H, W, n_bins)``: the shape of :attr:`data`."""
        return (self.n_files, self.height, self.width, self.n_bins)

    # ------------------------------------------------------------- time axis

    @property
    def bin_edges_ps(self) -> np.ndarray:
        """Bin edges, ps, shape ``(n_bins + 1,)``."""
        return self.t0_ps + self.bin_width_ps * np.arange(self.n_bins + 1, dtype=np.float64)

    @property
    def times_ps(self) -> np.ndarray:
        """Bin centres, ps, shape ``(n_bins,)``."""
        return self.t0_ps + self.bin_width_ps * (np.arange(self.n_bins, dtype=np.float64) + 0.5)

    @property
    def t_end_ps(self) -> float:
        """End of the last bin, ps."""
        return self.t0_ps + self.bin_width_ps * self.n_bins

    @property
    def bin_width_m(self) -> float:
        """Bin width as optical path length, metres."""
        return self.bin_width_ps * C_M_PER_PS

    @property
    def t0_m(self) -> float:
        """Start of bin 0 as optical path length, metres."""
        return self.t0_ps * C_M_PER_PS

    # ----------------------------------------------------------------- data

    def spot(self, j: int) -> np.ndarray:
        """Histograms of stored file ``j``, shape ``(H, W, n_bins)``.

        For array captures file ``j`` is laser spot ``j``; a confocal capture
        has one file (``j = 0``) holding every pixel with its own spot.
        """
        j = int(j)
        if not 0 <= j < self.n_files:
            raise UserInputError(f"spot index {j} out of range: this capture has {self.n_files} file(s)")
        if "data" in self._cache:
            return self._cache["data"][j]
        arr = np.asarray(self._loader(j))
        if arr.shape != (self.height, self.width, self.n_bins):
            raise UserInputError(
                f"{self.source or 'capture'}: spot {j} has shape {arr.shape}, "
                f"expected ({self.height}, {self.width}, {self.n_bins})"
            )
        return arr

    def iter_spots(self) -> Iterator[tuple[int, np.ndarray]]:
        """Yield ``(j, histograms[H, W, n_bins])`` for every stored file, one at a time."""
        for j in range(self.n_files):
            yield j, self.spot(j)

    @property
    def data(self) -> np.ndarray:
        """All histograms, ``[n_files, H, W, n_bins]`` (loaded once, then cached)."""
        if "data" not in self._cache:
            first = self.spot(0)
            out = np.empty(self.shape, dtype=first.dtype)
            out[0] = first
            for j in range(1, self.n_files):
                out[j] = self.spot(j)
            self._cache["data"] = out
        return self._cache["data"]

    # -------------------------------------------------------------- geometry

    def spot_positions(self, j: int) -> np.ndarray:
        """Laser spot(s) used by file ``j``: ``(3,)`` (array) or ``(H, W, 3)`` (confocal)."""
        if self.mode == "confocal":
            return self.spots.reshape(self.height, self.width, 3)
        return self.spots[j]

    def path_offsets_m(self, j: int) -> np.ndarray:
        """First + last segment lengths for file ``j``, metres, shape ``(H, W)``.

        ``|laser - S_j| + |P_k - detector|`` when the capture includes them,
        zeros otherwise. Subtracting it from a bin's path length leaves the
        three-bounce part ``|S_j - o| + |o - P_k|``. Captures rendered through a window record the legs'
        optical path lengths (manifest ``geometry.spot_leg_opl_m`` and ``pixel_leg_opl_m``: refraction
        and the slower light in glass, see docs/glass.md); they are used instead when present.
        """
        if not self.include_first_last:
            return np.zeros((self.height, self.width))
        geo = self.manifest.get("geometry") or {}
        if geo.get("pixel_leg_opl_m") is not None:
            last = np.asarray(geo["pixel_leg_opl_m"], dtype=np.float64).reshape(self.height, self.width)
        else:
            last = np.linalg.norm(self.pixel_centers - self.detector_origin, axis=-1)
        if geo.get("spot_leg_opl_m") is not None:
            legs = np.asarray(geo["spot_leg_opl_m"], dtype=np.float64)
            first = legs.reshape(self.height, self.width) if self.mode == "confocal" else legs[j]
        else:
            first = np.linalg.norm(self.spot_positions(j) - self.laser_origin, axis=-1)
        return first + last

    def pixel_pitch_m(self) -> tuple[float, float]:
        """Mean spacing of neighbouring pixel patches along x (columns) and y (rows), metres."""
        P = self.pixel_centers
        dx = float(np.mean(np.linalg.norm(np.diff(P, axis=1), axis=-1))) if self.width > 1 else math.nan
        dy = float(np.mean(np.linalg.norm(np.diff(P, axis=0), axis=-1))) if self.height > 1 else math.nan
        if math.isnan(dx):
            dx = dy
        if math.isnan(dy):
            dy = dx
        if math.isnan(dx):
            fp = (self.manifest.get("geometry") or {}).get("pixel_footprint_m")
            dx = dy = float(fp) if fp else math.nan
        return dx, dy

    def wall_is_z0(self, atol: float = 1e-6) -> bool:
        """True if every pixel patch and spot lies in the plane z = 0 with normal +z."""
        pts = np.concatenate([self.pixel_centers.reshape(-1, 3), self.spots])
        nrm = np.concatenate([self.pixel_normals.reshape(-1, 3), self.spot_normals])
        return bool(np.all(np.abs(pts[:, 2]) <= atol) and np.all(np.abs(nrm - [0, 0, 1]) <= 1e-6))

    def n_pulses(self) -> float | None:
        """Number of laser pulses a counts capture integrates (from the manifest's ``detector``)."""
        det = self.manifest.get("detector") or {}
        for key in PULSE_KEYS:
            v = det.get(key)
            if isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0:
                return float(v)
        return None

    # -------------------------------------------------------------- derived

    def derive(self, transform: Callable[[int, np.ndarray], np.ndarray] | None = None, step: str | None = None,
               **changes) -> "Capture":
        """A new capture whose files are ``transform(j, self.spot(j))`` (lazily).

        ``changes`` replace attributes (e.g. ``t0_ps``, ``n_bins``,
        ``include_first_last``); ``step`` is appended to :attr:`processing`.
        """
        parent = self
        loader = self._loader if transform is None else (lambda j: transform(j, parent.spot(j)))
        if transform is None and "data" in self._cache:
            loader = (lambda j: parent._cache["data"][j])
        proc = self.processing + ((step,) if step else ())
        return dataclasses.replace(self, _loader=loader, _cache={}, processing=proc, **changes)

    def describe(self) -> str:
        """One line: mode, sizes and time axis."""
        what = (f"confocal {self.height}x{self.width}" if self.mode == "confocal"
                else f"array {self.n_spots} spot(s) x {self.height}x{self.width} pixels")
        return (f"{what}, {self.n_bins} bins of {self.bin_width_ps:g} ps from {self.t0_ps:g} ps, "
                f"{self.kind}, first/last segments {'included' if self.include_first_last else 'excluded'}")

    # ----------------------------------------------------------- constructors

    @classmethod
    def from_arrays(
        cls,
        data: np.ndarray,
        *,
        mode: str = "array",
        spots: Sequence | np.ndarray,
        pixel_centers: np.ndarray,
        pixel_normals: np.ndarray | None = None,
        spot_normals: np.ndarray | None = None,
        laser_origin: Sequence[float] | None = None,
        detector_origin: Sequence[float] | None = None,
        t0_ps: float = 0.0,
        bin_width_ps: float,
        include_first_last: bool = False,
        kind: str = "ideal",
        spot_grid: Sequence[int] | None = None,
        quantity: str | None = None,
        manifest_extra: dict | None = None,
        source: str | None = None,
    ) -> "Capture":
        """Build a capture from in-memory arrays.

        Parameters
        ----------
        data : ndarray, shape (n_files, H, W, n_bins) or (H, W, n_bins)
            Histograms; ``n_files = n_spots`` (array) or 1 (confocal).
        mode : {"array", "confocal"}
        spots : array_like, shape (n_spots, 3)
            Laser spots on the wall, metres (confocal: ``H*W`` spots, row-major).
        pixel_centers : ndarray, shape (H, W, 3)
            Wall patch centres, metres.
        pixel_normals, spot_normals : ndarray, optional
            Unit normals; default ``+z`` (the relay wall in the plane z = 0).
        laser_origin, detector_origin : 3 floats, optional
            Needed when ``include_first_last``.
        t0_ps, bin_width_ps : float
            Time axis (ps).
        include_first_last : bool
        kind : {"ideal", "counts"}
        spot_grid : (ny, nx), optional
            Scan grid of the spots (array captures); default ``(1, n_spots)``.
        quantity : str, optional
            What a bin holds; default ``photons_per_pulse`` / ``counts``.
        manifest_extra : dict, optional
            Extra manifest content (e.g. ``{"detector": {...}, "laser": {...}}``).
        """
        arr = np.asarray(data)
        if arr.ndim == 3:
            arr = arr[None]
        if arr.ndim != 4:
            raise UserInputError(f"data has shape {arr.shape}: expected (n_files, H, W, n_bins) or (H, W, n_bins)")
        if not np.issubdtype(arr.dtype, np.number) or np.iscomplexobj(arr):
            raise UserInputError(f"data has dtype {arr.dtype}: expected real numbers")
        n_files, H, W, T = arr.shape
        cap = _build(
            mode=mode, kind=kind, spots=spots, pixel_centers=pixel_centers, pixel_normals=pixel_normals,
            spot_normals=spot_normals, laser_origin=laser_origin, detector_origin=detector_origin,
            t0_ps=t0_ps, bin_width_ps=bin_width_ps, n_bins=T, include_first_last=include_first_last,
            n_files=n_files, spot_grid=spot_grid, quantity=quantity, manifest_extra=manifest_extra,
            loader=lambda j: arr[j], source=source,
        )
        if (cap.height, cap.width) != (H, W):
            raise UserInputError(f"data is {H}x{W} pixels but pixel_centers is {cap.height}x{cap.width}")
        if kind == "counts" and arr.size and (np.any(arr < 0) or (arr.dtype.kind == "f" and np.any(arr != np.round(arr)))):
            raise UserInputError("kind='counts' needs whole, non-negative numbers in data")
        if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
            raise UserInputError("data contains NaN or infinite values")
        cap._cache["data"] = arr
        return cap

    @classmethod
    def from_manifest(cls, manifest: dict, loader: Callable[[int], np.ndarray], source: str | None = None) -> "Capture":
        """Build a capture from a stack manifest and a per-file loader ``loader(j) -> [H, W, T]``."""
        m = manifest
        where = source or "manifest"
        if m.get("capture") not in MODES:
            raise UserInputError(
                f"{where}: capture={m.get('capture')!r} is not an NLOS capture; recon needs "
                f"{' or '.join(MODES)} (a camera capture is a transient video)"
            )
        geo = m.get("geometry") or {}
        t = m["time"]
        pc = np.asarray(geo.get("pixel_centers"), dtype=np.float64)
        n_spots = len(geo.get("spots") or [])
        spot_normals = geo.get("spot_normals")
        if spot_normals is None and geo.get("wall_normal") is not None and m["capture"] == "array":
            spot_normals = np.broadcast_to(np.asarray(geo["wall_normal"], dtype=np.float64), (n_spots, 3))
        return _build(
            mode=m["capture"], kind=m["kind"], spots=geo.get("spots"), pixel_centers=pc,
            pixel_normals=geo.get("pixel_normals"), spot_normals=spot_normals,
            laser_origin=geo.get("laser_origin"), detector_origin=geo.get("detector_origin"),
            t0_ps=t["t0_ps"], bin_width_ps=t["bin_width_ps"], n_bins=t["n_bins"],
            include_first_last=m["include_first_last"], n_files=m["n_files"], spot_grid=geo.get("spot_grid"),
            quantity=m.get("quantity"), manifest=m, loader=loader, source=source,
        )


def _build(*, mode, kind, spots, pixel_centers, pixel_normals, spot_normals, laser_origin, detector_origin,
           t0_ps, bin_width_ps, n_bins, include_first_last, n_files, spot_grid, quantity, loader, source,
           manifest=None, manifest_extra=None) -> Capture:
    where = f"{source}: " if source else ""
    if mode not in MODES:
        raise UserInputError(f"{where}mode={mode!r}: allowed {', '.join(MODES)}")
    if kind not in KINDS:
        raise UserInputError(f"{where}kind={kind!r}: allowed {', '.join(KINDS)}")
    pc = np.asarray(pixel_centers, dtype=np.float64)
    if pc.ndim != 3 or pc.shape[-1] != 3 or pc.shape[0] < 1 or pc.shape[1] < 1:
        raise UserInputError(f"{where}pixel_centers has shape {pc.shape}: expected (H, W, 3)")
    if not np.all(np.isfinite(pc)):
        raise UserInputError(f"{where}pixel_centers contains non-finite values")
    H, W = pc.shape[:2]
    pn = np.broadcast_to(np.array([0.0, 0.0, 1.0]), pc.shape) if pixel_normals is None \
        else np.asarray(pixel_normals, dtype=np.float64)
    if pn.shape != pc.shape:
        raise UserInputError(f"{where}pixel_normals has shape {pn.shape}, expected {pc.shape}")
    pn = _unit_normals(np.array(pn), f"{where}pixel_normals")
    if spots is None:
        raise UserInputError(f"{where}spots are missing: expected (n_spots, 3) positions in metres")
    sp = np.asarray(spots, dtype=np.float64)
    if sp.ndim == 1 and sp.shape == (3,):
        sp = sp[None]
    n_expected = H * W if mode == "confocal" else int(n_files)
    if sp.shape != (n_expected, 3):
        what = f"H*W = {H}*{W}" if mode == "confocal" else f"n_files = {n_files}"
        raise UserInputError(f"{where}spots has shape {sp.shape}, expected ({n_expected}, 3) ({what} for a {mode} capture)")
    if not np.all(np.isfinite(sp)):
        raise UserInputError(f"{where}spots contains non-finite values")
    if mode == "confocal" and int(n_files) != 1:
        raise UserInputError(f"{where}a confocal capture is stored in 1 file, got n_files={n_files}")
    if spot_normals is None:
        sn = pn.reshape(-1, 3).copy() if mode == "confocal" else np.tile([0.0, 0.0, 1.0], (sp.shape[0], 1))
    else:
        sn = np.asarray(spot_normals, dtype=np.float64).reshape(-1, 3)
        if sn.shape != sp.shape:
            raise UserInputError(f"{where}spot_normals has shape {sn.shape}, expected {sp.shape}")
        sn = _unit_normals(sn.copy(), f"{where}spot_normals")
    lo = _vec3(laser_origin, f"{where}laser_origin", allow_none=True)
    do = _vec3(detector_origin, f"{where}detector_origin", allow_none=True)
    if include_first_last and (lo is None or do is None):
        raise UserInputError(
            f"{where}include_first_last is true but laser_origin/detector_origin are missing: "
            "the first and last segments cannot be removed without them"
        )
    for name, v in (("t0_ps", t0_ps), ("bin_width_ps", bin_width_ps)):
        if not isinstance(v, (int, float, np.floating, np.integer)) or not math.isfinite(float(v)):
            raise UserInputError(f"{where}{name}={v!r} must be a finite number")
    if not float(bin_width_ps) > 0:
        raise UserInputError(f"{where}bin_width_ps={bin_width_ps!r} must be > 0")
    if int(n_bins) < 1:
        raise UserInputError(f"{where}n_bins={n_bins!r} must be >= 1")
    if spot_grid is not None:
        g = tuple(int(v) for v in spot_grid)
        if len(g) != 2 or g[0] * g[1] != sp.shape[0] or min(g) < 1:
            raise UserInputError(f"{where}spot_grid={list(spot_grid)!r} does not hold {sp.shape[0]} spots (ny * nx)")
        spot_grid = g
    elif mode == "array":
        spot_grid = (1, sp.shape[0])
    if manifest is None:
        manifest = _make_manifest(mode, kind, H, W, int(n_files), float(t0_ps), float(bin_width_ps), int(n_bins),
                                  bool(include_first_last), sp, sn, pc, pn, lo, do, spot_grid, quantity,
                                  manifest_extra or {})
    return Capture(
        mode=mode, kind=kind, spots=sp, spot_normals=sn, pixel_centers=pc, pixel_normals=pn,
        laser_origin=lo, detector_origin=do, t0_ps=float(t0_ps), bin_width_ps=float(bin_width_ps),
        n_bins=int(n_bins), include_first_last=bool(include_first_last), n_files=int(n_files),
        _loader=loader, spot_grid=spot_grid, manifest=manifest, source=source,
    )


def _make_manifest(mode, kind, H, W, n_files, t0_ps, bin_width_ps, n_bins, include_first_last, sp, sn, pc, pn,
                   lo, do, spot_grid, quantity, extra) -> dict:
    """A stack manifest for an in-memory capture (validated when the origins are known)."""
    from transient_core import stack

    geometry = {
        "laser_origin": None if lo is None else lo.tolist(),
        "detector_origin": None if do is None else do.tolist(),
        "spots": sp.tolist(),
        "pixel_centers": pc.tolist(),
        "pixel_normals": pn.tolist(),
    }
    if mode == "array":
        geometry["spot_grid"] = list(spot_grid)
        if not np.allclose(sn, [0.0, 0.0, 1.0]):
            geometry["spot_normals"] = sn.tolist()
    normals = pn.reshape(-1, 3)
    if np.allclose(normals, normals[0]):
        geometry["wall_normal"] = normals[0].tolist()
    extra = dict(extra)
    geometry.update(extra.pop("geometry", None) or {})
    fields = dict(
        kind=kind, capture=mode, width=W, height=H, n_files=n_files, t0_ps=t0_ps, bin_width_ps=bin_width_ps,
        n_bins=n_bins, quantity=quantity or ("counts" if kind == "counts" else "photons_per_pulse"),
        include_first_last=include_first_last, geometry=geometry,
        laser=extra.pop("laser", None), detector=extra.pop("detector", None), render=extra.pop("render", None),
    )
    if lo is not None and do is not None:
        m = stack.new_manifest(**fields, **extra)
    else:  # cannot be a valid stack manifest without the origins; keep the same layout
        m = {"format": stack.FORMAT, "format_version": stack.FORMAT_VERSION, "status": "incomplete",
             "kind": kind, "capture": mode, "quantity": fields["quantity"], "width": W, "height": H,
             "n_files": n_files, "time": {"t0_ps": t0_ps, "bin_width_ps": bin_width_ps, "n_bins": n_bins},
             "include_first_last": include_first_last, "geometry": geometry, "laser": fields["laser"],
             "detector": fields["detector"], "render": fields["render"], **extra}
    m["status"] = "complete"
    return m
