"""Metrics against ground truth: Chamfer, depth-map error, occupancy IoU, point localisation."""

import json
import math

import numpy as np
import pytest
import trimesh

from transient_core.errors import UserInputError
from recon.grid import VoxelGrid
from recon.metrics import GroundTruth, compute_metrics, load_ground_truth, mesh_depth_map
from recon.result import Reconstruction

GRID = VoxelGrid.from_bounds((-0.4, 0.4, -0.4, 0.4, 0.2, 0.8), voxel_size_m=0.05)   # 16 x 16 x 12


def _square(z, half=0.199):
    v = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]])
    return trimesh.Trimesh(vertices=v, faces=[[0, 1, 2], [0, 2, 3]], process=False)


def _layer(iz):
    vol = np.zeros(GRID.shape, np.float32)
    ix = np.abs(GRID.x_m) < 0.2
    iy = np.abs(GRID.y_m) < 0.2
    vol[iz][np.ix_(iy, ix)] = 1.0
    return Reconstruction(raw=vol, grid=GRID, method="bp")


def test_perfect_plane_reconstruction(tmp_path):
    iz = 5
    mesh = _square(GRID.z_m[iz])
    mesh.export(tmp_path / "plane.obj")
    gt = load_ground_truth(tmp_path / "plane.obj")
    m = compute_metrics(_layer(iz), gt, seed=1)
    assert m["iou"] == 1.0
    assert m["depth_mae_m"] == pytest.approx(0.0, abs=1e-12) and m["depth_coverage"] == 1.0
    assert m["depth_false_columns"] == 0.0
    spacing = min(GRID.voxel_size_m) / 4
    assert m["accuracy_m"] <= spacing                              # voxel centres lie on the surface
    assert m["completeness_m"] <= math.sqrt(2) / 2 * GRID.voxel_size_m[0]
    assert "localisation_error_m" not in m                         # a 40 cm plane is not a point target


def test_plane_one_voxel_too_deep():
    iz = 5
    m = compute_metrics(_layer(iz + 1), GroundTruth(mesh=_square(GRID.z_m[iz])), seed=1)
    dz = GRID.voxel_size_m[2]
    assert m["depth_mae_m"] == pytest.approx(dz) and m["depth_rmse_m"] == pytest.approx(dz)
    assert m["iou"] == 0.0
    assert m["accuracy_m"] == pytest.approx(dz, rel=0.05)


def test_mesh_depth_map_is_the_first_hit():
    near, far = _square(0.35), _square(0.6, half=0.3)
    d = mesh_depth_map(trimesh.util.concatenate([far, near]), GRID)
    inner = (np.abs(GRID.y_m)[:, None] < 0.19) & (np.abs(GRID.x_m)[None, :] < 0.19)
    ring = ((np.abs(GRID.y_m)[:, None] < 0.29) & (np.abs(GRID.x_m)[None, :] < 0.29)) & ~inner \
        & ~((np.abs(GRID.y_m)[:, None] < 0.21) & (np.abs(GRID.x_m)[None, :] < 0.21))
    np.testing.assert_allclose(d[inner], 0.35)
    np.testing.assert_allclose(d[ring], 0.6)
    assert np.all(np.isnan(d[(np.abs(GRID.y_m)[:, None] > 0.31) | (np.abs(GRID.x_m)[None, :] > 0.31)]))


def test_point_targets_localisation(tmp_path):
    targets = np.array([[0.1, -0.1, 0.5], [-0.2, 0.15, 0.35]])
    vol = np.zeros(GRID.shape, np.float32)
    found = []
    for t, v in zip(targets, (1.0, 0.7)):
        ix, iy, iz = (int(np.argmin(np.abs(a - c))) for a, c in zip((GRID.x_m, GRID.y_m, GRID.z_m), t))
        vol[iz, iy, ix] = v
        found.append([GRID.x_m[ix], GRID.y_m[iy], GRID.z_m[iz]])
    vol[0, 0, 0] = 0.1                                             # a weaker spurious peak
    rec = Reconstruction(raw=vol, grid=GRID, method="bp")
    want = np.linalg.norm(np.array(found) - targets, axis=1)
    spheres = []
    for t in targets:
        s = trimesh.creation.icosphere(subdivisions=1, radius=0.01)
        s.apply_translation(t)
        spheres.append(s)
    trimesh.util.concatenate(spheres).export(tmp_path / "pts.ply")
    (tmp_path / "pts.json").write_text(json.dumps({"points": targets.tolist()}))
    np.save(tmp_path / "pts.npy", targets)
    np.savetxt(tmp_path / "pts.csv", targets, delimiter=",")
    for name in ("pts.ply", "pts.json", "pts.npy", "pts.csv"):
        m = compute_metrics(rec, load_ground_truth(tmp_path / name))
        np.testing.assert_allclose(m["point_targets"]["errors_m"], want, atol=1e-3 if name == "pts.ply" else 1e-12)
        assert m["localisation_error_m"] == pytest.approx(want.mean(), abs=1e-3)


def test_ground_truth_errors(tmp_path):
    with pytest.raises(UserInputError, match="does not exist"):
        load_ground_truth(tmp_path / "missing.obj")
    (tmp_path / "bad.json").write_text("[[1, 2]]")
    with pytest.raises(UserInputError, match=r"expected points of shape \(n, 3\)"):
        load_ground_truth(tmp_path / "bad.json")
    (tmp_path / "bad.obj").write_text("this is not a mesh\n")
    with pytest.raises(UserInputError, match="bad.obj"):
        load_ground_truth(tmp_path / "bad.obj")
