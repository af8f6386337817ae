"""Voxel grids for reconstructions: bounds, voxel centres, defaults from a capture.

Volumes are ``[z, y, x]`` arrays; :class:`VoxelGrid` holds the voxel-centre
coordinates ``x_m``, ``y_m``, ``z_m`` (metres, increasing). Bounds are the
outer faces of the voxel block: ``(xmin, xmax, ymin, ymax, zmin, zmax)``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Sequence

import numpy as np

from transient_core.errors import UserInputError

__all__ = ["VoxelGrid", "make_grid", "default_bounds", "parse_bounds", "reachable_depth_m"]

DEFAULT_VOXELS = 64


@dataclasses.dataclass(frozen=True, eq=False)
class VoxelGrid:
    """A regular voxel grid.

    Attributes
    ----------
    x_m, y_m, z_m : ndarray
        Voxel-centre coordinates along each axis, metres (increasing).
    """

    x_m: np.ndarray
    y_m: np.ndarray
    z_m: np.ndarray

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(nz, ny, nx)``: the shape of a volume on this grid."""
        return (len(self.z_m), len(self.y_m), len(self.x_m))

    @property
    def voxel_size_m(self) -> tuple[float, float, float]:
        """``(dx, dy, dz)``, metres."""
        return tuple(float(_step(a)) for a in (self.x_m, self.y_m, self.z_m))  # type: ignore[return-value]

    @property
    def bounds(self) -> tuple[float, ...]:
        """Outer faces ``(xmin, xmax, ymin, ymax, zmin, zmax)``, metres."""
        out = []
        for a in (self.x_m, self.y_m, self.z_m):
            h = _step(a) / 2
            out += [float(a[0] - h), float(a[-1] + h)]
        return tuple(out)

    def centers(self) -> np.ndarray:
        """All voxel centres, shape ``(nz, ny, nx, 3)`` (x, y, z)."""
        Z, Y, X = np.meshgrid(self.z_m, self.y_m, self.x_m, indexing="ij")
        return np.stack([X, Y, Z], axis=-1)

    @classmethod
    def from_bounds(cls, bounds: Sequence[float], voxels: int | Sequence[int] | None = None,
                    voxel_size_m: float | None = None) -> "VoxelGrid":
        """Grid filling ``bounds`` with ``voxels`` per axis or cubic voxels of ``voxel_size_m``.

        With ``voxels=N`` each axis gets N voxels (voxel sizes may differ per
        axis); ``voxels=(nx, ny, nz)`` sets each axis. With ``voxel_size_m=s``
        each axis gets ``ceil(extent / s)`` voxels of side ``s`` and its upper
        bound moves up to a whole number of voxels.
        """
        b = _check_bounds(bounds)
        if voxels is not None and voxel_size_m is not None:
            raise UserInputError("give either voxels or voxel_size_m, not both")
        axes = []
        if voxel_size_m is not None:
            s = float(voxel_size_m)
            if not s > 0 or not math.isfinite(s):
                raise UserInputError(f"voxel_size_m={voxel_size_m!r} must be a positive number (metres)")
            for i in range(3):
                lo, hi = b[2 * i], b[2 * i + 1]
                n = max(1, int(math.ceil((hi - lo) / s - 1e-9)))
                axes.append(lo + (np.arange(n) + 0.5) * s)
        else:
            n3 = _voxel_counts(DEFAULT_VOXELS if voxels is None else voxels)
            for i in range(3):
                lo, hi = b[2 * i], b[2 * i + 1]
                n = n3[i]
                axes.append(lo + (np.arange(n) + 0.5) * (hi - lo) / n)
        n_total = len(axes[0]) * len(axes[1]) * len(axes[2])
        if n_total > 1024 ** 3:
            raise UserInputError(f"the grid would have {n_total} voxels (more than 1024^3): use fewer voxels")
        return cls(*axes)


def _step(a: np.ndarray) -> float:
    return float(a[1] - a[0]) if len(a) > 1 else float("nan")


def _voxel_counts(voxels) -> tuple[int, int, int]:
    if np.isscalar(voxels):
        v = (voxels,) * 3
    else:
        v = tuple(voxels)
    if len(v) != 3 or any((not isinstance(n, (int, np.integer))) or isinstance(n, bool) or n < 1 for n in v):
        raise UserInputError(f"voxels={voxels!r}: expected a positive integer or three (nx, ny, nz)")
    return tuple(int(n) for n in v)  # type: ignore[return-value]


def _check_bounds(bounds) -> tuple[float, ...]:
    try:
        b = tuple(float(v) for v in bounds)
    except (TypeError, ValueError):
        raise UserInputError(f"bounds={bounds!r}: expected 6 numbers xmin,xmax,ymin,ymax,zmin,zmax (metres)") from None
    if len(b) != 6 or not all(math.isfinite(v) for v in b):
        raise UserInputError(f"bounds={bounds!r}: expected 6 finite numbers xmin,xmax,ymin,ymax,zmin,zmax (metres)")
    for i, ax in enumerate("xyz"):
        if not b[2 * i] < b[2 * i + 1]:
            raise UserInputError(f"bounds: {ax}min={b[2 * i]:g} must be smaller than {ax}max={b[2 * i + 1]:g}")
    return b


def parse_bounds(text: str) -> tuple[float, ...]:
    """Parse ``"xmin,xmax,ymin,ymax,zmin,zmax"`` (metres)."""
    parts = [p for p in str(text).replace(" ", "").split(",") if p != ""]
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        raise UserInputError(f"--bounds {text!r}: expected 6 comma-separated numbers xmin,xmax,ymin,ymax,zmin,zmax (metres)") from None
    if len(vals) != 6:
        raise UserInputError(f"--bounds {text!r}: got {len(vals)} numbers, expected 6 (xmin,xmax,ymin,ymax,zmin,zmax)")
    return _check_bounds(vals)


def _path_range_m(capture) -> tuple[float, float]:
    """Smallest and largest three-bounce path length (|S-o|+|o-P|) the time axis can hold, metres."""
    offs = [capture.path_offsets_m(j) for j in range(capture.n_files)] if capture.include_first_last else [np.zeros(1)]
    off_min = min(float(o.min()) for o in offs)
    off_max = max(float(o.max()) for o in offs)
    lo = capture.t0_m - off_max
    hi = capture.t0_m + capture.n_bins * capture.bin_width_m - off_min
    return lo, hi


def reachable_depth_m(capture) -> float:
    """Largest depth z a reflector in front of the wall can have and still arrive within the time axis.

    Any point at depth ``z`` has ``|S - o| + |o - P| >= 2 z`` for wall points
    in the plane z = 0, so ``z <= L_max / 2`` with ``L_max`` the longest
    three-bounce path the time axis holds.
    """
    return max(0.0, _path_range_m(capture)[1] / 2)


def default_bounds(capture) -> tuple[float, ...]:
    """Hidden volume in front of the relay wall that the capture can see.

    x and y span the wall area seen by the pixels (patch centres plus half a
    patch); z spans from the smallest depth whose paths can reach the first
    bin (0 unless the time axis starts late) to the deepest point the time
    axis can hold (:func:`reachable_depth_m`).

    Raises
    ------
    UserInputError
        If the wall is not the plane z = 0 with normal +z (give bounds
        explicitly) or the time axis holds no three-bounce path at all.
    """
    if not capture.wall_is_z0(atol=1e-4):
        raise UserInputError("the relay wall of this capture is not the plane z = 0 with normal +z: "
                             "default bounds are undefined, give --bounds xmin,xmax,ymin,ymax,zmin,zmax")
    P = capture.pixel_centers
    dx, dy = capture.pixel_pitch_m()
    hx = dx / 2 if math.isfinite(dx) else 0.05
    hy = dy / 2 if math.isfinite(dy) else 0.05
    xmin, xmax = float(P[..., 0].min() - hx), float(P[..., 0].max() + hx)
    ymin, ymax = float(P[..., 1].min() - hy), float(P[..., 1].max() + hy)
    lo, hi = _path_range_m(capture)
    z_hi = hi / 2
    if not z_hi > 0:
        raise UserInputError(f"the time axis ({capture.t0_ps:g} ps + {capture.n_bins} x {capture.bin_width_ps:g} ps) "
                             "ends before any three-bounce path from the hidden space could arrive")
    # Largest lateral distance between a wall point used and a voxel column.
    wall = np.concatenate([P.reshape(-1, 3), capture.spots])
    corners = np.array([[x, y] for x in (xmin, xmax) for y in (ymin, ymax)])
    D = float(np.max(np.linalg.norm(wall[:, None, :2] - corners[None], axis=-1)))
    z_lo = math.sqrt(max(0.0, (lo / 2) ** 2 - D ** 2)) if lo > 0 else 0.0
    if z_lo >= z_hi:
        z_lo = 0.0
    return (xmin, xmax, ymin, ymax, z_lo, z_hi)


def make_grid(capture, bounds: Sequence[float] | None = None, voxels: int | Sequence[int] | None = None,
              voxel_size_m: float | None = None) -> VoxelGrid:
    """Voxel grid for reconstructing ``capture``; checks the bounds against the hidden space.

    Parameters
    ----------
    capture : Capture
    bounds : 6 floats, optional
        ``(xmin, xmax, ymin, ymax, zmin, zmax)``, metres; default
        :func:`default_bounds`.
    voxels : int or (nx, ny, nz), optional
        Voxels per axis (default 64 when neither this nor ``voxel_size_m`` is given).
    voxel_size_m : float, optional
        Cubic voxel side, metres.

    Raises
    ------
    UserInputError
        If the bounds lie behind the relay wall (z <= 0 for a wall in the plane
        z = 0) or beyond the depth the time axis can reach.
    """
    if bounds is None:
        b = default_bounds(capture)
    else:
        b = _check_bounds(bounds)
        if capture.wall_is_z0(atol=1e-4):
            if b[5] <= 0:
                raise UserInputError(
                    f"bounds z range [{b[4]:g}, {b[5]:g}] m lies behind the relay wall: the hidden space is z > 0 "
                    "(the wall is the plane z = 0)")
            if b[4] < 0:
                raise UserInputError(
                    f"bounds zmin={b[4]:g} m is behind the relay wall: the hidden space is z > 0; use zmin >= 0")
            zr = reachable_depth_m(capture)
            if b[4] >= zr:
                raise UserInputError(
                    f"bounds zmin={b[4]:g} m is deeper than the time axis can see (paths end at depth {zr:.4g} m): "
                    "lower zmin or use a capture with a longer time axis")
    return VoxelGrid.from_bounds(b, voxels=voxels, voxel_size_m=voxel_size_m)
