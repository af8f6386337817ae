"""EXR histogram stack: bit-exact round trips and clear errors for broken captures."""

from __future__ import annotations

import json
import os
import sys

import numpy as np
import pytest

from transient_core import stack


def _manifest(kind="ideal", capture="camera", n_files=1, H=3, W=4, T=7, **kw):
    geo = None
    if capture != "camera":
        n_spots = H * W if capture == "confocal" else n_files
        geo = {
            "laser_origin": [0.5, 0.0, 1.0], "detector_origin": [-0.5, 0.0, 1.0],
            "spots": np.zeros((n_spots, 3)).tolist(), "spot_grid": [1, n_spots],
            "pixel_centers": np.zeros((H, W, 3)).tolist(), "pixel_normals": np.tile([0, 0, 1.0], (H, W, 1)).tolist(),
        }
    return stack.new_manifest(kind=kind, capture=capture, width=W, height=H, n_files=n_files, t0_ps=12.25,
                              bin_width_ps=2.5, n_bins=T, quantity="counts" if kind == "counts" else "radiance",
                              geometry=geo, **kw)


def test_round_trip_is_bit_exact_float_and_uint(tmp_path):
    rng = np.random.default_rng(0)
    m = _manifest(capture="array", n_files=3, T=300)
    a = rng.random((3, 3, 4, 300), dtype=np.float32) * 1e-9
    a[0, 0, 0, :5] = [0.0, np.float32(1e-45), np.finfo(np.float32).max, 1.0, np.float32(3.4e-38)]
    stack.write_stack(tmp_path / "f", m, a)
    m2, b = stack.read_stack(tmp_path / "f")
    assert b.dtype == np.float32 and a.tobytes() == b.tobytes()
    assert m2["status"] == "complete"

    mc = _manifest(kind="counts", T=4100)
    c = rng.integers(0, 2**32, size=(1, 3, 4, 4100), dtype=np.uint64).astype(np.uint32)
    stack.write_stack(tmp_path / "c", mc, c)
    _, d = stack.read_stack(tmp_path / "c")
    assert d.dtype == np.uint32 and c.tobytes() == d.tobytes()
    names = stack.channel_names(4100)
    assert names == sorted(names) and len(set(names)) == 4100


def test_spot_file_is_self_describing(tmp_path):
    import OpenEXR

    m = _manifest(capture="array", n_files=2)
    stack.write_stack(tmp_path / "s", m, np.ones((2, 3, 4, 7), np.float32))
    h = OpenEXR.File(str(tmp_path / "s" / "spot_00001.exr"), header_only=True).header()
    assert h["tmi_kind"] == "ideal" and h["tmi_spot_index"] == 1 and h["tmi_n_files"] == 2
    assert list(h["tmi_time_axis"]) == [12.25, 2.5, 7.0]


def test_missing_spot_names_the_file(tmp_path):
    m = _manifest(capture="array", n_files=3)
    stack.write_stack(tmp_path / "s", m, np.ones((3, 3, 4, 7), np.float32))
    os.remove(tmp_path / "s" / "spot_00001.exr")
    with pytest.raises(stack.StackError, match=r"spot_00001\.exr"):
        stack.read_stack(tmp_path / "s")


def test_truncated_spot_names_the_file(tmp_path):
    m = _manifest(T=200)
    stack.write_stack(tmp_path / "s", m, np.random.default_rng(1).random((1, 3, 4, 200), dtype=np.float32))
    p = tmp_path / "s" / "spot_00000.exr"
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    with pytest.raises(stack.StackError, match=r"spot_00000\.exr"):
        stack.read_stack(tmp_path / "s")


def test_manifest_mismatch_names_the_difference(tmp_path):
    m = _manifest()
    stack.write_stack(tmp_path / "s", m, np.ones((1, 3, 4, 7), np.float32))
    mp = tmp_path / "s" / "manifest.json"
    j = json.loads(mp.read_text())
    j["time"]["n_bins"] = 8
    mp.write_text(json.dumps(j))
    with pytest.raises(stack.StackError, match=r"time axis .* manifest says"):
        stack.read_stack(tmp_path / "s")
    j["time"]["n_bins"] = 7
    j["width"] = 5
    mp.write_text(json.dumps(j))
    with pytest.raises(stack.StackError, match=r"image is 4x3, manifest says 5x3"):
        stack.read_stack(tmp_path / "s")
    j["width"] = 4
    j["format_version"] = 99
    mp.write_text(json.dumps(j))
    with pytest.raises(stack.StackError, match=r"format_version=99"):
        stack.read_stack(tmp_path / "s")


def test_incomplete_capture_is_not_taken_as_complete(tmp_path):
    m = _manifest(capture="array", n_files=2)
    d = tmp_path / "s"
    d.mkdir()
    stack.write_manifest(d, m)
    stack.write_spot(d, 0, np.ones((3, 4, 7), np.float32), m)
    with pytest.raises(stack.StackError, match="spot_00001.exr"):
        stack.read_stack(d)
    stack.write_spot(d, 1, np.ones((3, 4, 7), np.float32), m)
    with pytest.raises(stack.StackError, match="status is 'incomplete'"):
        stack.read_stack(d)


def test_writer_rejects_bad_data(tmp_path):
    m = _manifest()
    d = tmp_path / "s"
    d.mkdir()
    with pytest.raises(stack.StackError, match="shape"):
        stack.write_spot(d, 0, np.ones((3, 4, 6), np.float32), m)
    bad = np.ones((3, 4, 7), np.float32)
    bad[0, 0, 0] = np.nan
    with pytest.raises(stack.StackError, match="finite"):
        stack.write_spot(d, 0, bad, m)
    mc = _manifest(kind="counts")
    with pytest.raises(stack.StackError, match="whole numbers"):
        stack.write_spot(d, 0, np.full((3, 4, 7), 0.5), mc)
    assert list(d.iterdir()) == []  # nothing half-written


def test_not_a_capture_directory(tmp_path):
    with pytest.raises(stack.StackError, match="does not exist"):
        stack.read_manifest(tmp_path / "nope")
    with pytest.raises(stack.StackError, match="manifest.json: missing"):
        stack.read_manifest(tmp_path)
    (tmp_path / "manifest.json").write_text("{not json")
    with pytest.raises(stack.StackError, match="not valid JSON"):
        stack.read_manifest(tmp_path)


def test_stack_reader_needs_no_mitsuba(tmp_path):
    import subprocess

    m = _manifest()
    stack.write_stack(tmp_path / "s", m, np.ones((1, 3, 4, 7), np.float32))
    code = ("import sys; from transient_core.stack import read_stack; m, d = read_stack(sys.argv[1]); "
            "assert d.shape == (1, 3, 4, 7); assert 'mitsuba' not in sys.modules and 'drjit' not in sys.modules")
    r = subprocess.run([sys.executable, "-c", code, str(tmp_path / "s")], capture_output=True, text=True,
                       cwd=os.path.dirname(os.path.dirname(__file__)))
    assert r.returncode == 0, r.stderr


@pytest.mark.parametrize("value", [float("nan"), np.float64("inf"), np.float32("nan")])
def test_manifest_value_that_is_not_finite_is_refused(value):
    # Python and numpy non-finite values alike: a manifest must be plain, finite JSON.
    with pytest.raises(stack.StackError, match="not finite"):
        _manifest(render={"spp": 4, "scale": value})
