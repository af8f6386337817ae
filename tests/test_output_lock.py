"""One writer per output directory (``transient_core.lock``), stale locks and temporaries, and the commands using it."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from detector_helpers import make_ideal_capture
from transient_core import lock as _lock
from transient_core.errors import UserInputError
from transient_core import stack
from recon.synthetic import point_capture

ROOT = Path(__file__).resolve().parents[1]
CBOX = ROOT / "scenes" / "cornell_box.xml"


def cli(*args):
    env = dict(os.environ, TRANSIENT_MI_PROGRESS="0")
    return subprocess.run([sys.executable, "-m", "transient_mi", *map(str, args)], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=600)


def _one_line_error(r, *fragments):
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    lines = [ln for ln in r.stderr.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), r.stderr
    for f in fragments:
        assert f in lines[0], (f, lines[0])


@pytest.fixture
def live_owner():
    """A live process other than this one (``sleep``) and a function writing its lock record for an output."""
    proc = subprocess.Popen(["sleep", "300"])

    def hold(out: Path) -> Path:
        path = _lock.lock_path(out)
        path.parent.mkdir(parents=True, exist_ok=True)
        rec = dict(_lock.owner_record("transient-mi render (the other run)"), pid=proc.pid,
                   start_ticks=_lock.process_start_ticks(proc.pid))
        path.write_text(json.dumps(rec))
        return path

    yield hold
    proc.kill()
    proc.wait()


def _dead_pid() -> int:
    p = subprocess.Popen(["true"])
    p.wait()
    return p.pid


def test_lock_file_names_its_owner_and_is_removed_after(tmp_path):
    out = tmp_path / "out"
    with _lock.output_lock(out) as path:
        rec = json.loads(path.read_text())
        assert path == tmp_path / ".out.lock"
        assert rec["pid"] == os.getpid() and rec["host"] == socket.gethostname()
        assert rec["start_ticks"] == _lock.process_start_ticks(os.getpid()) is not None
        with _lock.output_lock(out):  # re-entrant within one process (render -> detect)
            pass
        assert path.exists()
    assert not path.exists() and list(tmp_path.iterdir()) == []


def test_second_process_is_refused_while_the_first_holds_the_lock(tmp_path):
    out = tmp_path / "out"
    code = ("import sys; from transient_core.lock import output_lock; from transient_core.errors import UserInputError\n"
            "try:\n    output_lock(sys.argv[1]).__enter__()\nexcept UserInputError as e:\n    print(e); sys.exit(3)\n")
    with _lock.output_lock(out):
        r = subprocess.run([sys.executable, "-c", code, str(out)], cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 3, r.stderr
    assert "another run is writing this output" in r.stdout and f"pid {os.getpid()}" in r.stdout


def test_live_owner_refuses(tmp_path, live_owner):
    out = tmp_path / "out"
    path = live_owner(out)
    with pytest.raises(UserInputError, match="another run is writing this output"):
        _lock.acquire(out)
    assert path.exists()


@pytest.mark.parametrize("stale", ["dead_pid", "reused_pid", "garbage"])
def test_stale_lock_is_taken_over(tmp_path, stale):
    out = tmp_path / "out"
    path = _lock.lock_path(out)
    rec = _lock.owner_record("old run")
    if stale == "dead_pid":
        rec["pid"] = _dead_pid()
        rec["start_ticks"] = None
    elif stale == "reused_pid":  # this very pid, but a process that started at another time
        rec["start_ticks"] = _lock.process_start_ticks(os.getpid()) - 1
    path.write_text("{not json" if stale == "garbage" else json.dumps(rec))
    if stale == "garbage":
        os.utime(path, (0, 0))  # an unreadable lock older than the grace period
    with _lock.output_lock(out):
        assert json.loads(path.read_text())["pid"] == os.getpid()
    assert not path.exists()


def test_lock_from_another_host_is_not_taken_over(tmp_path):
    out = tmp_path / "out"
    path = _lock.lock_path(out)
    path.write_text(json.dumps(dict(_lock.owner_record("x"), host="elsewhere", pid=_dead_pid())))
    with pytest.raises(UserInputError, match=f"on elsewhere.*remove {path}"):
        _lock.acquire(out)


def test_stale_temporaries_of_the_output_are_removed_others_kept(tmp_path):
    out = tmp_path / "det"
    (tmp_path / ".det.ab12cd_9.tmp").mkdir()  # a killed detect's temporary directory
    (tmp_path / ".det.ab12cd_9.tmp" / "spot_00000.exr").write_bytes(b"x")
    (tmp_path / ".det.zz99yy88.old").mkdir()  # a killed replace_dir's moved-aside result
    keep = [tmp_path / ".det.x.ab12cd_9.tmp", tmp_path / ".detector.ab12cd_9.tmp", tmp_path / "det.ab12cd_9.tmp"]
    for k in keep:
        k.mkdir()
    with _lock.output_lock(out):
        pass
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(k.name for k in keep)


def test_missing_parents_created_for_the_lock_are_removed_after_a_refusal(tmp_path, live_owner):
    out = tmp_path / "a" / "b" / "out"
    with pytest.raises(UserInputError):
        with _lock.output_lock(out):
            raise UserInputError("bad input found under the lock")
    assert list(tmp_path.iterdir()) == []


# --- the commands ----------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    d = tmp_path_factory.mktemp("lock_inputs")
    cap = point_capture([[0.0, 0.0, 0.4]], pixels=8, wall_size_m=0.8, sigma_ps=20, bin_width_ps=8)
    stack.write_stack(d / "capture", cap.manifest, cap.data)
    data = np.zeros((1, 2, 2, 64), np.float32)
    data[..., 30:34] = 1e-3
    make_ideal_capture(d / "ideal", data, bin_width_ps=20.0)
    return d


@pytest.mark.parametrize("command", ["render", "detect", "recon", "study", "demo"])
def test_every_writing_command_refuses_an_output_another_run_holds(tmp_path, inputs, live_owner, command):
    out = tmp_path / "out"
    path = live_owner(out)
    args = {
        "render": ["render", CBOX, "-o", out, "-D", "width=4", "-D", "height=4", "-D", "n_bins=20", "--spp", "1"],
        "detect": ["detect", inputs / "ideal", "-o", out, "--pulses", "100"],
        "recon": ["recon", inputs / "capture", "-o", out, "--voxels", "8"],
        "study": ["study", "array-size", "-o", out, "--arrays", "2", "--quick"],
        "demo": ["demo", "--quick", "-o", out],
    }[command]
    r = cli(*args)
    _one_line_error(r, f"{out}: another run is writing this output", "the other run")
    assert not out.exists() and path.exists()


def test_detect_removes_a_killed_runs_temporary_directory(tmp_path, inputs):
    stale = tmp_path / ".counts.k1ll3d_x.tmp"
    stale.mkdir()
    (stale / "manifest.json").write_text("{}")
    r = cli("detect", inputs / "ideal", "-o", tmp_path / "counts", "--pulses", "100")
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["counts"]


def test_exact_engine_estimates_its_work_and_refuses_past_the_limit_unless_forced(tmp_path, inputs, monkeypatch):
    from spad_detector import stream as det_stack

    # 2x2 pixels x 4 bins x 1e-3 photons per pulse, PDE 0.3 -> ~4.8e-3 events per pulse: 1e4 pulses ~ 48 events
    monkeypatch.setattr(det_stack, "EXACT_MAX_EVENTS", 10.0)
    with pytest.raises(UserInputError, match=r"engine=exact: .* simulated photon events .*4e\+04 pixel-pulses.*"
                                             r"--force"):
        det_stack.detect_stack(inputs / "ideal", tmp_path / "c", pulses=10_000, engine="exact", progress=False)
    assert list(tmp_path.iterdir()) == []
    det_stack.detect_stack(inputs / "ideal", tmp_path / "c", pulses=10_000, engine="exact", progress=False,
                           force=True)
    assert stack.read_manifest(tmp_path / "c")["detector"]["resolved"]["engines_used"] == ["exact"]


@pytest.mark.parametrize("args, message", [
    (["--spp", "0"], "--spp 0: must be >= 1"),
    (["-D", "spp=0"], "sample_count is 0"),
])
def test_render_refuses_zero_samples_per_pixel(tmp_path, args, message):
    out = tmp_path / "out"
    r = cli("render", CBOX, "-o", out, "-D", "width=4", "-D", "height=4", "-D", "n_bins=20", *args)
    _one_line_error(r, message)
    assert list(tmp_path.iterdir()) == []
