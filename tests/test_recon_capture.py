"""recon.load_capture / Capture: EXR stacks, lazy per-spot access, geometry, validation errors."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from recon import load_capture
from recon.capture import Capture
from transient_core.errors import UserInputError
from transient_core import stack
from recon.synthetic import point_capture, to_counts, wall_grid
from transient_core.units import C_M_PER_PS

ROOT = Path(__file__).resolve().parents[1]
POINT = [[0.07, -0.04, 0.45]]


def _array_capture(**kw):
    spots = wall_grid(3, 2, (0.4, 0.2)).reshape(-1, 3)
    return point_capture(POINT, mode="array", pixels=(4, 5), spots=spots, spot_grid=(2, 3), sigma_ps=15, **kw)


def test_stack_to_capture_array(tmp_path):
    cap = _array_capture(include_first_last=True)
    stack.write_stack(tmp_path / "c", cap.manifest, cap.data)
    got = load_capture(tmp_path / "c")
    assert got.mode == "array" and got.kind == "ideal" and got.n_files == 6 and got.n_spots == 6
    assert got.shape == cap.shape and got.spot_grid == (2, 3)
    # lazily per spot, and all at once
    for j, h in got.iter_spots():
        np.testing.assert_array_equal(h, cap.data[j])
    np.testing.assert_array_equal(got.data, cap.data)
    np.testing.assert_array_equal(got.spots, cap.spots)
    np.testing.assert_array_equal(got.pixel_centers, cap.pixel_centers)
    np.testing.assert_array_equal(got.laser_origin, cap.laser_origin)
    assert got.include_first_last and got.t0_ps == cap.t0_ps and got.bin_width_ps == cap.bin_width_ps
    np.testing.assert_allclose(got.times_ps, cap.t0_ps + (np.arange(cap.n_bins) + 0.5) * cap.bin_width_ps)
    assert got.manifest == json.loads((tmp_path / "c" / "manifest.json").read_text())


def test_confocal_layout_one_file(tmp_path):
    cap = point_capture(POINT, mode="confocal", pixels=(4, 5), sigma_ps=15)
    stack.write_stack(tmp_path / "c", cap.manifest, cap.data)
    got = load_capture(tmp_path / "c")
    assert got.mode == "confocal" and got.n_files == 1 and got.n_spots == 20
    assert sorted(p.name for p in (tmp_path / "c").glob("*.exr")) == ["spot_00000.exr"]
    # spot k is pixel k's patch (row-major)
    np.testing.assert_array_equal(got.spot_positions(0), got.pixel_centers)


def test_path_offsets_are_first_plus_last_segments():
    cap = _array_capture(include_first_last=True)
    j = 4
    off = cap.path_offsets_m(j)
    want = np.linalg.norm(cap.spots[j] - cap.laser_origin) + np.linalg.norm(cap.pixel_centers - cap.detector_origin, axis=-1)
    np.testing.assert_allclose(off, want, rtol=0, atol=1e-12)
    # the synthetic peak sits where the three-bounce path plus the offsets says
    o = np.array(POINT[0])
    P = cap.pixel_centers[2, 3]
    L = np.linalg.norm(o - cap.spots[j]) + np.linalg.norm(o - P) + off[2, 3]
    peak_t = cap.times_ps[np.argmax(cap.data[j, 2, 3])]
    assert abs(peak_t - L / C_M_PER_PS) <= cap.bin_width_ps
    assert np.all(_array_capture(include_first_last=False).path_offsets_m(j) == 0)


def test_counts_capture_keeps_dtype_and_pulses(tmp_path):
    cap = to_counts(point_capture(POINT, pixels=4, sigma_ps=15), n_pulses=10 ** 6, seed=3)
    stack.write_stack(tmp_path / "c", cap.manifest, cap.data)
    got = load_capture(tmp_path / "c")
    assert got.kind == "counts" and got.data.dtype == np.uint32 and got.n_pulses() == 10 ** 6
    np.testing.assert_array_equal(got.data, cap.data)
    again = to_counts(point_capture(POINT, pixels=4, sigma_ps=15), n_pulses=10 ** 6, seed=3)
    assert again.data.tobytes() == cap.data.tobytes()  # same seed, same bytes


def test_missing_spot_file_is_a_clear_error(tmp_path):
    cap = _array_capture()
    stack.write_stack(tmp_path / "c", cap.manifest, cap.data)
    (tmp_path / "c" / "spot_00003.exr").unlink()
    with pytest.raises(UserInputError, match=r"1 of 6 spot files missing \(spot_00003.exr\).*--resume"):
        load_capture(tmp_path / "c")


def test_incomplete_or_corrupt_stack_errors(tmp_path):
    cap = _array_capture()
    d = tmp_path / "c"
    stack.write_stack(d, cap.manifest, cap.data)
    m = json.loads((d / "manifest.json").read_text())
    m["status"] = "incomplete"
    (d / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(UserInputError, match="status is 'incomplete'"):
        load_capture(d)
    m["status"] = "complete"
    (d / "manifest.json").write_text(json.dumps(m))
    (d / "spot_00002.exr").write_bytes(b"not an exr")
    with pytest.raises(UserInputError, match="spot_00002.exr: not a readable EXR"):
        load_capture(d)


def test_not_a_capture_errors(tmp_path):
    with pytest.raises(UserInputError, match="does not exist"):
        load_capture(tmp_path / "nope")
    (tmp_path / "x.txt").write_text("hello")
    with pytest.raises(UserInputError, match="suffix '.txt'"):
        load_capture(tmp_path / "x.txt")
    cam = stack.new_manifest(kind="ideal", capture="camera", width=2, height=2, n_files=1, t0_ps=0,
                             bin_width_ps=1, n_bins=3, quantity="radiance")
    stack.write_stack(tmp_path / "cam", cam, np.zeros((1, 2, 2, 3), np.float32))
    with pytest.raises(UserInputError, match="capture='camera' is not an NLOS capture"):
        load_capture(tmp_path / "cam")


def test_from_arrays_names_the_mismatch():
    P = wall_grid(4, 3)
    data = np.zeros((2, 3, 4, 10), np.float32)
    with pytest.raises(UserInputError, match=r"spots has shape \(1, 3\), expected \(2, 3\)"):
        Capture.from_arrays(data, spots=[[0, 0, 0]], pixel_centers=P, bin_width_ps=1)
    with pytest.raises(UserInputError, match="data is 3x5 pixels but pixel_centers is 3x4"):
        Capture.from_arrays(np.zeros((1, 3, 5, 10)), spots=[[0, 0, 0]], pixel_centers=P, bin_width_ps=1,
                            laser_origin=[0, 0, 1], detector_origin=[0, 0, 1])
    with pytest.raises(UserInputError, match="include_first_last is true but laser_origin/detector_origin are missing"):
        Capture.from_arrays(data[:1], spots=[[0, 0, 0]], pixel_centers=P, bin_width_ps=1, include_first_last=True)
    with pytest.raises(UserInputError, match="bin_width_ps=0 must be > 0"):
        Capture.from_arrays(data[:1], spots=[[0, 0, 0]], pixel_centers=P, bin_width_ps=0)
    with pytest.raises(UserInputError, match="pixel_normals has vectors of length"):
        Capture.from_arrays(data[:1], spots=[[0, 0, 0]], pixel_centers=P, bin_width_ps=1,
                            pixel_normals=np.full((3, 4, 3), 2.0))
    with pytest.raises(UserInputError, match="kind='counts' needs whole, non-negative numbers"):
        Capture.from_arrays(data[:1] + 0.5, spots=[[0, 0, 0]], pixel_centers=P, bin_width_ps=1, kind="counts")
    with pytest.raises(UserInputError, match=r"spots has shape \(1, 3\), expected \(12, 3\)"):
        Capture.from_arrays(data[:1], mode="confocal", spots=[[0, 0, 0]], pixel_centers=P, bin_width_ps=1)


def test_recon_never_imports_mitsuba():
    code = ("import sys, recon, recon.capture, recon.grid, recon.backprojection, recon.confocal, recon.phasor, "
            "recon.filters, recon.metrics, recon.output, recon.pipeline, recon.preprocess, recon.synthetic, "
            "recon.io.ytal\n"
            "from recon.synthetic import point_capture\n"
            "from recon.pipeline import reconstruct\n"
            "c = point_capture([[0, 0, 0.4]], pixels=4, sigma_ps=20)\n"
            "reconstruct(c, 'bp', voxels=4, threshold='none')\n"
            "assert 'mitsuba' not in sys.modules and 'drjit' not in sys.modules, 'mitsuba imported'\n")
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
