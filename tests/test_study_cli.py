"""``transient-mi study photon-budget|array-size``: end to end on tiny settings, and bad input."""

from __future__ import annotations

import csv
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def cli(*args):
    env = dict(os.environ, TRANSIENT_MI_PROGRESS="0")
    return subprocess.run([sys.executable, "-m", "transient_mi", *map(str, args)], capture_output=True, text=True,
                          cwd=ROOT, env=env, timeout=600)


def test_photon_budget_command(tmp_path):
    out = tmp_path / "pb"
    r = cli("study", "photon-budget", "-o", out, "-D", "array=4", "-D", "spp=32", "--exposures-ms", "1e-3,0.1",
            "--dark-count-rates-cps", "25", "--dark-count-rates-cps", "1e5", "--dead-times-ns", "10", "--seeds", "2",
            "--voxels", "16,16,8", "--quick")
    assert r.returncode == 0, r.stderr
    assert "wrote" in r.stdout
    with open(out / "results.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 2 * 2 * 1 * 2
    assert sorted({float(x["exposure_s"]) for x in rows}) == [1e-6, 1e-4]
    assert {float(x["dark_count_rate_cps"]) for x in rows} == {25.0, 1e5}
    for name in ("summary.md", "error_vs_photons.png", "snr_vs_photons.png", "timings.csv", "snr_bins.csv"):
        assert (out / name).is_file(), name


def test_array_size_command(tmp_path):
    out = tmp_path / "as"
    r = cli("study", "array-size", "-o", out, "--arrays", "4", "-D", "spp=32", "--exposure-ms", "1", "--voxels", "16",
            "--quick")
    assert r.returncode == 0, r.stderr
    with open(out / "results.csv") as f:
        rows = list(csv.DictReader(f))
    assert [int(x["array"]) for x in rows] == [4] and float(rows[0]["chamfer_m"]) > 0
    assert (out / "array_size.png").is_file() and (out / "summary.md").is_file()


def test_help_lists_both_studies():
    r = cli("study", "--help")
    assert r.returncode == 0 and "photon-budget" in r.stdout and "array-size" in r.stdout


def test_bad_input_exit_status_2_one_line_no_output(tmp_path):
    out = tmp_path / "never"
    r = cli("study", "photon-budget", "-o", out, "--exposures-ms", "-1")
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: --exposures-ms") and "-1" in lines[0]
    assert "Traceback" not in r.stderr and not out.exists()


@pytest.mark.parametrize("args, match", [
    (["photon-budget", "--exposures-ms", "abc"], "--exposures-ms 'abc'"),
    (["photon-budget", "--exposures-ms", "0"], "--exposures-ms: 0.0"),
    (["photon-budget", "--dead-times-ns", "-5"], "--dead-times-ns: -5.0"),
    (["photon-budget", "--dark-count-rates-cps", "nan"], "--dark-count-rates-cps: nan"),
    (["photon-budget", "--laser-powers-w", "0"], "--laser-powers-w: 0.0"),
    (["photon-budget", "--seeds", "1"], "--seeds 1"),
    (["photon-budget", "--voxels", "1,2"], "--voxels 1,2"),
    (["photon-budget", "--voxels", "a"], "--voxels 'a'"),
    (["photon-budget", "-D", "bogus=1"], "has no parameter 'bogus'"),
    (["photon-budget", "-D", "array"], "-D 'array'"),
    (["photon-budget", "-D", "spp=many"], "-D spp='many'"),
    (["photon-budget", "no_such_scene"], "SCENE 'no_such_scene'"),
    (["photon-budget", "--ground-truth", "/no/such.ply"], "does not exist"),
    (["array-size", "--arrays", "4,x"], "--arrays '4,x'"),
    (["array-size", "--arrays", "0"], "--arrays '0'"),
    (["array-size", "--exposure-ms", "0"], "--exposure-ms 0"),
    (["array-size", "--seed", "-1"], "--seed -1"),
    (["array-size", "-D", "array=8"], "set by the study"),
    (["methods", "--fit", "mesh,cube"], "fit='cube': allowed mannequin, patches, mesh"),
    (["methods", "--fit", "mesh", "--fit-iterations", "mesh=x"], "--fit-iterations 'x': expected a whole number"),
    (["methods", "--fit", "mesh", "--fit-iterations", "=4"], "--fit-iterations '=4': expected N or MODEL=N"),
    (["methods", "--fit", "mesh", "--fit-iterations", "patches=4"], "'patches' is not one of the fitted models mesh"),
    (["methods", "--fit", "mesh", "--fit-arrays", "mesh=8,x"], "--fit-arrays '8,x'"),
    (["methods", "--fit", "mannequin,mesh", "--fit-arrays", "mesh=64"], "fit_arrays=[64]: each must be one of"),
])
def test_bad_input_messages(tmp_path, capsys, args, match):
    """In process (fast): each mistake is one line naming the option and value, status 2, nothing written."""
    import transient_mi  # noqa: F401
    from transient_mi.cli import main

    out = tmp_path / "out" / "study"
    code = main(["study", args[0], "-o", str(out), *args[1:]])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("error: ") and match in err[0], err
    assert not (tmp_path / "out").exists()


def test_per_model_fit_options_parse():
    """``--fit-iterations`` and ``--fit-arrays`` take one value for every fitted model or ``MODEL=...`` per model."""
    from transient_mi.commands.study import _fit_arrays, _fit_iterations

    assert _fit_iterations("40") == 40 and _fit_iterations("1e2") == 100
    assert _fit_iterations("mannequin=300,mesh=40") == {"mannequin": 300, "mesh": 40}
    assert _fit_arrays("8,16") == (8, 16)
    assert _fit_arrays("mannequin=8,16;mesh=8") == {"mannequin": (8, 16), "mesh": (8,)}


def test_existing_output_is_refused(tmp_path, capsys):
    import transient_mi  # noqa: F401
    from transient_mi.cli import main

    out = tmp_path / "full"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    assert main(["study", "array-size", "-o", str(out), "--arrays", "4"]) == 2
    assert "not empty" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["keep.txt"]
