"""Quality metrics of a reconstruction against ground truth (a mesh, or point targets).

Definitions (all distances in metres; "occupied" voxels are those with
``volume > 0``, i.e. kept by the filter's threshold):

``chamfer_m``
    Symmetric Chamfer distance ``(accuracy_m + completeness_m) / 2``, where
    ``accuracy_m`` is the mean distance from each occupied voxel centre to the
    mesh surface and ``completeness_m`` the mean distance from the mesh
    surface (the part inside the reconstruction bounds) to the nearest
    occupied voxel centre. The surface is represented by area-uniform samples
    (spacing at most a quarter of the smallest voxel side, seeded), so both
    terms carry a discretisation error below that spacing.
``depth_mae_m``, ``depth_rmse_m``
    Per voxel column (x_m, y_m), the ground-truth depth is the first hit of
    the line from the wall along +z with the mesh (NaN if it misses or the
    hit lies outside the z bounds);
    the reconstructed depth is the z of the column's maximum of ``volume``.
    Mean absolute and root-mean-square difference over columns where both
    exist. ``depth_coverage`` is the fraction of ground-truth columns that
    have a reconstructed depth, ``depth_false_columns`` the fraction of
    reconstructed columns without ground truth.
``iou``
    Occupancy intersection over union: occupied voxels vs the voxels that
    contain mesh surface samples.
``visible_accuracy_m``, ``visible_completeness_m``, ``visible_chamfer_m``
    The same distances against the *visible* surface only: the first hits of
    lines along +z from the wall (:func:`recon.ground_truth.ground_truth_depth_map`)
    on an (x, y) grid four times finer than the voxels, inside the bounds.
    Three-bounce light only comes from surface the relay wall sees, so no
    NLOS method can place voxels on a body's back; the whole-mesh
    ``completeness_m`` of even a perfect front-surface reconstruction is
    about half the object's thickness. (The visible surface is sampled per
    projected area: steep parts count less than in ``completeness_m``.)
``visible_iou``
    Occupancy intersection over union against the voxels that contain
    points of the visible surface (the points of ``visible_chamfer_m``): 1
    for a reconstruction holding exactly the voxels the visible surface passes
    through (on steep parts, several per column).
``silhouette_iou``
    Intersection over union of the columns ``[y, x]`` holding any occupied
    voxel and the columns whose line along +z meets the mesh inside the z
    bounds (the front view a person reads a letter from).
``normal_error_deg``, ``normal_error_median_deg``
    Mean and median angle between the normal maps
    (:func:`recon.surface.normal_map`) of the reconstructed and the
    ground-truth depth maps, over columns where both are defined.
``surface_accuracy_m``, ``surface_completeness_m``, ``surface_chamfer_m``, ``surface_faces``
    Distances between the vertices of the isosurface of ``volume``
    (:func:`recon.surface.reconstruction_surface`) and the mesh samples.
``localisation_error_m`` (point targets)
    Point targets are given as points, or are the mesh's connected
    components smaller than two voxel diagonals (their centroids). The
    strongest local maxima of ``volume`` (one per target, 3x3x3
    non-maximum suppression) are matched to the targets by minimum total
    distance (Hungarian assignment); the error of each target is its
    distance to its matched maximum. ``localisation_error_m`` is the mean
    over matched targets; a target without a maximum (the threshold removed
    it) has error ``null`` and is not counted in ``n_found``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from transient_core.errors import UserInputError
from .grid import VoxelGrid
from .result import Reconstruction

__all__ = ["load_ground_truth", "compute_metrics", "mesh_depth_map", "mesh_occupancy", "localisation_errors",
           "chamfer", "visible_surface_points"]

_MAX_SAMPLES = 4_000_000


class GroundTruth:
    """A mesh (``trimesh.Trimesh``) and/or point targets ``(n, 3)``."""

    def __init__(self, mesh=None, points: np.ndarray | None = None, source: str | None = None):
        self.mesh = mesh
        self.points = None if points is None else np.asarray(points, dtype=np.float64).reshape(-1, 3)
        self.source = source


def load_ground_truth(path: str | Path) -> GroundTruth:
    """Load a ground-truth mesh (any format trimesh reads: .obj, .ply, .stl, .off, .glb)
    or point targets (.json list of [x, y, z], .npy (n, 3), .csv/.txt with 3 columns)."""
    p = Path(path)
    if not p.is_file():
        raise UserInputError(f"--ground-truth {str(p)!r} does not exist or is not a file")
    suf = p.suffix.lower()
    try:
        if suf == ".json":
            data = json.loads(p.read_text())
            if isinstance(data, dict):
                data = data.get("points")
            return GroundTruth(points=_points(data, p), source=str(p))
        if suf == ".npy":
            return GroundTruth(points=_points(np.load(p), p), source=str(p))
        if suf in (".csv", ".txt", ".xyz"):
            return GroundTruth(points=_points(np.loadtxt(p, delimiter="," if suf == ".csv" else None, ndmin=2), p),
                               source=str(p))
    except (ValueError, OSError) as e:
        raise UserInputError(f"--ground-truth {str(p)!r}: cannot read points ({e})") from None
    import trimesh

    try:
        mesh = trimesh.load(p, force="mesh", process=False)
    except Exception as e:  # trimesh raises many types
        raise UserInputError(f"--ground-truth {str(p)!r}: not a mesh trimesh can read ({e})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise UserInputError(f"--ground-truth {str(p)!r}: contains no triangles")
    return GroundTruth(mesh=mesh, source=str(p))


def _points(data, p) -> np.ndarray:
    a = np.asarray(data, dtype=np.float64)
    if a.ndim == 1 and a.size == 3:
        a = a[None]
    if a.ndim != 2 or a.shape[1] != 3 or a.shape[0] < 1 or not np.all(np.isfinite(a)):
        raise UserInputError(f"--ground-truth {str(p)!r}: expected points of shape (n, 3), got {a.shape}")
    return a


# ------------------------------------------------------------------ mesh helpers


def _samples(mesh, grid: VoxelGrid, seed: int) -> np.ndarray:
    """Area-uniform surface samples, spacing <= min voxel side / 4, inside the grid bounds."""
    import trimesh

    spacing = min(grid.voxel_size_m) / 4
    n = int(min(_MAX_SAMPLES, max(1000, math.ceil(mesh.area / spacing ** 2))))
    pts, _ = trimesh.sample.sample_surface(mesh, n, seed=seed)
    b = np.array(grid.bounds).reshape(3, 2)
    inside = np.all((pts >= b[:, 0]) & (pts <= b[:, 1]), axis=1)
    return pts[inside]


def mesh_occupancy(mesh, grid: VoxelGrid, seed: int = 0, samples: np.ndarray | None = None) -> np.ndarray:
    """Boolean ``[z, y, x]``: voxels containing mesh surface samples."""
    pts = _samples(mesh, grid, seed) if samples is None else samples
    occ = np.zeros(grid.shape, dtype=bool)
    if len(pts) == 0:
        return occ
    idx = []
    for axis, coord in ((2, grid.z_m), (1, grid.y_m), (0, grid.x_m)):
        d = coord[1] - coord[0] if len(coord) > 1 else 1.0
        lo = coord[0] - d / 2
        idx.append(np.clip(np.floor((pts[:, axis] - lo) / d).astype(np.int64), 0, len(coord) - 1))
    occ[idx[0], idx[1], idx[2]] = True
    return occ


def mesh_depth_map(mesh, grid: VoxelGrid) -> np.ndarray:
    """Ground-truth depth per voxel column: the first hit (z, metres) of the line through (x_m, y_m) along +z
    with the mesh (:func:`recon.ground_truth.ground_truth_depth_map`), NaN where it misses the mesh or the
    first hit lies outside the grid's z bounds."""
    from .ground_truth import ground_truth_depth_map

    d = ground_truth_depth_map(mesh, grid.x_m, grid.y_m)
    zlo, zhi = grid.bounds[4], grid.bounds[5]
    d[~((d >= zlo) & (d <= zhi))] = np.nan
    return d


def visible_surface_points(mesh, grid: VoxelGrid, oversample: int = 4) -> np.ndarray:
    """Points ``(n, 3)`` of the surface seen from the wall along +z, on an (x, y) grid ``oversample`` times
    finer than the voxels, inside the grid's bounds (see the module docstring)."""
    from .ground_truth import ground_truth_depth_map

    b = np.array(grid.bounds).reshape(3, 2)
    dx, dy, _ = grid.voxel_size_m
    nx = max(1, int(round((b[0, 1] - b[0, 0]) / dx * oversample)))
    ny = max(1, int(round((b[1, 1] - b[1, 0]) / dy * oversample)))
    x = b[0, 0] + (np.arange(nx) + 0.5) * (b[0, 1] - b[0, 0]) / nx
    y = b[1, 0] + (np.arange(ny) + 0.5) * (b[1, 1] - b[1, 0]) / ny
    d = ground_truth_depth_map(mesh, x, y)
    X, Y = np.meshgrid(x, y, indexing="xy")
    ok = np.isfinite(d) & (d >= b[2, 0]) & (d <= b[2, 1])
    return np.stack([X[ok], Y[ok], d[ok]], axis=1)


def _point_targets_from_mesh(mesh, grid: VoxelGrid) -> np.ndarray | None:
    diag = float(np.linalg.norm(grid.voxel_size_m))
    parts = mesh.split(only_watertight=False) if len(mesh.faces) < 200_000 else [mesh]
    pts = []
    for part in parts:
        ext = float(np.linalg.norm(part.bounds[1] - part.bounds[0]))
        if ext >= 2 * diag:
            return None
        pts.append(part.bounds.mean(axis=0))
    return np.array(pts) if pts else None


# ------------------------------------------------------------------ metrics


def chamfer(rec_points: np.ndarray, surface_points: np.ndarray) -> dict:
    """Accuracy, completeness and their mean between two point sets (nearest-neighbour distances)."""
    from scipy.spatial import cKDTree

    if len(rec_points) == 0 or len(surface_points) == 0:
        return {"accuracy_m": None, "completeness_m": None, "chamfer_m": None}
    acc = float(np.mean(cKDTree(surface_points).query(rec_points, workers=-1)[0]))
    comp = float(np.mean(cKDTree(rec_points).query(surface_points, workers=-1)[0]))
    return {"accuracy_m": acc, "completeness_m": comp, "chamfer_m": (acc + comp) / 2}


def _peaks(vol: np.ndarray, n: int) -> list[tuple[int, int, int]]:
    from scipy.ndimage import maximum_filter

    mx = maximum_filter(vol, size=3, mode="constant", cval=-np.inf)
    cand = np.argwhere((vol == mx) & (vol > 0))
    if len(cand) == 0:
        return []
    vals = vol[tuple(cand.T)]
    order = np.argsort(-vals, kind="stable")[:n]
    return [tuple(c) for c in cand[order]]


def localisation_errors(rec: Reconstruction, points: np.ndarray) -> dict:
    """Match each target to one of the strongest local maxima of ``rec.volume``; see the module docstring."""
    from scipy.optimize import linear_sum_assignment

    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    vol = rec.volume if np.any(rec.volume > 0) else rec.raw
    peaks = _peaks(vol, len(pts))
    g = rec.grid
    found = np.array([[g.x_m[ix], g.y_m[iy], g.z_m[iz]] for iz, iy, ix in peaks]).reshape(-1, 3)
    errs = [None] * len(pts)
    positions = [None] * len(pts)
    if len(found):
        cost = np.linalg.norm(pts[:, None] - found[None], axis=-1)
        r, c = linear_sum_assignment(cost)
        for i, j in zip(r, c):
            errs[i] = float(cost[i, j])
            positions[i] = found[j].tolist()
    valid = [e for e in errs if e is not None]
    return {"targets": pts.tolist(), "found": positions, "errors_m": errs, "n_found": len(valid),
            "localisation_error_m": float(np.mean(valid)) if valid else None,
            "max_localisation_error_m": float(np.max(valid)) if valid else None,
            "voxel_size_m": list(g.voxel_size_m)}


def compute_metrics(rec: Reconstruction, ground_truth: GroundTruth, seed: int = 0) -> dict:
    """All metrics of ``rec`` against ``ground_truth`` (see the module docstring)."""
    from .filters import depth_map

    out: dict = {"ground_truth": ground_truth.source, "method": rec.method,
                 "occupied_voxels": int(np.count_nonzero(rec.volume > 0))}
    g = rec.grid
    occ = rec.volume > 0
    centres = g.centers()[occ] if occ.any() else np.zeros((0, 3))
    points = ground_truth.points
    if ground_truth.mesh is not None:
        mesh = ground_truth.mesh
        samples = _samples(mesh, g, seed)
        out["surface_samples"] = int(len(samples))
        out.update(chamfer(centres, samples))
        gt_occ = mesh_occupancy(mesh, g, samples=samples)
        union = np.count_nonzero(gt_occ | occ)
        out["iou"] = float(np.count_nonzero(gt_occ & occ) / union) if union else None
        gt_depth = mesh_depth_map(mesh, g)
        rec_depth = depth_map(rec.volume, g)
        both = np.isfinite(gt_depth) & np.isfinite(rec_depth)
        diff = (rec_depth - gt_depth)[both]
        out["depth_mae_m"] = float(np.mean(np.abs(diff))) if diff.size else None
        out["depth_rmse_m"] = float(np.sqrt(np.mean(diff ** 2))) if diff.size else None
        n_gt = int(np.count_nonzero(np.isfinite(gt_depth)))
        n_rec = int(np.count_nonzero(np.isfinite(rec_depth)))
        out["depth_coverage"] = float(np.count_nonzero(both) / n_gt) if n_gt else None
        out["depth_false_columns"] = float(np.count_nonzero(np.isfinite(rec_depth) & ~np.isfinite(gt_depth)) / n_rec) \
            if n_rec else None
        sil_gt = np.isfinite(gt_depth)
        sil_rec = occ.any(axis=0)
        u = np.count_nonzero(sil_gt | sil_rec)
        out["silhouette_iou"] = float(np.count_nonzero(sil_gt & sil_rec) / u) if u else None
        vis_points = visible_surface_points(mesh, g)
        vis = chamfer(centres, vis_points)
        out.update({f"visible_{k}": v for k, v in vis.items()})
        vis_occ = mesh_occupancy(mesh, g, samples=vis_points)
        union = np.count_nonzero(vis_occ | occ)
        out["visible_iou"] = float(np.count_nonzero(vis_occ & occ) / union) if union else None
        from .surface import normal_map, reconstruction_surface

        n_rec = normal_map(rec_depth, g)
        n_gt = normal_map(gt_depth, g)
        cosang = np.sum(n_rec * n_gt, axis=-1)
        ok = np.isfinite(cosang)
        ang = np.degrees(np.arccos(np.clip(cosang[ok], -1.0, 1.0)))
        out["normal_error_deg"] = float(np.mean(ang)) if ang.size else None
        out["normal_error_median_deg"] = float(np.median(ang)) if ang.size else None
        verts, faces = reconstruction_surface(rec)
        out["surface_faces"] = int(len(faces))
        out.update({f"surface_{k}": v for k, v in chamfer(verts, samples).items()})
        if points is None:
            points = _point_targets_from_mesh(mesh, g)
    if points is not None:
        out["point_targets"] = localisation_errors(rec, points)
        out["localisation_error_m"] = out["point_targets"]["localisation_error_m"]
    return out
