"""Shape completion behind the visible surface (recon.completion) against closed forms.

Deterministic geometry, no random numbers: the tolerances are the discretisation bounds stated per test
(half a column or voxel), not statistical.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from recon.completion import check_aspect, complete_surface, front_depth, local_thickness
from recon.grid import VoxelGrid
from recon.result import Reconstruction
from transient_core.errors import UserInputError

VOX = 0.01   # 1 cm voxels


def _grid(nz=40):
    return VoxelGrid.from_bounds((-0.2, 0.2, -0.2, 0.2, 0.3, 0.3 + nz * VOX), voxel_size_m=VOX)


def _front_volume(g, front_m, sigma_m=0.012):
    """A filtered-looking volume: per column a Gaussian along z peaked at the front depth (NaN: empty column)."""
    z = g.z_m[:, None, None]
    vol = np.exp(-0.5 * ((z - front_m[None]) / sigma_m) ** 2)
    vol = np.where(np.isfinite(front_m)[None] & (vol > 0.3), vol, 0.0)
    return vol.astype(np.float32)


def _cylinder(g, radius, z_axis, aspect):
    """A horizontal elliptic cylinder along y (lateral semi-axis ``radius``, depth semi-axis ``aspect*radius``)
    with |y| < 0.12: its front depth per column, NaN outside."""
    X, Y = np.meshgrid(g.x_m, g.y_m, indexing="xy")
    inside = (np.abs(X) < radius) & (np.abs(Y) < 0.12)
    half = aspect * np.sqrt(np.clip(radius ** 2 - X ** 2, 0, None))
    return np.where(inside, z_axis - half, np.nan), np.where(inside, z_axis + half, np.nan)


def test_local_thickness_of_a_disk_and_a_strip():
    d = 0.005
    n = 81
    c = (np.arange(n) - n // 2) * d
    X, Y = np.meshgrid(c, c, indexing="xy")
    disk = X ** 2 + Y ** 2 <= 0.15 ** 2
    dist, radius, centre = local_thickness(disk, d, d)
    # every column of a disk lies in the disk's own largest inscribed disk: R = the disk's radius, to a column
    assert np.all(np.abs(radius[disk] - 0.15) <= d), np.abs(radius[disk] - 0.15).max()
    assert np.all(radius[~disk] == 0) and np.all(dist[~disk] == 0)
    assert tuple(centre[n // 2, n // 2]) == (n // 2, n // 2)
    strip = (np.abs(X) <= 0.06) & (np.abs(Y) <= 0.18)
    _, radius, _ = local_thickness(strip, d, d)
    # away from the strip's ends R is its half width (to a column)
    mid = strip & (np.abs(Y) < 0.1)
    assert np.all(np.abs(radius[mid] - 0.0625) <= d), np.abs(radius[mid] - 0.0625).max()


def test_front_depth_is_sub_voxel():
    g = _grid()
    front_true = np.full((len(g.y_m), len(g.x_m)), 0.4537)
    front_true[:, :5] = np.nan
    got = front_depth(_front_volume(g, front_true), g.z_m)
    assert np.all(np.isnan(got[:, :5]))
    # a parabola through three samples of a Gaussian of sigma 1.2 voxels: within 0.1 voxel of its peak
    assert np.nanmax(np.abs(got - front_true)) < 0.1 * VOX


@pytest.mark.parametrize("aspect", [1.0, 0.5])
def test_completed_back_of_an_elliptic_cylinder(aspect):
    """Given its aspect, the back lies where the cylinder's is: within half a voxel (the shell's quantisation)
    plus one column (R is an inscribed disk's radius centred on a column, up to half a column short, and the
    thickness is twice it)."""
    g = _grid()
    front, back = _cylinder(g, 0.08, 0.45, aspect)
    rec = Reconstruction(raw=np.zeros(g.shape, np.float32), grid=g, method="test", volume=_front_volume(g, front))
    out = complete_surface(rec, aspect)
    occ = out.volume > 0
    assert out.params["completion"]["aspects"][0]["aspect"] == aspect
    # deepest voxel per column vs the true back
    iz_back = len(g.z_m) - 1 - np.argmax(occ[::-1], axis=0)
    has = occ.any(axis=0) & np.isfinite(back)
    err = g.z_m[iz_back][has] - back[has]
    X, Y = (a[has] for a in np.meshgrid(g.x_m, g.y_m, indexing="xy"))
    # where the slope is moderate the front is found to 0.1 voxel (see above); within R of the cylinder's flat
    # ends the prior rounds them off (a column there lies in a disk it is off-centre in)
    core = (np.abs(X) < 0.06) & (np.abs(Y) < 0.12 - 0.08)
    assert np.all(np.abs(err[core]) <= 1.5 * VOX), np.abs(err[core]).max()
    # the shell is closed: filling its holes adds the interior, and nothing escapes to the volume's border
    from scipy.ndimage import binary_fill_holes

    solid = binary_fill_holes(occ)
    assert np.count_nonzero(solid) > 2 * np.count_nonzero(occ) * (0.5 if aspect < 1 else 1)


@pytest.mark.parametrize("aspect", [1.0, 0.5])
def test_auto_aspect_is_estimated_from_the_front(aspect):
    """A spheroid (lateral semi-axis R, depth semi-axis aspect * R) is what the prior assumes everywhere."""
    g = _grid()
    X, Y = np.meshgrid(g.x_m, g.y_m, indexing="xy")
    r2 = X ** 2 + Y ** 2
    front = np.where(r2 < 0.12 ** 2, 0.5 - aspect * np.sqrt(np.clip(0.12 ** 2 - r2, 0, None)), np.nan)
    rec = Reconstruction(raw=np.zeros(g.shape, np.float32), grid=g, method="test", volume=_front_volume(g, front))
    got = complete_surface(rec, "auto").params["completion"]["aspects"]
    assert len(got) == 1
    # The estimate is biased high: the inscribed disks are centred on columns, so R is short of the spheroid's
    # radius by up to half a column diagonal and the predicted recession near the edge is too small (measured
    # +10 % at 12 columns of radius, +26 % at 8; documented in docs/recon.md). Bound: within [a, 1.15 a].
    assert aspect <= got[0]["aspect"] <= 1.15 * aspect


def test_flat_plate_stays_a_plate():
    """A plane facing the wall has no recession: the estimated aspect is 0 and the shell is the front itself."""
    g = _grid()
    front = np.full((len(g.y_m), len(g.x_m)), np.nan)
    front[10:30, 12:28] = 0.45
    vol = _front_volume(g, front)
    rec = Reconstruction(raw=np.zeros(g.shape, np.float32), grid=g, method="test", volume=vol)
    out = complete_surface(rec, "auto")
    assert out.params["completion"]["aspects"][0]["aspect"] == pytest.approx(0.0, abs=1e-9)
    occ = out.volume > 0
    assert np.array_equal(occ.any(axis=0), vol.any(axis=0))
    assert np.all(occ.sum(axis=0) <= 2)   # one or two voxels deep: the front, never a body behind it


def test_empty_volume_and_refusals():
    g = _grid(8)
    rec = Reconstruction(raw=np.zeros(g.shape, np.float32), grid=g, method="test")
    out = complete_surface(rec, 1)
    assert not np.any(out.volume) and out.params["completion"]["added_voxels"] == 0
    assert check_aspect("auto") is None and check_aspect("0.5") == 0.5
    for bad in ("round", -0.1, 2.5, float("nan"), None, True):
        with pytest.raises(UserInputError, match="--complete"):
            check_aspect(bad)


def test_reconstruct_records_the_prior_and_the_cli_refuses_in_one_line(tmp_path):
    import recon
    from recon.synthetic import point_capture, wall_grid

    cap = point_capture([[0.0, 0.0, 0.5]], pixels=8, wall_size_m=1.0, spots=wall_grid(1, 1, 0.5).reshape(-1, 3),
                        spot_grid=(1, 1), bin_width_ps=16.0, sigma_ps=10.0)
    rec = recon.reconstruct(cap, "bp", bounds=(-0.3, 0.3, -0.3, 0.3, 0.3, 0.7), voxels=16, complete="auto")
    assert rec.params["completion"]["prior"] == "elliptical cross-sections"
    with pytest.raises(UserInputError, match="--complete 'x'"):
        recon.reconstruct(cap, "bp", voxels=8, complete="x")
    r = subprocess.run([sys.executable, "-m", "transient_mi", "recon", str(tmp_path / "nothing"), "-o",
                        str(tmp_path / "o"), "--complete", "3"], capture_output=True, text=True)
    assert r.returncode != 0 and "Traceback" not in r.stderr
    assert not (tmp_path / "o").exists()


def test_rasterised_height_field_is_gap_free_and_exact_on_a_plane():
    """A plane's voxels are those it passes through; a steep ramp leaves no z gap between neighbouring columns."""
    from recon.completion import rasterise_height

    g = _grid()
    cols = np.ones((len(g.y_m), len(g.x_m)), bool)
    flat = rasterise_height(np.full(cols.shape, 0.4551), cols, g.z_m)
    iz = int(np.floor((0.4551 - g.bounds[4]) / VOX))
    assert np.array_equal(np.nonzero(flat.any(axis=(1, 2)))[0], [iz])   # the one voxel holding z = 0.4551
    X = np.meshgrid(g.x_m, g.y_m, indexing="xy")[0]
    ramp = rasterise_height(0.5 + 1.5 * X, cols & (np.abs(X) < 0.1), g.z_m)   # slope 1.5: 1.5 voxels per column
    for ix in np.nonzero(np.abs(g.x_m) < 0.09)[0]:
        z = np.nonzero(ramp[:, 20, ix])[0]
        assert len(z) >= 2 and np.all(np.diff(z) == 1)   # contiguous in z
        nxt = np.nonzero(ramp[:, 20, ix + 1])[0]
        assert nxt.min() <= z.max() + 1                  # and touching the next column's voxels
