"""The padded, branchless float32 backprojection kernels equal the bounds-checked float64 sum.

:func:`recon.backprojection.backproject` copies each chunk of histograms into a zero-padded time axis
covering every bin index a voxel of the grid can reach and computes path lengths in float32 bin units
(``recon._kernels``). The reference here is the definition in float64 numpy: the sum over pairs of
bin ``floor((|v - S| + |v - P| + offset - c t0) / w)`` when it lies in ``[0, T)``, else nothing.

float32 path lengths (about 1e3 bins here, unit roundoff 6e-8, a few operations) err by less than
1e-3 bin, so a pair can land in the neighbouring bin only when its float64 path lies within
``EDGE_BINS = 1e-3`` bin of a bin edge. The test bounds the difference per voxel by exactly those pairs'
possible jumps (``|h[b] - h[b +- 1]|``); every other pair must contribute its exact bin. The geometries
put paths before the first bin and after the last (the padding must read zeros there) and cover the
three kernels: one spot per file (array), confocal (spot on the pixel's patch) and paired confocal
(spot 1 cm off the patch).
"""

import numpy as np
import pytest

from recon.backprojection import backproject
from recon.capture import Capture
from recon.grid import VoxelGrid
from recon.synthetic import wall_grid
from transient_core.errors import UserInputError

EDGE_BINS = 1e-3
GRID = VoxelGrid.from_bounds((-0.33, 0.31, -0.29, 0.35, 0.15, 0.8), voxels=(9, 8, 7))


def _capture(kind: str) -> Capture:
    rng = np.random.default_rng(11)
    P = wall_grid(4, 3, 0.6) + rng.normal(0, 0.01, (3, 4, 3))
    n = np.tile([0.0, 0.0, 1.0], (3, 4, 1))
    T, w_ps = 300, 4.7
    common = dict(pixel_centers=P, pixel_normals=n, laser_origin=[-0.5, 0, 1.0], detector_origin=[-0.5, 0.2, 1.0],
                  bin_width_ps=w_ps, include_first_last=True)
    if kind == "array":
        spots = np.array([[0.0, 0.0, 0.0], [0.2, -0.1, 0.01], [-0.15, 0.12, -0.02]])
        data = rng.random((3, 3, 4, T)).astype(np.float32)
        return Capture.from_arrays(data, spots=spots, t0_ps=9400.0, **common)
    spots = P.reshape(-1, 3) + (0.0 if kind == "confocal" else np.array([0.01, -0.007, 0.0]))
    data = rng.random((3, 4, T)).astype(np.float32)
    return Capture.from_arrays(data, mode="confocal", spots=spots, t0_ps=8800.0, **common)


def _reference(capture, grid):
    """(sum, allowed deviation, pairs before the axis, pairs after it, pairs near an edge) in float64."""
    V = grid.centers().reshape(-1, 3)
    P = capture.pixel_centers.reshape(-1, 3)
    w, t0 = capture.bin_width_m, capture.t0_m
    out = np.zeros(len(V))
    allowed = np.zeros(len(V))
    before = after = near = 0
    for j in range(capture.n_files):
        h = capture.spot(j).reshape(len(P), -1).astype(np.float64)
        T = h.shape[1]
        hp = np.concatenate([np.zeros((len(P), 1)), h, np.zeros((len(P), 1))], axis=1)  # hp[b + 1] = h[b]
        off = capture.path_offsets_m(j).reshape(-1)
        for k in range(len(P)):
            S = capture.spots[k] if capture.mode == "confocal" else capture.spots[j]
            r = (np.linalg.norm(V - S, axis=1) + np.linalg.norm(V - P[k], axis=1) + off[k] - t0) / w
            b = np.floor(r).astype(np.int64)
            before += int(np.sum(b < 0))
            after += int(np.sum(b >= T))
            ok = (b >= 0) & (b < T)
            out[ok] += h[k, b[ok]]
            frac = r - b
            edge = (frac < EDGE_BINS) | (frac > 1 - EDGE_BINS)
            near += int(edge.sum())
            bc = np.clip(b, -1, T) + 1
            jump = np.maximum(np.abs(hp[k, bc] - hp[k, np.clip(bc - 1, 0, T + 1)]),
                              np.abs(hp[k, bc] - hp[k, np.clip(bc + 1, 0, T + 1)]))
            allowed[edge] += jump[edge]
    return out.reshape(grid.shape), allowed.reshape(grid.shape), before, after, near


@pytest.mark.parametrize("kind", ["array", "confocal", "paired"])
def test_padded_kernel_equals_the_bounds_checked_float64_sum(kind):
    cap = _capture(kind)
    ref, allowed, before, after, near = _reference(cap, GRID)
    # the geometry exercises the padding on both sides and most pairs land inside the axis
    assert before > 0 and after > 0
    assert ref.max() > 0
    pairs = cap.n_files * cap.height * cap.width * GRID.centers().reshape(-1, 3).shape[0]
    assert near < 0.01 * pairs
    got = backproject(cap, GRID)
    assert got.dtype == np.float64 and got.shape == GRID.shape
    # float64 accumulation of float32 values: order-of-summation rounding far below 1e-9 of the total
    np.testing.assert_array_less(np.abs(got - ref), allowed + 1e-9 * np.abs(ref).max())


def test_padded_kernel_is_deterministic():
    cap = _capture("array")
    a = backproject(cap, GRID)
    b = backproject(cap, GRID)
    assert a.tobytes() == b.tobytes()


def test_padded_axis_over_2_20_bins_is_refused():
    # 1 fs bins (0.3 um of path): the grid's path lengths span millions of bins
    P = wall_grid(2, 2, 0.2)
    cap = Capture.from_arrays(np.ones((1, 2, 2, 10), np.float32), spots=[[0.0, 0.0, 0.0]], pixel_centers=P,
                              t0_ps=3000.0, bin_width_ps=0.001)
    with pytest.raises(UserInputError, match="at most 1048576 are supported"):
        backproject(cap, GRID)
