"""``transient-mi detect`` through a subprocess: exit codes, one-line errors, no partial output, manifest."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from detector_helpers import make_ideal_capture, poison_spot
from transient_core.stack import read_manifest, read_stack
from spad_detector import param_names

ROOT = Path(__file__).resolve().parents[1]


def _run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "transient_mi", "detect", *map(str, args)], cwd=cwd or ROOT,
                          capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def ideal(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli")
    data = np.zeros((2, 3, 3, 120), np.float32)
    data[..., 60:66] = 2e-3
    make_ideal_capture(d / "ideal", data, bin_width_ps=20.0)
    return d / "ideal"


def test_detect_writes_counts_and_records_every_parameter(ideal, tmp_path):
    out = tmp_path / "counts"
    r = _run(ideal, "-o", out, "--pulses", 20000, "--pde", 0.55, "--dark-count-rate-cps", 300, "--jitter-ps", 40,
             "--gate-open-ps", 800, "--gate-close-ps", 1800, "--gate-transition-ps", 90, "--dead-time-ns", 30,
             "--afterpulse-prob", 0.02, "--crosstalk-prob", 0.01, "--ambient-rate-cps", 1000,
             "--tcspc-max-count-rate-hz", 0, "--seed", 17, "--engine", "exact", "--laser-power-w", 2e-3)
    assert r.returncode == 0, r.stderr
    assert f"wrote {out}" in r.stdout and "engine exact" in r.stdout
    m, data = read_stack(out)
    assert m["kind"] == "counts" and data.dtype == np.uint32 and data[..., 55:75].sum() > 0
    d = m["detector"]
    assert set(param_names()) <= set(d)
    assert (d["pde"], d["dark_count_rate_cps"], d["jitter_ps"], d["gate_open_ps"], d["gate_close_ps"],
            d["gate_transition_ps"], d["dead_time_ns"], d["afterpulse_prob"], d["crosstalk_prob"],
            d["ambient_rate_cps"], d["tcspc_max_count_rate_hz"], d["seed"], d["engine"], d["pulses"],
            d["laser_power_w"]) == (0.55, 300.0, 40.0, 800.0, 1800.0, 90.0, 30.0, 0.02, 0.01, 1000.0, None, 17,
                                    "exact", 20000, 2e-3)
    assert d["resolved"]["photon_scale"] == pytest.approx(2.0)
    assert m["source_ideal"] == str(ideal.resolve())
    # same command, same seed: same bytes
    out2 = tmp_path / "again"
    r2 = _run(ideal, "-o", out2, "--pulses", 20000, "--pde", 0.55, "--dark-count-rate-cps", 300, "--jitter-ps",
              40, "--gate-open-ps", 800, "--gate-close-ps", 1800, "--gate-transition-ps", 90, "--dead-time-ns", 30,
              "--afterpulse-prob", 0.02, "--crosstalk-prob", 0.01, "--ambient-rate-cps", 1000,
              "--tcspc-max-count-rate-hz", 0, "--seed", 17, "--engine", "exact", "--laser-power-w", 2e-3)
    assert r2.returncode == 0
    assert (out / "spot_00001.exr").read_bytes() == (out2 / "spot_00001.exr").read_bytes()


def test_exposure_and_auto_gate(ideal, tmp_path):
    r = _run(ideal, "-o", tmp_path / "c", "--exposure-s", 2e-4, "--auto-gate", "--auto-gate-depth-max-m", 1.0)
    assert r.returncode == 0, r.stderr
    d = read_manifest(tmp_path / "c")["detector"]
    assert d["pulses"] == 10_000 and d["auto_gate"] is True and d["resolved"]["gate"] == "auto_per_spot"
    assert d["auto_gate_depth_max_m"] == 1.0


@pytest.mark.parametrize("args, text", [
    (["--pde", "1.5"], "pde=1.5: allowed in [0, 1]"),
    (["--dark-count-rate-cps", "-1"], "dark_count_rate_cps=-1.0: allowed >= 0"),
    (["--gate-open-ps", "500", "--gate-close-ps", "100"], "gate_close_ps=100.0 <= gate_open_ps=500.0"),
    (["--pulses", "5", "--exposure-s", "1"], "give one of them, not both"),
    (["--auto-gate", "--gate-open-ps", "1", "--gate-close-ps", "2"], "not both"),
    (["--engine", "quantum"], "engine='quantum'"),
    (["--dead-time-model", "sticky"], "dead_time_model='sticky'"),
    (["--repetition-rate-hz", "1e9"], "longer than the laser period"),
])
def test_bad_input_gives_one_line_error_and_no_output(ideal, tmp_path, args, text):
    out = tmp_path / "counts"
    r = _run(ideal, "-o", out, *args)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and text in lines[0], r.stderr
    assert "Traceback" not in r.stderr
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_missing_input_and_bad_spot_data(ideal, tmp_path):
    r = _run(tmp_path / "nope", "-o", tmp_path / "out")
    assert r.returncode == 2 and r.stderr.startswith("error: ") and "does not exist" in r.stderr
    bad = tmp_path / "bad"
    data = np.full((2, 2, 2, 50), 1e-4, np.float32)
    m = make_ideal_capture(bad, data, bin_width_ps=20.0)
    poison_spot(bad, 1, m, -1.0)
    r = _run(bad, "-o", tmp_path / "out")
    assert r.returncode == 2 and "spot_00001.exr[0, 0, 0] = -1.0" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad"]  # no partial output, no temporary dir


def test_help_lists_the_options():
    r = subprocess.run([sys.executable, "-m", "transient_mi", "detect", "--help"], cwd=ROOT, capture_output=True,
                       text=True, timeout=120, env={"COLUMNS": "200", "PATH": "/usr/bin:/bin"})
    assert r.returncode == 0
    for opt in ("--pulses", "--exposure-s", "--pde", "--dark-count-rate-cps", "--jitter-ps", "--gate-open-ps",
                "--gate-close-ps", "--gate-transition-ps", "--auto-gate", "--dead-time-ns", "--afterpulse-prob",
                "--crosstalk-prob", "--seed", "--engine"):
        assert opt in r.stdout, opt
