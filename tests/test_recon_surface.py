"""3-D output (recon.surface) and the surface metrics (recon.metrics), against closed forms.

All checks are deterministic (no random process except the seeded mesh sampling of compute_metrics).
"""

import math

import numpy as np
import pytest
import trimesh

from transient_core.errors import UserInputError
from recon.grid import VoxelGrid
from recon.metrics import GroundTruth, compute_metrics, visible_surface_points
from recon.result import Reconstruction
from recon.surface import isosurface, normal_map, reconstruction_surface, write_ply

CENTRE = np.array([0.01, -0.02, 0.5])
R = 0.12
GRID = VoxelGrid.from_bounds((-0.2, 0.2, -0.2, 0.2, 0.3, 0.7), voxels=(40, 40, 40))


def test_isosurface_of_a_sphere_is_closed_outward_and_on_the_sphere():
    f = R - np.linalg.norm(GRID.centers() - CENTRE, axis=-1)   # signed distance, > 0 inside
    v, faces = isosurface(f, GRID, 0.0)
    mesh = trimesh.Trimesh(v, faces, process=True)
    assert mesh.is_watertight
    # vertices are means of linearly interpolated edge crossings of an exactly linear-in-the-normal field:
    # each lies within the chord error of a cell, h^2 / (2 R) * 3 (three axes), of the sphere
    h = GRID.voxel_size_m[0]
    assert np.max(np.abs(np.linalg.norm(v - CENTRE, axis=1) - R)) <= 3 * h ** 2 / (2 * R)
    # outward normals: positive enclosed volume; a polyhedron inscribed within that band
    vol = 4 / 3 * math.pi * R ** 3
    assert abs(mesh.volume / vol - 1) <= 3 * (3 * h ** 2 / (2 * R)) / R
    # the face normals point away from the centre
    c = mesh.triangles_center - CENTRE
    assert np.all(np.sum(c * mesh.face_normals, axis=1) > 0)


def test_reconstruction_surface_encloses_the_kept_voxels_and_ply_round_trips(tmp_path):
    vol = np.zeros(GRID.shape, dtype=np.float32)
    vol[10:20, 12:30, 5:15] = 2.0           # a box of kept voxels (the threshold zeroed the rest)
    rec = Reconstruction(raw=vol, grid=GRID, method="test", volume=vol)
    v, faces = reconstruction_surface(rec)
    mesh = trimesh.Trimesh(v, faces, process=True)
    assert mesh.is_watertight and mesh.volume > 0
    # level 1.0 between 2 and 0: the surface runs halfway between the outer kept voxel centres and their
    # neighbours, i.e. on the box of voxel faces
    b = mesh.bounds
    x, y, z = GRID.x_m, GRID.y_m, GRID.z_m
    h = np.array(GRID.voxel_size_m)
    np.testing.assert_allclose(b[0], [x[5] - h[0] / 2, y[12] - h[1] / 2, z[10] - h[2] / 2], atol=1e-9)
    np.testing.assert_allclose(b[1], [x[14] + h[0] / 2, y[29] + h[1] / 2, z[19] + h[2] / 2], atol=1e-9)
    # a region touching the boundary is closed by the padding (open with closed=False)
    vol2 = np.zeros(GRID.shape, dtype=np.float32)
    vol2[:5, :, :] = 1.0
    assert trimesh.Trimesh(*isosurface(vol2, GRID, 0.5), process=True).is_watertight
    assert not trimesh.Trimesh(*isosurface(vol2, GRID, 0.5, closed=False), process=True).is_watertight
    write_ply(tmp_path / "s.ply", v, faces)
    back = trimesh.load(tmp_path / "s.ply", process=False)
    np.testing.assert_allclose(back.vertices, v.astype(np.float32))
    np.testing.assert_array_equal(back.faces, faces)


def test_normal_map_of_a_tilted_plane():
    # z = 0.5 + 0.3 x - 0.2 y: normal (0.3, -0.2, -1)/|.| facing the wall, exact for central differences
    X, Y = np.meshgrid(GRID.x_m, GRID.y_m, indexing="xy")
    n = normal_map(0.5 + 0.3 * X - 0.2 * Y, GRID)
    expected = np.array([0.3, -0.2, -1.0]) / math.sqrt(1.13)
    np.testing.assert_allclose(n, np.broadcast_to(expected, n.shape), atol=1e-12)
    with pytest.raises(UserInputError, match="depth map has shape"):
        normal_map(np.zeros((3, 3)), GRID)


def _plane_mesh(z0=0.5):
    v = np.array([[-0.1, -0.1, z0], [0.1, -0.1, z0], [0.1, 0.1, z0], [-0.1, 0.1, z0],
                  [-0.1, -0.1, z0 + 0.1], [0.1, -0.1, z0 + 0.1], [0.1, 0.1, z0 + 0.1], [-0.1, 0.1, z0 + 0.1]])
    f = np.array([[0, 1, 2], [0, 2, 3], [4, 6, 5], [4, 7, 6]])   # front square and a back square 10 cm behind
    return trimesh.Trimesh(v, f, process=False)


def test_visible_metrics_ignore_the_back_and_normals_match():
    mesh = _plane_mesh()
    g = VoxelGrid.from_bounds((-0.2, 0.2, -0.2, 0.2, 0.4, 0.7), voxel_size_m=0.02)
    pts = visible_surface_points(mesh, g)
    assert len(pts) and np.allclose(pts[:, 2], 0.5, rtol=0, atol=1e-12)   # only the front square is seen
    # a reconstruction with exactly the front square's voxels (z = 0.5 is a voxel face: the voxel behind it)
    vol = np.zeros(g.shape, dtype=np.float32)
    iz = int(np.argmin(np.abs(g.z_m - 0.51)))
    inx = np.abs(g.x_m) < 0.1
    iny = np.abs(g.y_m) < 0.1
    vol[iz][np.ix_(iny, inx)] = 1.0
    rec = Reconstruction(raw=vol, grid=g, method="test", volume=vol)
    m = compute_metrics(rec, GroundTruth(mesh=mesh))
    # voxel centres sit 1 cm behind the front square: every distance between the two is >= 1 cm and, laterally
    # within half a voxel diagonal of a centre, <= sqrt(0.01^2 + 2 * 0.01^2)
    for k in ("visible_accuracy_m", "visible_completeness_m"):
        assert 0.01 - 1e-9 <= m[k] <= math.sqrt(3) * 0.01 + 1e-9, (k, m[k])
    # the whole-mesh completeness also counts the back square, 9 cm behind the voxels
    assert m["completeness_m"] > m["visible_completeness_m"] + 0.03
    assert m["normal_error_deg"] == pytest.approx(0.0, abs=1e-9)
    # the occupied columns are exactly those the 20 cm square covers (|x|, |y| < 0.1 on a 2 cm grid)
    assert m["silhouette_iou"] == pytest.approx(1.0)
    assert m["surface_faces"] > 0 and m["surface_chamfer_m"] is not None
