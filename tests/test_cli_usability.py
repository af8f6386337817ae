"""The command line as a newcomer meets it: flags shown as flags, ``1e6`` for integers, progress lines in logs,
the engine message worded as the docs word it."""

from __future__ import annotations

import io
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from detector_helpers import make_ideal_capture
from transient_core.progress import LineProgress, progress_mode
from transient_core.stack import read_manifest

ROOT = Path(__file__).resolve().parents[1]
COMMANDS = [["render"], ["detect"], ["recon"], ["demo"], ["dataset"], ["mannequin"], ["info"],
            ["study", "photon-budget"], ["study", "array-size"]]


def cli(*args, env=None):
    e = dict(os.environ, TRANSIENT_MI_PROGRESS="0", COLUMNS="200")
    e.update(env or {})
    return subprocess.run([sys.executable, "-m", "transient_mi", *map(str, args)], cwd=ROOT, env=e,
                          capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("command", COMMANDS, ids=" ".join)
def test_help_shows_flags_without_a_bool_value(command):
    r = cli(*command, "--help")
    assert r.returncode == 0, r.stderr
    assert "<bool>" not in r.stdout and "--help" in r.stdout
    if command == ["render"]:
        assert re.search(r"--resume\s+Continue", r.stdout), r.stdout


@pytest.fixture(scope="module")
def ideal(tmp_path_factory):
    d = tmp_path_factory.mktemp("usability")
    data = np.zeros((1, 2, 2, 40), np.float32)
    data[..., 20:22] = 1e-3
    make_ideal_capture(d / "ideal", data, bin_width_ps=20.0)
    return d / "ideal"


def test_integer_options_accept_float_notation(ideal, tmp_path):
    r = cli("detect", ideal, "-o", tmp_path / "c", "--pulses", "2e3")
    assert r.returncode == 0, r.stderr
    assert read_manifest(tmp_path / "c")["detector"]["pulses"] == 2000


@pytest.mark.parametrize("value, message", [("1.5", "--pulses 1.5: expected a whole number"),
                                            ("lots", "--pulses 'lots': expected a whole number")])
def test_integer_options_refuse_fractions_in_one_line(ideal, tmp_path, value, message):
    r = cli("detect", ideal, "-o", tmp_path / "c", "--pulses", value)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [f"error: {message} (e.g. 1000000 or 1e6)" +
                                             ("" if value == "lots" else ", not a fraction")]
    assert not (tmp_path / "c").exists()


def test_progress_is_reported_as_periodic_lines_off_a_terminal():
    assert progress_mode(None) in ("bar", "lines", "off")
    t = [0.0]
    out = io.StringIO()
    p = LineProgress("detect x", total=100, interval_s=10, stream=out, clock=lambda: t[0])
    for _ in range(4):  # 25 units every 5 s: a line at 10 s and at 20 s, then the last one
        t[0] += 5
        p.advance(25)
    p.finish()
    lines = out.getvalue().splitlines()
    assert lines == ["detect x: 50 % (50/100), elapsed 0:00:10, eta 0:00:10",
                     "detect x: 100 % (100/100), elapsed 0:00:20, eta 0:00:00",
                     "detect x: 100 % (100/100), elapsed 0:00:20, eta 0:00:00"]
    quiet = io.StringIO()
    q = LineProgress("short", total=3, interval_s=10, stream=quiet, clock=lambda: 0.0)
    q.advance(3)
    q.finish()
    assert quiet.getvalue() == ""  # work shorter than the interval prints nothing


def test_commands_print_progress_lines_into_a_log(ideal, tmp_path):
    env = {"TRANSIENT_MI_PROGRESS_INTERVAL_S": "0"}
    env_no_flag = dict(os.environ, COLUMNS="200", **env)
    env_no_flag.pop("TRANSIENT_MI_PROGRESS", None)
    r = subprocess.run([sys.executable, "-m", "transient_mi", "detect", str(ideal), "-o", str(tmp_path / "c"),
                        "--pulses", "1000"], cwd=ROOT, env=env_no_flag, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert re.search(r"^detect ideal: 100 % \(1000/1000\), elapsed \d+:\d\d:\d\d, eta 0:00:00$", r.stderr, re.M), \
        r.stderr


def test_engine_message_says_what_auto_does_as_the_docs_do():
    from transient_mi.commands.detect import engine_note
    from spad_detector.detect import AUTO_EXACT_MAX_EVENTS

    assert engine_note("auto", True) == " (exact)"
    note = engine_note("auto", False)
    assert "analytic engine is not exact for this capture" in note and f"{AUTO_EXACT_MAX_EVENTS:.0e}" in note
    # (the README's detector section moved to docs/detector.md when the README became a front page)
    docs = " ".join((ROOT / "docs" / "detector.md").read_text().split())
    assert AUTO_EXACT_MAX_EVENTS == 2e7
    assert ("runs the analytic engine wherever it is exact, else the exact engine when it would simulate at most "
            "2e7 events per spot, else the analytic engine") in docs
    assert ("runs the analytic engine when it is exact for the inputs, otherwise the exact engine when it would "
            "simulate at most 2e7 events per spot, otherwise the analytic engine") in docs


def test_pyproject_avoids_the_setuptools_deprecations_that_made_install_output_noisy():
    """`pip install -e .` printed two setuptools warnings: the license as a TOML table (deprecated) and the
    meta-path-finder editable install. Checked by hand with setuptools 84 (no warning left); here the
    configuration that avoids them is pinned, since building a wheel needs the network."""
    import tomllib

    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert isinstance(cfg["project"]["license"], str)  # an SPDX expression
    assert "setuptools>=77" in cfg["build-system"]["requires"]  # the first setuptools that reads it
    assert cfg["tool"]["setuptools"]["package-dir"] == {"": "."}  # flat layout: a plain .pth editable install
