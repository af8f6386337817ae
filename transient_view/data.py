"""What the viewer shows, found under one root path: captures, reconstructions, ground-truth meshes.

The viewer is read-only and confined to the path it was started on: every
file it opens or serves is resolved (symbolic links followed) and must lie
inside that root (:meth:`Library.resolve`).

A *capture* is an EXR stack directory (``manifest.json``; NLOS ``array`` /
``confocal`` captures and ``camera`` transient videos) or a y-tal HDF5 file
(``.h5``/``.hdf5``). A *reconstruction* is a directory holding ``volume.npz``
(``transient-mi recon`` output). A *ground-truth mesh* is a ``.ply``, ``.obj``,
``.stl`` or ``.off`` file; the one that belongs to a capture is found beside it
or in a parent directory (the demo's ``ground_truth.ply``), or through a
dataset's ``index.jsonl`` (its ``mesh`` column).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from transient_core.errors import UserInputError

__all__ = ["Library", "CaptureData", "discover", "MESH_SUFFIXES", "HDF5_SUFFIXES"]

MESH_SUFFIXES = (".ply", ".obj", ".stl", ".off")
HDF5_SUFFIXES = (".h5", ".hdf5", ".hdf")
#: Directory levels searched below the root, and the most entries listed (a dataset can hold thousands).
MAX_DEPTH = 6
MAX_ENTRIES = 2000


@dataclass
class Library:
    """Everything viewable under ``root``.

    Attributes
    ----------
    root : Path
        The resolved path the viewer was started on (a directory or one file).
    captures, recons, meshes : list of Path
        Resolved paths, sorted.
    ground_truth : Path or None
        A mesh given explicitly (``--ground-truth``); it overrides the search.
    """

    root: Path
    captures: list = field(default_factory=list)
    recons: list = field(default_factory=list)
    meshes: list = field(default_factory=list)
    ground_truth: Path | None = None
    _index_meshes: dict = field(default_factory=dict, repr=False)

    @property
    def base(self) -> Path:
        """Directory that relative names are taken from."""
        return self.root if self.root.is_dir() else self.root.parent

    def label(self, p: Path) -> str:
        """A short name for ``p`` (relative to the root)."""
        if p == self.root:
            return p.name
        return p.relative_to(self.base).as_posix()

    def contains(self, p: Path) -> bool:
        """True if the resolved path ``p`` is the root or lies inside it (a file root allows only itself)."""
        if p == self.root:
            return True
        return self.root.is_dir() and self.root in p.parents

    def resolve(self, relative: str) -> Path:
        """The file ``relative`` (a name relative to the root) if it lies inside the root.

        Raises
        ------
        PermissionError
            For absolute names, ``..`` escapes, symbolic links out of the root
            and anything that is not an existing regular file.
        """
        rel = relative.replace("\\", "/")
        if rel.startswith("/") or "\x00" in rel or any(part == ".." for part in rel.split("/")):
            raise PermissionError(f"{relative!r}: outside the viewed path")
        p = (self.base / rel).resolve()
        if not self.contains(p) or not p.is_file():
            raise PermissionError(f"{relative!r}: not a file of the viewed path")
        return p

    def ground_truth_for(self, p: Path) -> Path | None:
        """The ground-truth mesh of a capture or reconstruction at ``p``, or None."""
        if self.ground_truth is not None:
            return self.ground_truth
        if p in self._index_meshes:
            return self._index_meshes[p]
        if not self.meshes:
            return None
        d = p if p.is_dir() else p.parent
        while True:
            here = sorted(m for m in self.meshes if m.parent == d)
            named = [m for m in here if m.stem.startswith("ground_truth")]
            if named or len(here) == 1:
                return (named or here)[0]
            if d == self.base or d == d.parent or not self.contains(d.parent):
                return None
            d = d.parent

    def recon_capture(self, p: Path) -> Path | None:
        """The capture a reconstruction directory was made from, if it is inside the root."""
        meta = p / "recon.json"
        try:
            src = json.loads(meta.read_text()).get("capture", {}).get("source")
        except (OSError, ValueError, AttributeError):
            return None
        if not src:
            return None
        return self._find_moved(Path(src), p)

    def _find_moved(self, recorded: Path, near: Path) -> Path | None:
        """A capture of the library at ``recorded`` (absolute, or relative to ``near``), or, when its
        directory was moved (the demo and datasets build under a temporary name), the capture whose path
        ends with the longest tail of ``recorded``."""
        cands = [recorded] if recorded.is_absolute() else [near / recorded, self.base / recorded]
        parts = recorded.parts
        cands += [self.base.joinpath(*parts[-k:]) for k in range(min(len(parts), 6), 0, -1)]
        for cand in cands:
            try:
                c = cand.resolve()
            except OSError:
                continue
            if c in self.captures:
                return c
        return None


def _is_stack(d: Path) -> bool:
    return (d / "manifest.json").is_file()


def discover(path, ground_truth=None) -> Library:
    """Find captures, reconstructions and meshes under ``path`` (see the module docstring).

    Raises
    ------
    UserInputError
        If ``path`` does not exist or holds nothing the viewer can show.
    """
    p = Path(path)
    if not p.exists():
        raise UserInputError(f"PATH {str(path)!r} does not exist (expected a capture, a y-tal .h5 file, "
                             "a recon output or a dataset directory)")
    root = p.resolve()
    gt = None
    if ground_truth is not None:
        gt = Path(ground_truth)
        if not gt.is_file() or gt.suffix.lower() not in MESH_SUFFIXES:
            raise UserInputError(f"--ground-truth {str(ground_truth)!r}: expected a mesh file "
                                 f"({', '.join(MESH_SUFFIXES)})")
        from recon.metrics import load_ground_truth

        load_ground_truth(gt)  # a mesh that cannot be read is refused now, not by a panel later
        gt = gt.resolve()
    lib = Library(root=root, ground_truth=gt)
    if root.is_file():
        if root.suffix.lower() not in HDF5_SUFFIXES:
            raise UserInputError(f"PATH {str(path)!r} is a file with suffix {root.suffix!r}: expected a y-tal "
                                 f"HDF5 file ({', '.join(HDF5_SUFFIXES)}) or a directory")
        from recon.capture import load_capture

        load_capture(root)  # refuse a truncated or foreign file now, not with a page that cannot show it
        lib.captures.append(root)
        return lib
    n = 0
    for dirpath, dirnames, filenames in os.walk(root, followlinks=False):
        d = Path(dirpath)
        depth = len(d.relative_to(root).parts)
        dirnames[:] = sorted(x for x in dirnames if not x.startswith(".") and x != "__pycache__")
        if depth >= MAX_DEPTH:
            dirnames[:] = []
        if "manifest.json" in filenames:
            lib.captures.append(d)
        if "volume.npz" in filenames:
            lib.recons.append(d)
        for f in filenames:
            suf = Path(f).suffix.lower()
            if suf in HDF5_SUFFIXES:
                lib.captures.append(d / f)
            elif suf in MESH_SUFFIXES and not ("volume.npz" in filenames and f == "surface.ply"):
                # (a reconstruction's own isosurface, recon/surface.py, is output, not ground truth)
                lib.meshes.append(d / f)
        n += 1
        if len(lib.captures) + len(lib.recons) >= MAX_ENTRIES:
            break
    lib.captures.sort()
    lib.recons.sort()
    lib.meshes.sort()
    _read_dataset_index(lib)
    if not lib.captures and not lib.recons:
        raise UserInputError(f"PATH {str(path)!r} holds no capture (manifest.json or .h5) and no reconstruction "
                             "(volume.npz) within {MAX_DEPTH} directory levels".replace("{MAX_DEPTH}", str(MAX_DEPTH)))
    return lib


def _read_dataset_index(lib: Library) -> None:
    """Map each dataset item's capture (and ideal capture) to its mesh (``index.jsonl``'s columns)."""
    idx = lib.base / "index.jsonl"
    if not idx.is_file():
        return
    for line in idx.read_text().splitlines():
        try:
            row = json.loads(line)
        except ValueError:
            continue
        mesh = row.get("mesh")
        if not mesh:
            continue
        m = (lib.base / mesh).resolve()
        if not lib.contains(m) or not m.is_file():
            continue
        for key in ("capture", "ideal"):
            if row.get(key):
                lib._index_meshes[(lib.base / row[key]).resolve()] = m


class CaptureData:
    """One capture opened for viewing: manifest facts, geometry and one laser spot's histograms at a time.

    NLOS captures (``array``, ``confocal``, y-tal HDF5) are opened with
    :func:`recon.load_capture` and keep their :class:`recon.Capture`
    (:attr:`capture`); camera captures (transient videos) are read as a plain
    stack and have ``capture = None`` (no wall geometry, no reconstruction).

    Only the spot on screen is held in memory (:meth:`spot` caches the last one).
    """

    def __init__(self, path: Path):
        from recon.capture import load_capture

        self.path = Path(path)
        self.capture = None
        if self.path.is_file():
            self.capture = load_capture(self.path)
            self.manifest = self.capture.manifest
        else:
            from transient_core.stack import read_manifest

            self.manifest = read_manifest(self.path)
            if self.manifest.get("capture") in ("array", "confocal"):
                self.capture = load_capture(self.path)
        m = self.manifest
        t = m["time"]
        self.t0_ps = float(t["t0_ps"])
        self.bin_width_ps = float(t["bin_width_ps"])
        self.n_bins = int(t["n_bins"])
        if self.capture is not None:
            self.n_files, self.height, self.width = self.capture.n_files, self.capture.height, self.capture.width
        else:
            self.n_files, self.height, self.width = int(m["n_files"]), int(m["height"]), int(m["width"])
        self.kind = m.get("kind", "ideal")
        self.mode = m.get("capture", "array")
        self.quantity = m.get("quantity") or ("counts" if self.kind == "counts" else "photons_per_pulse")
        self._cached: tuple[int, np.ndarray] | None = None

    # ------------------------------------------------------------------ data

    @property
    def times_ps(self) -> np.ndarray:
        """Bin centres, ps, shape ``(n_bins,)``."""
        return self.t0_ps + self.bin_width_ps * (np.arange(self.n_bins) + 0.5)

    def spot(self, j: int) -> np.ndarray:
        """Histograms of stored file ``j`` as float32, shape ``(H, W, n_bins)``."""
        j = int(j)
        if self._cached is not None and self._cached[0] == j:
            return self._cached[1]
        if self.capture is not None:
            arr = self.capture.spot(j)
        else:
            from transient_core.stack import read_intensity

            arr = read_intensity(self.path, j, self.manifest)
        arr = np.asarray(arr, dtype=np.float32)
        self._cached = (j, arr)
        return arr

    # -------------------------------------------------------------- geometry

    @property
    def has_wall(self) -> bool:
        """True for NLOS captures (pixel patches and laser spots on a relay wall)."""
        return self.capture is not None

    def wall_points(self, j: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """Wall-plane coordinates for drawing: ``(pixels[H, W, 2], spots[n, 2], active[k, 2], footprint_m)``.

        Points are projected on the wall's own axes (x along the wall's x, y
        completing the frame with its normal), metres. ``active`` is the laser
        spot(s) used by file ``j`` (all of them for a confocal capture).
        """
        cap = self.capture
        n = np.mean(cap.pixel_normals.reshape(-1, 3), axis=0)
        n = n / np.linalg.norm(n)
        ex = np.array([1.0, 0.0, 0.0]) - n * n[0]
        if np.linalg.norm(ex) < 1e-6:
            ex = np.array([0.0, 0.0, 1.0]) - n * n[2]
        ex /= np.linalg.norm(ex)
        ey = np.cross(n, ex)
        proj = lambda p: np.stack([p @ ex, p @ ey], axis=-1)  # noqa: E731
        px = proj(cap.pixel_centers)
        sp = proj(cap.spots)
        active = sp if cap.mode == "confocal" else sp[j:j + 1]
        dx, dy = cap.pixel_pitch_m()
        fp = (self.manifest.get("geometry") or {}).get("pixel_footprint_m") or min(dx, dy)
        return px, sp, active, float(fp)

    # ----------------------------------------------------------------- facts

    def facts(self) -> list[tuple[str, str]]:
        """Manifest facts for the page, ``(name, value with its unit)``."""
        m = self.manifest
        out = [
            ("capture", f"{self.mode} ({self.kind}, {self.quantity})"),
            ("files (laser spots)", str(self.n_files)),
            ("pixels (H x W)", f"{self.height} x {self.width}"),
            ("time bins", f"{self.n_bins} x {self.bin_width_ps:g} ps from t0 = {self.t0_ps:g} ps "
                          f"(to {self.t0_ps + self.n_bins * self.bin_width_ps:g} ps)"),
            ("bin width as path length", f"{self.bin_width_ps * 0.299792458:.4g} mm"),
        ]
        if "include_first_last" in m:
            out.append(("first/last segments in path", "included" if m["include_first_last"] else "excluded"))
        geo = m.get("geometry") or {}
        if geo.get("pixel_footprint_m"):
            out.append(("pixel footprint", f"{1e3 * float(geo['pixel_footprint_m']):.4g} mm"))
        for name in ("laser_origin", "detector_origin"):
            if geo.get(name) is not None:
                out.append((name.replace("_", " "), "(" + ", ".join(f"{v:.3f}" for v in geo[name]) + ") m"))
        laser = m.get("laser") or {}
        for key, unit, scale in (("wavelength_nm", "nm", 1), ("repetition_rate_hz", "MHz", 1e-6),
                                 ("average_power_w", "mW", 1e3), ("photons_per_pulse", "photons", 1)):
            if isinstance(laser.get(key), (int, float)):
                out.append((f"laser {key.rsplit('_', 1)[0].replace('_', ' ')}", f"{laser[key] * scale:.4g} {unit}"))
        det = m.get("detector") or {}
        if det:
            for key, unit in (("pulses", "pulses per spot"), ("pde", ""), ("jitter_ps", "ps FWHM"),
                              ("dark_count_rate_cps", "counts/s"), ("dead_time_ns", "ns")):
                if key in det and det[key] is not None:
                    out.append((f"detector {key.split('_')[0] if key != 'dark_count_rate_cps' else 'dark counts'}",
                                f"{det[key]:g} {unit}".strip()))
        ren = m.get("render") or {}
        for key, unit in (("spp", "samples per pixel"), ("seed", ""), ("render_time_s", "s")):
            if isinstance(ren.get(key), (int, float)):
                out.append((f"render {key.replace('_', ' ')}", f"{ren[key]:g} {unit}".strip()))
        if isinstance(m.get("scene"), dict) and m["scene"].get("file"):
            out.append(("scene", str(m["scene"]["file"])))
        return out

    # -------------------------------------------------------------- detector

    def ideal_source(self, lib: Library) -> "CaptureData | None":
        """The ideal capture (photons per pulse) for the detector panel: this one, or a counts capture's source."""
        if self.kind == "ideal" and self.quantity == "photons_per_pulse" and self.capture is not None:
            return self
        src = self.manifest.get("source_ideal")
        if self.kind != "counts" or not src or not self.path.is_dir():
            return None
        # The recorded path, else where it is after its directory moved (see Library._find_moved).
        p = lib._find_moved(Path(src), self.path)
        if p is None or p == self.path:
            return None
        other = CaptureData(p)
        if (other.kind == "ideal" and other.capture is not None and other.manifest["time"] == self.manifest["time"]
                and (other.n_files, other.height, other.width) == (self.n_files, self.height, self.width)):
            return other
        return None
