"""The paper's filter (Gaussian, Laplacian, threshold), projections and depth maps."""

import numpy as np
import pytest

from transient_core.errors import UserInputError
from recon.filters import (apply_threshold, depth_map, negative_laplacian_of_gaussian, otsu_threshold, paper_filter,
                           parse_threshold, projections)
from recon.grid import VoxelGrid
from recon.result import Reconstruction

GRID = VoxelGrid.from_bounds((0, 1, 0, 2, 0, 1.5), voxels=(20, 30, 25))   # anisotropic voxels


def test_laplacian_in_physical_units_is_exact_for_quadratics():
    C = GRID.centers()
    f = C[..., 0] ** 2 + 2 * C[..., 1] ** 2 + 3 * C[..., 2] ** 2          # Laplacian = 2 + 4 + 6
    for sigma in (None, 0.1):
        out = negative_laplacian_of_gaussian(f, GRID, sigma)
        interior = out[9:-9, 9:-9, 9:-9]                                  # away from the borders
        np.testing.assert_allclose(interior, -12.0, rtol=1e-5)
    lin = 3 * C[..., 0] - C[..., 2] + 7
    np.testing.assert_allclose(negative_laplacian_of_gaussian(lin, GRID)[5:-5, 5:-5, 5:-5], 0, atol=1e-3)


def test_paper_filter_keeps_the_blob_and_records_the_threshold():
    C = GRID.centers()
    c = np.array([0.4, 1.1, 0.7])
    blob = np.exp(-np.sum((C - c) ** 2, axis=-1) / (2 * 0.08 ** 2)) + 0.2 * C[..., 2]   # blob on a ramp
    rec = paper_filter(Reconstruction(raw=blob, grid=GRID, method="bp"), threshold="rel:0.5")
    assert np.all(rec.volume >= 0)
    kept = rec.volume > 0
    np.testing.assert_allclose(rec.argmax_m(), c, atol=max(GRID.voxel_size_m))
    # every kept voxel is near the blob; the ramp (zero Laplacian) is gone
    far = np.linalg.norm(C - c, axis=-1) > 0.25
    assert not np.any(kept & far)
    assert rec.filter["name"] == "paper" and rec.filter["threshold"] == "rel:0.5"
    assert rec.filter["threshold_value"] == pytest.approx(0.5 * float(np.max(np.maximum(
        negative_laplacian_of_gaussian(blob, GRID), 0))), rel=1e-6)


def test_thresholds():
    assert parse_threshold("otsu") == ("otsu", None)
    assert parse_threshold("rel:0.25") == ("rel", 0.25)
    assert parse_threshold("absolute:3") == ("abs", 3.0)
    assert parse_threshold("none") == ("none", None)
    for bad in ("rel:0", "rel:1.5", "abs:-1", "abs:x", "median", "rel:nan"):
        with pytest.raises(UserInputError, match="threshold"):
            parse_threshold(bad)
    rng = np.random.default_rng(1)
    low, high = rng.normal(1, 0.3, 5000), rng.normal(9, 0.5, 800)   # two classes 16 sigma apart
    t = otsu_threshold(np.concatenate([low, high]))
    assert low.max() < t < high.min()          # separates them without error
    out, thr = apply_threshold(np.array([0.0, 1.0, 2.0, 4.0]), "rel:0.5")
    assert thr == 2.0 and out.tolist() == [0, 0, 2, 4]
    with pytest.raises(UserInputError, match="keeps no voxel"):
        apply_threshold(np.array([0.0, 1.0]), "abs:5")


def test_projections_and_depth_map():
    vol = np.zeros(GRID.shape, np.float32)
    vol[10, 4, 7] = 2.0     # z index 10, y 4, x 7
    vol[3, 4, 7] = 1.0      # weaker, nearer the wall
    vol[5, 20, 2] = 0.5
    p = projections(vol)
    assert p["z"].shape == (30, 20) and p["y"].shape == (25, 20) and p["x"].shape == (25, 30)
    assert p["z"][4, 7] == 2.0 and p["y"][10, 7] == 2.0 and p["x"][10, 4] == 2.0
    d = depth_map(vol, GRID)
    assert d.shape == (30, 20)
    assert d[4, 7] == GRID.z_m[10] and d[20, 2] == GRID.z_m[5]
    assert np.isnan(d[0, 0]) and np.count_nonzero(np.isfinite(d)) == 2
