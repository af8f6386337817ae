"""The relay-wall frame shared by the ``spad_array`` sensor and the ``pulsed_laser``.

Pure numpy (no Mitsuba), so the geometry written to a capture's manifest and
the geometry used while rendering come from one place.

Conventions
-----------
The wall frame has its origin at a wall point ``target`` and three
orthonormal axes: the wall normal ``n`` (pointing into the hidden space, the
side where laser and detector are) and two in-plane axes ``ex``, ``ey``
with ``ex x ey = n``. ``ex`` is the world x axis projected into the wall
plane (the world y axis when the normal is along x), so for the default
wall in the plane z = 0 with normal (0, 0, 1): ``ex = (1, 0, 0)``,
``ey = (0, 1, 0)``.

Wall coordinates ``(u, v)`` of a point are its offsets along ``ex``, ``ey``
from ``target``, in metres. A regular grid of ``nx`` x ``ny`` cells of side
``spacing`` centred on ``target`` has cell ``(ix, iy)`` centred at
``u = (ix - (nx - 1) / 2) spacing``, ``v = (iy - (ny - 1) / 2) spacing``;
cell ``(0, 0)`` has the smallest wall coordinates. Row-major order
(``index = iy * nx + ix``) is the order of SPAD pixels in a file
(``[pixel_y, pixel_x]``) and the scan order of laser spots.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class WallFrame:
    """Orthonormal frame on the relay wall.

    Attributes
    ----------
    origin : ndarray (3,)
        World position of wall coordinates (0, 0), metres.
    normal, ex, ey : ndarray (3,)
        Unit wall normal and in-plane axes (``ex x ey = normal``).
    """

    origin: np.ndarray
    normal: np.ndarray
    ex: np.ndarray
    ey: np.ndarray

    @classmethod
    def from_normal(cls, origin, normal) -> "WallFrame":
        """Frame at ``origin`` with unit normal ``normal`` (any length > 0).

        Raises
        ------
        ValueError
            If ``normal`` has zero length.
        """
        o = np.asarray(origin, dtype=np.float64).reshape(3)
        n = np.asarray(normal, dtype=np.float64).reshape(3)
        length = float(np.linalg.norm(n))
        if not length > 0:
            raise ValueError(f"wall_normal={tuple(n)} must have non-zero length")
        n = n / length
        ref = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        ex = ref - np.dot(ref, n) * n
        ex /= np.linalg.norm(ex)
        ey = np.cross(n, ex)
        return cls(o, n, ex, ey)

    def to_world(self, u, v) -> np.ndarray:
        """World points of wall coordinates ``(u, v)`` (broadcast), shape ``(..., 3)``."""
        u = np.asarray(u, dtype=np.float64)[..., None]
        v = np.asarray(v, dtype=np.float64)[..., None]
        return self.origin + u * self.ex + v * self.ey

    def to_wall(self, points) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Wall coordinates ``(u, v)`` and signed height ``h`` (along the normal) of world points."""
        d = np.asarray(points, dtype=np.float64) - self.origin
        return d @ self.ex, d @ self.ey, d @ self.normal

    def height(self, point) -> float:
        """Signed distance of ``point`` from the wall plane (> 0: hidden-space side)."""
        return float((np.asarray(point, dtype=np.float64) - self.origin) @ self.normal)

    def grid(self, nx: int, ny: int, spacing: float) -> np.ndarray:
        """Centres of an ``nx`` x ``ny`` grid (row-major), shape ``(ny, nx, 3)``."""
        u = (np.arange(nx, dtype=np.float64) - (nx - 1) / 2.0) * spacing
        v = (np.arange(ny, dtype=np.float64) - (ny - 1) / 2.0) * spacing
        vv, uu = np.meshgrid(v, u, indexing="ij")
        return self.to_world(uu, vv)

    def grid_corners(self, nx: int, ny: int, spacing: float, shrink: float = 0.0) -> np.ndarray:
        """Corners of every cell of the grid, pulled ``shrink`` (fraction of a cell) inwards.

        Returns shape ``(ny, nx, 4, 3)``.
        """
        c = self.grid(nx, ny, spacing)
        h = 0.5 * spacing * (1.0 - 2.0 * shrink)
        offs = np.array([[-h, -h], [h, -h], [h, h], [-h, h]])
        return c[:, :, None, :] + offs[:, 0, None] * self.ex + offs[:, 1, None] * self.ey

    def cell_of(self, points, nx: int, ny: int, spacing: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Grid cell ``(ix, iy)`` containing each point's projection, and whether it is inside the grid."""
        u, v, _ = self.to_wall(points)
        ix = np.floor(u / spacing + nx / 2.0).astype(np.int64)
        iy = np.floor(v / spacing + ny / 2.0).astype(np.int64)
        inside = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
        return ix, iy, inside

    def as_dict(self) -> dict:
        return {"origin": self.origin.tolist(), "normal": self.normal.tolist(),
                "ex": self.ex.tolist(), "ey": self.ey.tolist()}


def ray_plane_point(origin, through, frame: WallFrame) -> np.ndarray:
    """Where the ray from ``origin`` through ``through`` meets the wall plane (broadcast)."""
    o = np.asarray(origin, dtype=np.float64)
    d = np.asarray(through, dtype=np.float64) - o
    denom = d @ frame.normal
    t = ((frame.origin - o) @ frame.normal) / np.where(denom == 0, np.nan, denom)
    return o + t[..., None] * d
