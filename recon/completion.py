"""Shape completion behind the visible surface: a stated prior, not a measurement.

Three-bounce NLOS light only reaches surface the relay wall sees, so every
method reconstructs the *front* of a hidden object; its back is not in the
data. Scored against a whole mesh, even a perfect front-surface
reconstruction keeps a completeness of about half the object's thickness
(``bench/front_surface_limit.py``). This module closes the surface behind the
front under an explicit assumption, for users who need a closed 3-D shape
(and who must read the result as such):

**Elliptical cross-sections.** Seen from the wall, the object's silhouette
is a union of inscribed disks. A column at distance ``d`` from the
silhouette's edge lies in the largest inscribed disk that contains it, of
radius ``R`` (the *local thickness* of Hildebrand & Ruegsegger 1997: the
radius of the largest ball inside the shape containing the point), at
lateral offset ``u = R - d`` from that disk's centre. The object there is
taken to be an ellipse with lateral semi-axis ``R`` and depth semi-axis
``a R`` (``a``: the *aspect*), whose front is the reconstructed front
depth, so the back lies ``2 a sqrt(R^2 - u^2)`` behind the front.

**The aspect** is either given (``1``: round cross-sections, as limbs are)
or estimated from the front itself (``"auto"``): an ellipse's front recedes
from its nearest point by ``a R (1 - sqrt(1 - (u/R)^2))``; ``a`` is the
least-squares slope of the front's measured recession against
``R (1 - sqrt(1 - (u/R)^2))`` over columns with ``0.4 < u/R < 0.95`` (where
the recession is large enough to measure and the front not yet vertical),
clipped to ``[0, 2]``. One aspect per connected part of the silhouette. From an
exact front the estimate is biased high by the columns' discretisation: disks
are centred on columns, so ``R`` falls short by up to half a column diagonal
(measured on spheroids: +10 % at 12 columns of radius, +26 % at 8). From a
reconstructed front it is a heuristic: the reconstruction's blur flattens the
front near the silhouette (the recession is underestimated) and dilates the
silhouette; on known cylinders and spheroids behind the paper's wall its errors
run both ways by tens of per cent (``bench/completion_aspect.py``, docs/recon.md).
Give the aspect when it is known.

The front depth per column is the z of the column's maximum of ``volume``,
refined to sub-voxel precision by a parabola through it and its two
neighbours along z (clipped to half a voxel).

Output: the voxels the closed surface passes through
(:func:`rasterise_height`): the front (the height field through each
column's refined maximum), the back, and the side walls at the silhouette's
edge columns (4-connected), from front to back. Voxels the reconstruction
kept keep their values, new ones get half its smallest kept value (so the depth
map, the column's maximum, is unchanged); kept voxels off the surface (the
filter's blur around the front) are dropped, and counted.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from transient_core.errors import UserInputError
from .result import Reconstruction

__all__ = ["complete_surface", "check_aspect", "rasterise_height", "local_thickness", "front_depth", "estimate_aspect", "ASPECT_WINDOW"]

#: Range of ``u / R`` whose front recession estimates the aspect (see the module docstring).
ASPECT_WINDOW = (0.4, 0.95)
#: Allowed aspects (depth semi-axis over lateral semi-axis).
ASPECT_RANGE = (0.0, 2.0)


@njit(cache=True, nogil=True)
def _paint_disks(dist, dy, dx, radius, centre):  # pragma: no cover - compiled
    """For each inside column q (dist > 0), paint the disk of radius dist[q] around q with max radius.

    dist : (ny, nx) float64, distance to the silhouette's edge (0 outside), metres
    radius : (ny, nx) float64, in/out: largest inscribed-disk radius containing each column
    centre : (ny, nx, 2) int64, in/out: that disk's centre (row, column)
    """
    ny, nx = dist.shape
    for qy in range(ny):
        for qx in range(nx):
            r = dist[qy, qx]
            if r <= 0.0:
                continue
            reach = r + 0.5 * min(dx, dy)
            ky = int(math.ceil(reach / dy))
            kx = int(math.ceil(reach / dx))
            for py in range(max(0, qy - ky), min(ny, qy + ky + 1)):
                for px in range(max(0, qx - kx), min(nx, qx + kx + 1)):
                    if dist[py, px] <= 0.0 or radius[py, px] >= r:
                        continue
                    ey = (py - qy) * dy
                    ex = (px - qx) * dx
                    if ey * ey + ex * ex <= reach * reach:
                        radius[py, px] = r
                        centre[py, px, 0] = qy
                        centre[py, px, 1] = qx


def local_thickness(silhouette: np.ndarray, dy: float, dx: float):
    """Distance to the edge, local thickness radius and its disk's centre for each column of a silhouette.

    Parameters
    ----------
    silhouette : ndarray of bool, shape (ny, nx), axes [y, x]
    dy, dx : float
        Column spacing, metres.

    Returns
    -------
    dist : ndarray (ny, nx), metres
        Distance from each inside column's centre to the silhouette's edge
        (Euclidean distance to the nearest outside column's centre, less half
        a column), 0 outside.
    radius : ndarray (ny, nx), metres
        ``R``: radius of the largest inscribed disk (centred on a column,
        radius its ``dist``) containing the column; 0 outside.
    centre : ndarray (ny, nx, 2) of int
        Row and column index of that disk's centre.
    """
    from scipy.ndimage import distance_transform_edt

    sil = np.asarray(silhouette, dtype=bool)
    dist = distance_transform_edt(sil, sampling=(dy, dx)) - 0.5 * min(dx, dy)
    dist = np.where(sil, np.maximum(dist, 0.5 * min(dx, dy)), 0.0)
    radius = dist.copy()
    centre = np.stack(np.indices(sil.shape), axis=-1).astype(np.int64)
    _paint_disks(dist, float(dy), float(dx), radius, centre)
    return dist, radius, centre


def front_depth(volume: np.ndarray, z_m: np.ndarray) -> np.ndarray:
    """Sub-voxel front depth per column (metres, NaN where the column has no occupied voxel).

    The z of the column's maximum of ``volume`` (``[z, y, x]``, occupied where
    > 0), moved by the vertex of the parabola through it and its two
    neighbours along z (at most half a voxel).
    """
    vol = np.asarray(volume, dtype=np.float64)
    occ = vol > 0
    sil = occ.any(axis=0)
    nz = vol.shape[0]
    z_m = np.asarray(z_m, dtype=np.float64)
    k = np.argmax(np.where(occ, vol, -np.inf), axis=0)
    if nz < 3:
        return np.where(sil, z_m[k], np.nan)
    kc = np.clip(k, 1, nz - 2)
    iy, ix = np.indices(k.shape)
    a, b, c = vol[kc - 1, iy, ix], vol[kc, iy, ix], vol[kc + 1, iy, ix]
    den = a - 2 * b + c
    with np.errstate(divide="ignore", invalid="ignore"):
        off = np.where((k == kc) & (den < 0), 0.5 * (a - c) / den, 0.0)
    off = np.clip(np.nan_to_num(off), -0.5, 0.5)
    dz = z_m[1] - z_m[0]
    return np.where(sil, z_m[k] + off * dz, np.nan)


def estimate_aspect(front_m: np.ndarray, radius: np.ndarray, dist: np.ndarray, centre: np.ndarray,
                    mask: np.ndarray) -> float | None:
    """Least-squares aspect of the elliptical cross-sections over ``mask`` (see the module docstring).

    Returns None when fewer than 3 columns fall in :data:`ASPECT_WINDOW`.
    """
    u = np.clip(radius - dist, 0.0, None)
    s = np.where(radius > 0, u / np.where(radius > 0, radius, 1.0), 0.0)
    use = mask & (s > ASPECT_WINDOW[0]) & (s < ASPECT_WINDOW[1])
    if np.count_nonzero(use) < 3:
        return None
    x = (radius * (1.0 - np.sqrt(np.clip(1.0 - s * s, 0.0, 1.0))))[use]
    recession = (front_m - front_m[centre[..., 0], centre[..., 1]])[use]
    den = float(np.sum(x * x))
    if den <= 0:
        return None
    return float(np.clip(np.sum(x * recession) / den, *ASPECT_RANGE))


def rasterise_height(height_m: np.ndarray, columns: np.ndarray, z_m: np.ndarray) -> np.ndarray:
    """Voxels ``[z, y, x]`` that a height field passes through over each column's footprint.

    Over a column's square footprint the surface runs from its centre value to
    the midpoints with its eight neighbours (those in ``columns``; the centre
    value toward the others), so a column's voxels are those whose z interval
    meets ``[min, max]`` of these values: a continuous surface leaves no gaps
    between neighbouring columns however steep it is.

    height_m : (ny, nx) metres; columns : (ny, nx) bool; z_m : (nz,) voxel centres (regular)
    """
    h = np.asarray(height_m, dtype=np.float64)
    cols = np.asarray(columns, dtype=bool)
    lo, hi = h.copy(), h.copy()
    pad_h = np.pad(h, 1, mode="edge")
    pad_c = np.pad(cols, 1, constant_values=False)
    ny, nx = h.shape
    for sy in (-1, 0, 1):
        for sx in (-1, 0, 1):
            if sy == 0 and sx == 0:
                continue
            nh = pad_h[1 + sy:1 + sy + ny, 1 + sx:1 + sx + nx]
            nc = pad_c[1 + sy:1 + sy + ny, 1 + sx:1 + sx + nx]
            mid = np.where(nc, 0.5 * (h + nh), h)
            np.minimum(lo, mid, out=lo)
            np.maximum(hi, mid, out=hi)
    z = np.asarray(z_m, dtype=np.float64)[:, None, None]
    half = 0.5 * (z_m[1] - z_m[0]) if len(z_m) > 1 else np.inf
    return cols[None] & (z + half > lo[None]) & (z - half <= hi[None])


def check_aspect(aspect) -> float | None:
    """The aspect as a float, or None for ``"auto"``; one-line refusal of anything else."""
    if isinstance(aspect, str) and aspect.strip() == "auto":
        return None
    if isinstance(aspect, bool):
        aspect = str(aspect)
    try:
        a = float(aspect)
    except (TypeError, ValueError):
        raise UserInputError(f"--complete {aspect!r}: allowed 'auto' or an aspect between 0 and 2 (1: round)") from None
    if not (math.isfinite(a) and ASPECT_RANGE[0] <= a <= ASPECT_RANGE[1]):
        raise UserInputError(f"--complete {aspect!r}: the aspect must lie in [0, 2] (1: round cross-sections)")
    return a


def complete_surface(rec: Reconstruction, aspect: float | str = "auto") -> Reconstruction:
    """Close the reconstructed front surface behind itself (elliptical cross-sections; see the module docstring).

    Parameters
    ----------
    rec : Reconstruction
        A filtered reconstruction (occupied voxels: ``volume > 0``).
    aspect : float or "auto"
        Depth over lateral semi-axis of the assumed cross-sections, in
        ``[0, 2]`` (``1``: round); ``"auto"`` estimates one per connected part of
        the silhouette from the front's recession (round where it cannot).

    Returns
    -------
    Reconstruction
        Same ``raw`` and grid; ``volume`` holds the voxels of the closed surface;
        ``params["completion"]`` records the aspects, the columns and the voxels added and dropped.
    """
    from scipy import ndimage as ndi

    a_given = check_aspect(aspect)
    auto = a_given is None
    g = rec.grid
    vol = np.asarray(rec.volume, dtype=np.float32)
    occ = vol > 0
    sil = occ.any(axis=0)
    dx, dy, dz = g.voxel_size_m
    params = {"prior": "elliptical cross-sections", "aspect_requested": "auto" if auto else a_given}
    if not sil.any():
        out = Reconstruction(raw=rec.raw, grid=g, method=rec.method, params={**rec.params, "completion": {
            **params, "aspects": [], "added_voxels": 0, "dropped_voxels": 0}}, volume=vol.copy(),
            filter=dict(rec.filter))
        return out
    front = front_depth(vol, g.z_m)
    dist, radius, centre = local_thickness(sil, dy, dx)
    labels, n_parts = ndi.label(sil)
    aspect_map = np.zeros(sil.shape)
    aspects = []
    for i in range(1, n_parts + 1):
        part = labels == i
        a = estimate_aspect(np.nan_to_num(front), radius, dist, centre, part) if auto else a_given
        a = 1.0 if a is None else a
        aspect_map[part] = a
        aspects.append({"part": i, "columns": int(np.count_nonzero(part)), "aspect": a})
    half = np.sqrt(np.maximum(radius ** 2 - (radius - dist) ** 2, 0.0))
    front = np.where(sil, front, 0.0)
    back = front + 2.0 * aspect_map * half
    z = np.asarray(g.z_m)[:, None, None]
    edge = sil & ~ndi.binary_erosion(sil, structure=ndi.generate_binary_structure(2, 1), border_value=0)
    walls = edge[None] & (z + dz / 2 > front[None]) & (z - dz / 2 <= back[None])
    shell = rasterise_height(front, sil, g.z_m) | rasterise_height(back, sil, g.z_m) | walls
    fill = 0.5 * float(vol[occ].min())   # below every kept value: the column's maximum stays where it was
    completed = np.where(shell, np.where(occ, vol, fill), 0.0).astype(np.float32)
    params.update({"aspects": aspects, "added_voxels": int(np.count_nonzero(shell & ~occ)),
                   "dropped_voxels": int(np.count_nonzero(occ & ~shell)),
                   "max_thickness_m": float(np.max(np.where(sil, back - front, 0.0)))})
    return Reconstruction(raw=rec.raw, grid=g, method=rec.method, params={**rec.params, "completion": params},
                          volume=completed, filter=dict(rec.filter))
