"""Interop: confocal y-tal export with the laser grid equal to the sensor grid, ``transient-mi export``, and readers
for the Stanford f-k ``.mat`` and ZNLOS HDF5 layouts (on small files written here in those layouts)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
import scipy.io

import recon
from transient_core import stack
from recon.io.real import read_fk_mat, read_znlos
from recon.synthetic import point_capture
from transient_core.units import C_M_PER_PS

ROOT = Path(__file__).resolve().parents[1]
POINT = [0.1, -0.15, 0.5]


def _confocal(wall=1.0, n=16, first_last=False):
    return point_capture([POINT], mode="confocal", pixels=n, wall_size_m=wall, sigma_ps=30, bin_width_ps=32,
                         include_first_last=first_last)


def test_confocal_export_stores_the_sensor_grid_as_the_laser_grid(tmp_path):
    cap = _confocal()
    m = dict(cap.manifest)
    g = dict(m["geometry"])
    g["spots"] = (np.asarray(g["spots"]) + 2e-7).tolist()  # ray-traced spots: float32 rounding off the centres
    m["geometry"] = g
    stack.write_stack(tmp_path / "c", m, cap.data)
    env = dict(os.environ, TRANSIENT_MI_PROGRESS="0")
    r = subprocess.run([sys.executable, "-m", "transient_mi", "export", tmp_path / "c", tmp_path / "c.h5", "--to",
                        "ytal"], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    with h5py.File(tmp_path / "c.h5") as f:
        assert np.array_equal(f["laser_grid_xyz"][()], f["sensor_grid_xyz"][()])  # y-tal's is_confocal(): exact
        assert np.array_equal(f["laser_grid_normals"][()], f["sensor_grid_normals"][()])
    back = recon.load_capture(tmp_path / "c.h5")
    assert back.mode == "confocal" and np.array_equal(back.spot(0), cap.spot(0))
    r2 = subprocess.run([sys.executable, "-m", "transient_mi", "export", tmp_path / "c", tmp_path / "c.h5", "--to",
                         "ytal"], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert r2.returncode == 2 and r2.stderr.strip().splitlines() == [
        f"error: OUTPUT {tmp_path / 'c.h5'}: exists; pass --overwrite to replace it"]


def _k0(cap) -> int:
    k0 = cap.t0_ps / cap.bin_width_ps
    assert k0 == int(k0)
    return int(k0)


def _fk_layout(cap, delays_bins):
    """The confocal histograms as f-k ``meas`` [y, x, t] (row 0 = top), delayed per pixel by ``delays_bins``."""
    d = np.asarray(cap.spot(0), dtype=np.float64)  # [y, x, t], pixel_centers[y] increasing in y
    d = d[::-1]  # f-k row 0 is the top of the wall
    T = d.shape[-1]
    k0 = _k0(cap)  # after rectification bin 0 is t = 0 (light leaving the wall)
    meas = np.zeros((d.shape[0], d.shape[1], k0 + T + delays_bins.max() + 1))
    for (i, j), s in np.ndenumerate(delays_bins):
        meas[i, j, s + k0:s + k0 + T] = d[i, j]
    return np.round(meas * 1e3)  # counts


@pytest.mark.parametrize("version", ["v5", "v7.3"])
def test_stanford_fk_mat_is_rectified_and_placed_on_the_wall(tmp_path, version):
    cap = _confocal(wall=1.0, n=16)
    rng = np.random.default_rng(3)
    delays = rng.integers(20, 40, size=(16, 16))
    meas = _fk_layout(cap, delays)
    tofgrid = delays * 32.0 + 5.0  # ps; floor(tof / 32) = delays
    if version == "v5":
        scipy.io.savemat(tmp_path / "meas_10min.mat", {"meas": meas})
        scipy.io.savemat(tmp_path / "tof.mat", {"tofgrid": tofgrid})
    else:  # MATLAB v7.3 is HDF5 with column-major arrays: h5py sees the axes reversed
        with h5py.File(tmp_path / "meas_10min.mat", "w") as f:
            f["meas"] = meas.transpose()
        with h5py.File(tmp_path / "tof.mat", "w") as f:
            f["tofgrid"] = tofgrid.transpose()
    got = recon.load_capture(tmp_path / "meas_10min.mat")
    assert got.mode == "confocal" and not got.include_first_last and got.t0_ps == 0.0
    assert got.bin_width_ps == 32.0 and got.kind == "counts"
    T, k0 = cap.n_bins, _k0(cap)
    expect = np.round(np.asarray(cap.spot(0), np.float64) * 1e3)
    assert np.array_equal(np.asarray(got.spot(0))[..., k0:k0 + T], expect)  # rectified exactly, rows in y order
    assert np.allclose(got.pixel_centers, cap.pixel_centers * 2.0)  # 2 m wall by default vs the 1 m synthetic
    one = read_fk_mat(tmp_path / "meas_10min.mat", wall_size_m=1.0, crop_bins=k0 + T)
    assert np.allclose(one.pixel_centers, cap.pixel_centers) and one.n_bins == k0 + T
    rec = recon.reconstruct(one, "fk", voxels=(16, 16, 32), bounds=(-0.5, 0.5, -0.5, 0.5, 0.3, 0.7))
    # the point target is found within one voxel (6.25 cm laterally, 1.25 cm in depth)
    peak = np.asarray(rec.argmax_m())
    assert np.all(np.abs(peak - POINT) <= np.asarray(rec.grid.voxel_size_m) + 1e-9), peak


@pytest.mark.parametrize("order", ["colors_first", "colors_last"])
def test_znlos_confocal_layout(tmp_path, order):
    cap = _confocal(wall=1.0, n=8, first_last=True)
    d = np.asarray(cap.spot(0), np.float64)  # [y, x, t]
    pc = cap.pixel_centers  # [y, x, 3]
    bounces = np.stack([0.25 * d, 0.75 * d], 0)  # two bounce bins summing to the data: [b, y, x, t]
    data = np.transpose(bounces, (3, 0, 1, 2))[None]  # (colors, t, bounces, y, x) -> y-tal: (sy, sx) last
    if order == "colors_last":
        data = np.transpose(data, (4, 3, 2, 1, 0))  # (x, y, bounces, t, colors)
    with h5py.File(tmp_path / "z.hdf5", "w") as f:
        f["data"] = data
        f["deltaT"] = np.float64(cap.bin_width_ps * C_M_PER_PS)
        f["t0"] = np.float64(cap.t0_ps * C_M_PER_PS)
        f["cameraGridPositions"] = np.transpose(np.swapaxes(pc, 0, 1))  # (3, y, x) as stored
        f["cameraGridNormals"] = np.transpose(np.swapaxes(cap.pixel_normals, 0, 1))
        f["laserGridPositions"] = np.transpose(np.swapaxes(pc, 0, 1))
        f["laserGridNormals"] = np.transpose(np.swapaxes(cap.pixel_normals, 0, 1))
        f["cameraPosition"] = cap.detector_origin
        f["laserPosition"] = cap.laser_origin
        f["isConfocal"] = 1
    got = recon.load_capture(tmp_path / "z.hdf5")
    assert got.mode == "confocal" and got.include_first_last
    assert got.t0_ps == pytest.approx(cap.t0_ps) and got.bin_width_ps == pytest.approx(cap.bin_width_ps)
    assert np.allclose(got.pixel_centers, pc)
    assert np.allclose(np.asarray(got.spot(0)), d, rtol=1e-6, atol=1e-12 * d.max())


def test_znlos_exhaustive_layout(tmp_path):
    ny, nx = 3, 2  # (a side of 3 would make the stored grid's axis order ambiguous, as it is for y-tal)
    spots = [[x, y, 0.0] for y in (-0.2, 0.0, 0.2) for x in (-0.3, 0.3)]  # row-major over (ly, lx)
    cap = point_capture([POINT], mode="array", pixels=4, wall_size_m=1.0, sigma_ps=30, bin_width_ps=32,
                        include_first_last=True, spots=spots, spot_grid=(ny, nx))
    d = np.stack([np.asarray(cap.spot(j), np.float64) for j in range(cap.n_files)])  # [spot, sy, sx, t]
    d = d.reshape(ny, nx, *d.shape[1:])  # [ly, lx, sy, sx, t]
    bounces = np.zeros((6,) + d.shape)  # [b, ly, lx, sy, sx, t]
    bounces[2] = d  # all in one bounce bin
    # stored (colors, t, bounces, sy, sx, ly, lx): y-tal moves the axes by (0, 2, 1, 6, 5, 4, 3)
    data = np.transpose(bounces, (5, 0, 3, 4, 1, 2))[None]
    with h5py.File(tmp_path / "z.hdf5", "w") as f:
        f["data"] = data
        f["deltaT"] = np.float64(cap.bin_width_ps * C_M_PER_PS)
        f["t0"] = np.float64(cap.t0_ps * C_M_PER_PS)
        f["cameraGridPositions"] = np.swapaxes(cap.pixel_centers, 0, 1)  # (sx, sy, 3)
        f["laserGridPositions"] = np.swapaxes(np.asarray(cap.spots).reshape(ny, nx, 3), 0, 1)  # (lx, ly, 3)
        f["cameraPosition"] = cap.detector_origin
        f["laserPosition"] = cap.laser_origin
    got = read_znlos(tmp_path / "z.hdf5")
    assert got.mode == "array" and got.n_files == ny * nx and tuple(got.spot_grid) == (ny, nx)
    assert np.allclose(got.spots, cap.spots) and np.allclose(got.pixel_centers, cap.pixel_centers)
    for j in range(cap.n_files):
        assert np.allclose(np.asarray(got.spot(j)), np.asarray(cap.spot(j)), rtol=1e-6)


def test_readers_refuse_other_layouts_in_one_line(tmp_path):
    from transient_core.errors import UserInputError

    scipy.io.savemat(tmp_path / "meas.mat", {"meas": np.zeros((4, 5, 10))})
    with pytest.raises(UserInputError, match=r"meas has shape \(4, 5, 10\); expected \[N, N, T\]"):
        read_fk_mat(tmp_path / "meas.mat")
    with h5py.File(tmp_path / "x.hdf5", "w") as f:
        f["data"] = np.zeros((2, 3, 4))
    with pytest.raises(UserInputError, match="not a ZNLOS file"):
        recon.load_capture(tmp_path / "x.hdf5")
