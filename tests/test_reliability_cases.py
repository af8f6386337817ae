"""The cases of issue 28 that a newcomer hit with bad input, each refused in one line (exit 2, no traceback,
nothing written). The two render resume cases of that issue (``--noise-target`` resume: ``TypeError`` on the
per-spot results; plain resume: a ``variance/.spot_*.tmp`` left and other dropped-light figures) are in
tests/test_fault_injection.py (``noise_target-before_rename@manifest.json:2``, ``nlos-before_rename@...``)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from fault_helpers import ROOT, run_cli
from recon.synthetic import point_capture
from transient_core import stack


def _refused(r, *fragments):
    assert r.code == 2, (r.code, r.out, r.err)
    lines = [ln for ln in r.err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), r.err
    assert "Traceback" not in r.err
    for f in fragments:
        assert f in lines[0], (f, lines[0])


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    d = tmp_path_factory.mktemp("cases")
    cap = point_capture([[0.0, 0.0, 0.4]], pixels=6, wall_size_m=0.8, sigma_ps=20, bin_width_ps=16)
    stack.write_stack(d / "capture", cap.manifest, cap.data)
    return d / "capture"


def test_recon_refuses_time_downsample_zero(tmp_path, capture):
    r = run_cli("recon", capture, "-o", tmp_path / "out", "--time-downsample", "0", "--voxels", "8")
    _refused(r, "--time-downsample 0", ">= 1")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("content", [b"hello, this is a text file\n", b"x" * 300, b""],
                         ids=["short-text", "long-text", "empty"])
def test_recon_refuses_a_file_named_mat_that_is_not_matlab(tmp_path, content):
    fake = tmp_path / "fake.mat"
    fake.write_bytes(content)
    r = run_cli("recon", fake, "-o", tmp_path / "out")
    _refused(r, str(fake))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fake.mat"]


def test_scene_mesh_refuses_a_scene_that_is_not_nlos(tmp_path):
    r = run_cli("scene-mesh", ROOT / "scenes" / "cornell_box.xml", "-o", tmp_path / "m.ply")
    _refused(r, "cornell_box.xml", "not an NLOS scene", "spad_array")
    assert list(tmp_path.iterdir()) == []


def _ytal(tmp_path, capture) -> Path:
    h5 = tmp_path / "full.h5"
    r = run_cli("export", capture, h5, "--to", "ytal")
    assert r.code == 0, r.err
    return h5


def test_view_refuses_a_truncated_hdf5_file(tmp_path, capture):
    full = _ytal(tmp_path, capture)
    trunc = tmp_path / "trunc.h5"
    trunc.write_bytes(full.read_bytes()[: full.stat().st_size // 2])
    # a child process: a viewer that accepted the file would serve until the timeout
    r = subprocess.run([sys.executable, "-c", "import sys; from transient_cli import main; sys.exit(main())", "view", str(trunc),
                        "--no-browser", "--port", "0"],
                       cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    assert r.stderr.strip().splitlines() == [r.stderr.strip()] and "trunc.h5: not a readable HDF5 file" in r.stderr
    assert "serving at" not in r.stdout


def test_video_refuses_an_unwritable_place(tmp_path, capture):
    r = run_cli("video", capture, "-o", "/proc/rel.gif")
    _refused(r, "-o /proc/rel.gif", "cannot create")
    ro = tmp_path / "ro"
    ro.mkdir()
    r = run_cli("video", capture, "-o", ro)
    _refused(r, "suffix")
    assert list(ro.iterdir()) == []
