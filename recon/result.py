"""The result of a reconstruction: raw and filtered volumes on a voxel grid."""

from __future__ import annotations

import dataclasses

import numpy as np

from .grid import VoxelGrid

__all__ = ["Reconstruction"]


@dataclasses.dataclass(eq=False)
class Reconstruction:
    """A reconstructed volume.

    Attributes
    ----------
    raw : ndarray, float32, shape (nz, ny, nx)
        The algorithm's output (e.g. the backprojection confidence map C).
    grid : VoxelGrid
        Voxel-centre coordinates ``x_m``, ``y_m``, ``z_m``.
    method : str
        ``bp``, ``fbp``, ``lct``, ``fk`` or ``phasor``.
    params : dict
        Parameters the method used (JSON-serialisable).
    volume : ndarray, float32, shape (nz, ny, nx)
        Filtered (and thresholded) volume; equals ``raw`` until a filter is applied.
    filter : dict
        How ``volume`` was obtained from ``raw`` (``{"name": "none"}`` by default).
    """

    raw: np.ndarray
    grid: VoxelGrid
    method: str
    params: dict = dataclasses.field(default_factory=dict)
    volume: np.ndarray | None = None
    filter: dict = dataclasses.field(default_factory=lambda: {"name": "none"})

    def __post_init__(self):
        self.raw = np.ascontiguousarray(self.raw, dtype=np.float32)
        if self.raw.shape != self.grid.shape:
            raise ValueError(f"raw has shape {self.raw.shape}, grid has {self.grid.shape}")
        if self.volume is None:
            self.volume = self.raw
        self.volume = np.ascontiguousarray(self.volume, dtype=np.float32)

    @property
    def x_m(self) -> np.ndarray:
        return self.grid.x_m

    @property
    def y_m(self) -> np.ndarray:
        return self.grid.y_m

    @property
    def z_m(self) -> np.ndarray:
        return self.grid.z_m

    def argmax_m(self, which: str = "volume") -> np.ndarray:
        """Position (x, y, z) in metres of the voxel with the largest value of ``volume`` or ``raw``."""
        v = self.volume if which == "volume" else self.raw
        iz, iy, ix = np.unravel_index(int(np.argmax(v)), v.shape)
        return np.array([self.x_m[ix], self.y_m[iy], self.z_m[iz]])
