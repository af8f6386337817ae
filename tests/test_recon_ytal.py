"""y-tal HDF5 interop: layout facts and exact round trips EXR stack -> capture -> HDF5 -> capture."""

import h5py
import numpy as np
import pytest
import yaml

from recon import load_capture
from transient_core.errors import UserInputError
from transient_core import stack
from recon.io.ytal import GRIDFORMAT, HFORMAT, KEYS, read_ytal, write_ytal
from recon.synthetic import point_capture, to_counts, wall_grid
from transient_core.units import C_M_PER_PS

POINT = [[0.07, -0.04, 0.45]]


def _captures():
    spots = wall_grid(3, 2, (0.4, 0.2)).reshape(-1, 3)
    return {
        "confocal": point_capture(POINT, mode="confocal", pixels=(4, 5), sigma_ps=15, include_first_last=True),
        "exhaustive": point_capture(POINT, mode="array", pixels=(4, 5), spots=spots, spot_grid=(2, 3), sigma_ps=15),
        "single": point_capture(POINT, mode="array", pixels=(3, 2), sigma_ps=15, bin_width_ps=7.3),
        "counts": to_counts(point_capture(POINT, mode="array", pixels=(3, 2), sigma_ps=15), 10 ** 8, seed=1),
    }


@pytest.mark.parametrize("name", ["confocal", "exhaustive", "single", "counts"])
def test_round_trip_exact(tmp_path, name):
    cap = _captures()[name]
    stack.write_stack(tmp_path / "stack", cap.manifest, cap.data)
    c1 = load_capture(tmp_path / "stack")
    write_ytal(c1, tmp_path / "x.h5")
    c2 = load_capture(tmp_path / "x.h5")
    assert c2.data.dtype == c1.data.dtype
    np.testing.assert_array_equal(c2.data, c1.data)
    for attr in ("spots", "spot_normals", "pixel_centers", "pixel_normals", "laser_origin", "detector_origin"):
        np.testing.assert_array_equal(getattr(c2, attr), getattr(c1, attr), err_msg=attr)
    for attr in ("mode", "kind", "t0_ps", "bin_width_ps", "n_bins", "include_first_last", "n_files", "spot_grid"):
        assert getattr(c2, attr) == getattr(c1, attr), attr
    assert c2.manifest == c1.manifest
    if name == "counts":  # counts above 2^24 are not exact in float32: stored as float64
        assert c1.data.max() >= 2 ** 24
        with h5py.File(tmp_path / "x.h5") as f:
            assert f["H"].dtype == np.float64
    # and back to a stack: same bytes of data
    stack.write_stack(tmp_path / "stack2", c2.manifest, c2.data)
    np.testing.assert_array_equal(stack.read_stack(tmp_path / "stack2")[1], cap.data)


def test_layout_facts_confocal(tmp_path):
    cap = _captures()["confocal"]
    write_ytal(cap, tmp_path / "c.h5")
    with h5py.File(tmp_path / "c.h5") as f:
        assert set(f.keys()) <= set(KEYS)
        H = f["H"][()]
        assert H.shape == (cap.n_bins, cap.width, cap.height)            # (T, Sx, Sy)
        np.testing.assert_array_equal(H[:, 3, 1], cap.data[0, 1, 3, :])     # H[t, x, y] = data[y, x, t]
        assert int(f["H_format"][0]) == HFORMAT["T_Sx_Sy"]
        assert h5py.check_enum_dtype(f["H_format"].dtype) is not None
        assert int(f["sensor_grid_format"][0]) == GRIDFORMAT["X_Y_3"]
        np.testing.assert_array_equal(f["sensor_grid_xyz"][3, 1], cap.pixel_centers[1, 3])
        np.testing.assert_array_equal(f["laser_grid_xyz"][()], f["sensor_grid_xyz"][()])  # confocal
        assert f["delta_t"][()] == pytest.approx(cap.bin_width_ps * C_M_PER_PS, rel=1e-15)
        assert f["t_start"][()] == pytest.approx(cap.t0_ps * C_M_PER_PS, rel=1e-15)
        assert bool(f["t_accounts_first_and_last_bounces"][()]) is True
        np.testing.assert_array_equal(f["sensor_xyz"][()], cap.detector_origin)
        np.testing.assert_array_equal(f["laser_xyz"][()], cap.laser_origin)
        info = yaml.safe_load(f["scene_info"][()])
        assert info["transient_mi_manifest"]["capture"] == "confocal"


def test_layout_facts_exhaustive(tmp_path):
    cap = _captures()["exhaustive"]
    write_ytal(cap, tmp_path / "e.h5")
    ny, nx = cap.spot_grid
    with h5py.File(tmp_path / "e.h5") as f:
        H = f["H"]
        assert H.shape == (cap.n_bins, nx, ny, cap.width, cap.height)    # (T, Lx, Ly, Sx, Sy)
        j = 4                                                             # spot row 1, column 1
        iy, ix = divmod(j, nx)
        np.testing.assert_array_equal(H[:, ix, iy, 2, 3], cap.data[j, 3, 2, :])
        np.testing.assert_array_equal(f["laser_grid_xyz"][ix, iy], cap.spots[j])
        assert int(f["H_format"][0]) == HFORMAT["T_Lx_Ly_Sx_Sy"]


def test_import_plain_ytal_file(tmp_path):
    """A file as y-tal writes it (no transient-mi manifest): metres -> ps, grids transposed, float data."""
    T, Sx, Sy = 40, 3, 2
    H = np.random.default_rng(0).random((T, Sx, Sy)).astype(np.float32)
    xs, ys = np.array([-0.1, 0.0, 0.1]), np.array([-0.05, 0.05])
    grid = np.stack(np.meshgrid(xs, ys, [0.0], indexing="ij"), -1)[:, :, 0, :]   # (Sx, Sy, 3)
    with h5py.File(tmp_path / "y.h5", "w") as f:
        f["H"] = H
        dt = h5py.enum_dtype(HFORMAT, basetype="i")
        f.create_dataset("H_format", (1,), dtype=dt)[0] = 1
        f["sensor_xyz"] = np.array([0.0, -0.5, 1.0])
        f["laser_xyz"] = np.array([0.2, -0.5, 1.0])
        f["sensor_grid_xyz"] = grid
        f["laser_grid_xyz"] = np.array([[[0.0, 0.0, 0.0]]])
        f["delta_t"] = 0.003
        f["t_start"] = 0.6
        f["t_accounts_first_and_last_bounces"] = False
        f["scene_info"] = yaml.safe_dump({"original_format": "HDF5_TAL"})
    c = read_ytal(tmp_path / "y.h5")
    assert c.mode == "array" and c.n_spots == 1 and (c.height, c.width) == (Sy, Sx)
    assert c.bin_width_ps == pytest.approx(0.003 / C_M_PER_PS) and c.t0_ps == pytest.approx(0.6 / C_M_PER_PS)
    np.testing.assert_array_equal(c.spot(0)[1, 2], H[:, 2, 1])
    np.testing.assert_array_equal(c.pixel_centers[1, 2], grid[2, 1])
    np.testing.assert_array_equal(c.pixel_normals[..., 2], 1.0)                   # absent normals: +z


def test_unsupported_ytal_layouts(tmp_path):
    with h5py.File(tmp_path / "f.h5", "w") as f:
        f["H"] = np.zeros((4, 3), np.float32)
        f.create_dataset("H_format", (1,), dtype=h5py.enum_dtype(HFORMAT, basetype="i"))[0] = HFORMAT["T_Si"]
        f["sensor_grid_xyz"] = np.zeros((3, 3))
        f["laser_grid_xyz"] = np.zeros((1, 3))
        f["delta_t"] = 0.001
    with pytest.raises(UserInputError, match="H_format='T_Si' is not supported"):
        read_ytal(tmp_path / "f.h5")
    with h5py.File(tmp_path / "g.h5", "w") as f:
        f["H"] = np.zeros((4, 3), np.float32)
        f["extra_key"] = 1
    with pytest.raises(UserInputError, match="unexpected keys"):
        read_ytal(tmp_path / "g.h5")
    (tmp_path / "h.h5").write_bytes(b"garbage")
    with pytest.raises(UserInputError, match="not a readable HDF5 file"):
        load_capture(tmp_path / "h.h5")
