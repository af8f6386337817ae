"""`transient-mi render` on NLOS scenes: streaming per spot, resume, kill -9, bad input."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from transient_core import stack
from transient_mi.scenes import scene_path

ROOT = Path(__file__).resolve().parents[1]
SCENE = scene_path("nlos_point_targets")
#: small array capture: 72 spots (12 x 6, two spot groups: 64 + 8) of 8 x 8 pixels
SMALL = ["-D", "width=8", "-D", "height=8", "-D", "spots_x=12", "-D", "spots_y=6", "-D", "spot_spacing_m=0.05",
         "-D", "n_bins=128", "-D", "bin_width_ps=64"]
N_SPOTS = 72


def _cli(*args, **kw):
    env = dict(os.environ, PYTHONPATH=str(ROOT), TRANSIENT_MI_PROGRESS="0")
    return subprocess.run([sys.executable, "-m", "transient_mi", *map(str, args)], capture_output=True,
                          text=True, env=env, cwd=ROOT, **kw)


def _popen(*args):
    env = dict(os.environ, PYTHONPATH=str(ROOT), TRANSIENT_MI_PROGRESS="0")
    return subprocess.Popen([sys.executable, "-m", "transient_mi", *map(str, args)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, env=env, cwd=ROOT)


def _wait_for(pred, timeout=120.0):
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        if pred():
            return True
        time.sleep(0.005)
    return False


def _complete_looking_files_are_complete(d: Path):
    """Every file with a final spot name is a complete, valid spot; the capture is not complete."""
    m = stack.read_manifest(d)
    assert m["status"] == "incomplete"
    for p in sorted(d.glob("spot_*.exr")):
        j = int(p.stem.split("_")[1])
        assert stack.spot_is_complete(d, j, m)
        data = stack.read_spot(d, j, m)
        assert data.shape == (8, 8, 128) and np.all(np.isfinite(data))
    with pytest.raises(stack.StackError):
        stack.read_stack(d)


def test_array_capture_streams_resumes_and_survives_kill_9(tmp_path):
    ref = tmp_path / "ref"
    r = _cli("render", SCENE, "-o", ref, "--spp", 256, "--seed", 5, *SMALL)
    assert r.returncode == 0, r.stderr
    m_ref, d_ref = stack.read_stack(ref)
    assert m_ref["n_files"] == N_SPOTS and m_ref["capture"] == "array" and m_ref["status"] == "complete"
    assert m_ref["quantity"] == "photons_per_pulse"
    assert len(m_ref["geometry"]["spots"]) == N_SPOTS and m_ref["geometry"]["spot_grid"] == [6, 12]
    assert d_ref.sum() > 0 and (ref / "preview.png").is_file()

    out = tmp_path / "killed"
    args = ("render", SCENE, "-o", out, "--spp", 256, "--seed", 5, *SMALL)
    # 1) kill -9 as early as possible (once the capture directory has its manifest)
    p = _popen(*args)
    assert _wait_for(lambda: (out / "manifest.json").exists() or p.poll() is not None)
    p.send_signal(signal.SIGKILL)
    p.wait()
    if (out / "manifest.json").exists():
        _complete_looking_files_are_complete(out)
    # 2) resume, and kill -9 again once the first new spot file appears
    before = set(out.glob("spot_*.exr")) if out.exists() else set()
    p = _popen(*args, "--resume")
    assert _wait_for(lambda: len(set(out.glob("spot_*.exr")) - before) > 0 or p.poll() is not None)
    p.send_signal(signal.SIGKILL)
    p.wait()
    _complete_looking_files_are_complete(out)
    written = sorted(x.name for x in out.glob("spot_*.exr"))
    assert 0 < len(written) < N_SPOTS, written
    # 3) resume to the end: same bytes as the uninterrupted render
    mtimes = {x.name: x.stat().st_mtime_ns for x in out.glob("spot_*.exr")}
    r = _cli(*args, "--resume")
    assert r.returncode == 0, r.stderr
    for name, t in mtimes.items():  # complete spots were skipped, not re-rendered
        assert (out / name).stat().st_mtime_ns == t
    m_out, d_out = stack.read_stack(out)
    assert m_out["status"] == "complete"
    assert d_out.tobytes() == d_ref.tobytes()
    for j in range(N_SPOTS):
        assert (out / stack.spot_filename(j)).read_bytes() == (ref / stack.spot_filename(j)).read_bytes()
    assert m_out["render"]["config_sha256"] == m_ref["render"]["config_sha256"]
    assert not [x for x in out.iterdir() if x.name.startswith(".")]  # no temporary files left behind


def test_confocal_capture_is_one_file(tmp_path):
    out = tmp_path / "conf"
    r = _cli("render", SCENE, "-o", out, "--spp", 16, "-D", "capture=confocal", "-D", "width=6", "-D", "height=5",
             "-D", "n_bins=64", "-D", "bin_width_ps=128")
    assert r.returncode == 0, r.stderr
    m, d = stack.read_stack(out)
    assert m["capture"] == "confocal" and m["n_files"] == 1 and d.shape == (1, 5, 6, 64)
    g = m["geometry"]
    assert np.array(g["spots"]).shape == (30, 3) and g["spot_grid"] == [5, 6]
    # spot k is the centre of pixel k's patch (row-major)
    np.testing.assert_allclose(np.array(g["spots"]).reshape(5, 6, 3), np.array(g["pixel_centers"]), atol=1e-6)
    assert m["laser"]["photons_per_pulse"] == pytest.approx(0.1 / 50e6 / (6.62607015e-34 * 299792458 / 1550e-9))


BAD = [
    (["-D", "spots_x=20", "-D", "spot_spacing_m=0.1"], "off the relay wall"),
    (["-D", "pixel_footprint_m=0"], "pixel_footprint_m=0 must be > 0"),
    (["-D", "width=64"], "larger than the relay wall"),
    (["-D", "detector_origin=0.2, 0.1, -1.0"], "behind the relay wall"),
    (["-D", "laser_origin=0.2, 0.1, -1.0"], "behind the relay wall"),
    (["-D", "capture=both"], "capture='both'"),
    (["-D", "spot_spacing_m=0", "-D", "spots_x=2"], "spot_spacing_m=0 must be > 0"),
]


@pytest.mark.parametrize("defines,message", BAD, ids=[b[1] for b in BAD])
def test_bad_input_one_line_error_exit_2_no_output(tmp_path, defines, message):
    out = tmp_path / "out"
    r = _cli("render", SCENE, "-o", out, *defines)
    assert r.returncode == 2, (r.stdout, r.stderr)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), r.stderr
    assert message in lines[0], lines[0]
    assert "Traceback" not in r.stderr
    assert not out.exists()
