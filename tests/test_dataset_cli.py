"""``transient-mi dataset`` from the command line: bad specs fail before any work, --dry-run writes nothing."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
GOOD = """\
scene: cornell_box
seed: 1
spp: 2
defines: {width: 8, height: 8, n_bins: 50, bin_width_ps: 600}
grid:
  max_depth: [2, 3]
"""


def cli(*args, env=None):
    return subprocess.run([sys.executable, "-m", "transient_mi", *map(str, args)], capture_output=True, text=True,
                          cwd=ROOT, env=dict(os.environ, TRANSIENT_MI_PROGRESS="0", **(env or {})), timeout=600)


def one_line_error(r, message):
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    lines = [ln for ln in r.stderr.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in r.stderr, r.stderr
    assert message in lines[0], lines[0]


@pytest.mark.parametrize("spec,message", [
    # a -D the scene does not have (checked against the scene before anything runs)
    (GOOD + "random:\n  fov: {uniform: [20, 40]}\n", "random.fov: scene cornell_box.xml has no parameter $fov"),
    # a value the scene rejects, at the end of a grid (the scene is loaded at each grid value)
    (GOOD.replace("max_depth: [2, 3]", "n_bins: [50, 0]").replace("n_bins: 50, ", ""),
     "grid.n_bins = 0: "),
    (GOOD + "gird: {}\n", "unknown key 'gird' in the spec"),
    (GOOD + "random:\n  t0_ps: {uniform: [11000, 9000]}\n", "random.t0_ps.uniform: [11000, 9000] is an empty range"),
    (GOOD + "random:\n  t0_ps: {poisson: [3]}\n", "random.t0_ps: unknown key 'poisson'"),
    (GOOD.replace("cornell_box", "cornell_boxx"), "scene: 'cornell_boxx' is neither a file"),
    ("scene: [cornell_box\n", "not valid YAML"),
])
def test_bad_spec_fails_before_any_work(tmp_path, spec, message):
    p = tmp_path / "spec.yaml"
    p.write_text(spec)
    out = tmp_path / "out"
    r = cli("dataset", p, "-o", out)
    one_line_error(r, message)
    assert not out.exists()


def test_bad_output_fails_before_any_work(tmp_path):
    p = tmp_path / "spec.yaml"
    p.write_text(GOOD)
    one_line_error(cli("dataset", p, "-o", "/proc/transient-mi-dataset"), "cannot create a directory in /proc")
    blocker = tmp_path / "file"
    blocker.write_text("x")
    one_line_error(cli("dataset", p, "-o", blocker), "exists and is not a directory")
    one_line_error(cli("dataset", p, "-o", blocker / "sub"), "does not exist")
    full = tmp_path / "full"
    full.mkdir()
    (full / "notes.txt").write_text("mine")
    one_line_error(cli("dataset", p, "-o", full), "is not empty and holds no transient-mi dataset")
    one_line_error(cli("dataset", tmp_path / "nope.yaml", "-o", tmp_path / "o"), "spec file")
    one_line_error(cli("dataset", p, "-o", tmp_path / "o", "--scheduler", "tcp://127.0.0.1:9", "--workers", "2"),
                   "--workers 2 with --scheduler")
    assert sorted(q.name for q in tmp_path.iterdir()) == ["file", "full", "spec.yaml"]


def test_unreachable_scheduler_fails_before_writing(tmp_path):
    p = tmp_path / "spec.yaml"
    p.write_text(GOOD)
    out = tmp_path / "out"
    r = cli("dataset", p, "-o", out, "--scheduler", "tcp://127.0.0.1:9",
            env={"DASK_DISTRIBUTED__COMM__TIMEOUTS__CONNECT": "2s"})  # dask's connect timeout, shortened
    one_line_error(r, "--scheduler tcp://127.0.0.1:9: cannot connect")
    assert not out.exists()


def test_dry_run_lists_the_plan_and_writes_nothing(tmp_path):
    p = tmp_path / "spec.yaml"
    p.write_text(GOOD)
    out = tmp_path / "out"
    r = cli("dataset", p, "-o", out, "--dry-run")
    assert r.returncode == 0, r.stderr
    assert "2 items; varied: define.max_depth" in r.stdout and "item_000001: render_seed=" in r.stdout
    assert "dry run: 2 items, 0 already done, 2 to build" in r.stdout
    assert not out.exists()
