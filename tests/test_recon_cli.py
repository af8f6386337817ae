"""``transient-mi recon`` end to end, through a subprocess like a user runs it."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from transient_core import stack
from recon.io.ytal import write_ytal
from recon.synthetic import point_capture

ROOT = Path(__file__).resolve().parents[1]
POINT = [0.07, -0.04, 0.45]


def cli(*args, cwd=None):
    env = dict(os.environ, TRANSIENT_MI_PROGRESS="0")
    return subprocess.run([sys.executable, "-m", "transient_mi", "recon", *map(str, args)], cwd=cwd or ROOT,
                          env=env, capture_output=True, text=True, timeout=600)


def _user_error(r, *fragments):
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    lines = [ln for ln in r.stderr.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), r.stderr
    assert "Traceback" not in r.stderr
    for f in fragments:
        assert f in lines[0], (f, lines[0])


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    d = tmp_path_factory.mktemp("captures")
    single = point_capture([POINT], pixels=16, wall_size_m=0.8, sigma_ps=20, bin_width_ps=8, include_first_last=True)
    stack.write_stack(d / "single", single.manifest, single.data)
    conf = point_capture([POINT], mode="confocal", pixels=16, wall_size_m=0.8, sigma_ps=20, bin_width_ps=8)
    write_ytal(conf, d / "confocal.h5")
    (d / "truth.json").write_text(json.dumps([POINT]))
    return d


def test_bp_with_ground_truth_writes_everything(captures, tmp_path):
    out = tmp_path / "out"
    r = cli(captures / "single", "-o", out, "--method", "bp", "--voxels", "16",
            "--bounds", "-0.4,0.4,-0.4,0.4,0.2,0.7", "--ground-truth", captures / "truth.json")
    assert r.returncode == 0, r.stderr
    assert "wrote" in r.stdout and "localisation_error_m" in r.stdout
    names = {p.name for p in out.iterdir()}
    assert {"volume.npz", "recon.json", "metrics.json", "projection_x.png", "projection_y.png", "projection_z.png",
            "depth_map.png", "surface.ply", "maps.npz"} <= names
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]        # no temporary left behind
    with np.load(out / "volume.npz") as z:
        assert set(z.files) == {"volume", "raw", "x_m", "y_m", "z_m"}
        assert z["volume"].dtype == np.float32 and z["volume"].shape == (16, 16, 16) == z["raw"].shape
        np.testing.assert_allclose(z["x_m"], -0.4 + (np.arange(16) + 0.5) * 0.05)
        np.testing.assert_allclose(z["z_m"], 0.2 + (np.arange(16) + 0.5) * 0.5 / 16)
        iz, iy, ix = np.unravel_index(np.argmax(z["volume"]), z["volume"].shape)
        found = np.array([z["x_m"][ix], z["y_m"][iy], z["z_m"][iz]])
    vs = np.array([0.05, 0.05, 0.5 / 16])
    assert np.all(np.abs(found - POINT) <= vs)
    m = json.loads((out / "metrics.json").read_text())
    assert m["localisation_error_m"] <= np.linalg.norm(vs)
    meta = json.loads((out / "recon.json").read_text())
    assert meta["method"] == "bp" and meta["filter"]["name"] == "paper" and meta["capture"]["mode"] == "array"


def test_ytal_input_fk_and_phasor(captures, tmp_path):
    r = cli(captures / "confocal.h5", "-o", tmp_path / "fk", "--method", "fk", "--filter", "none", "--no-plots",
            "--voxel-size-m", "0.05")
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in (tmp_path / "fk").iterdir()) == ["maps.npz", "recon.json", "surface.ply", "volume.npz"]
    r = cli(captures / "confocal.h5", "-o", tmp_path / "ph", "--method", "phasor", "--voxels", "16,16,12",
            "--threshold", "otsu", "--no-plots")
    assert r.returncode == 0, r.stderr
    with np.load(tmp_path / "ph" / "volume.npz") as z:
        assert z["volume"].shape == (12, 16, 16)


def test_user_errors(captures, tmp_path):
    _user_error(cli(captures / "single", "-o", tmp_path / "a", "--method", "lct"),
                "--method lct needs a confocal capture", "use bp, fbp or phasor")
    _user_error(cli(captures / "single", "-o", tmp_path / "b", "--bounds", "-0.4,0.4,-0.4,0.4,-0.5,-0.1"),
                "behind the relay wall")
    _user_error(cli(captures / "single", "-o", tmp_path / "c", "--voxels", "8", "--threshold", "abs:1e30"),
                "keeps no voxel")
    _user_error(cli(captures / "single", "-o", tmp_path / "d", "--method", "sart"), "--method 'sart'", "allowed")
    _user_error(cli(captures / "single", "-o", tmp_path / "e", "--voxels", "many"), "--voxels 'many'")
    _user_error(cli(captures / "nowhere", "-o", tmp_path / "f"), "does not exist")
    _user_error(cli(captures / "single", "-o", tmp_path / "g", "--snr", "10"), "snr do not apply to --method bp")
    for name in "abcdefg":
        assert not (tmp_path / name).exists()


def test_missing_spots_and_overwrite(captures, tmp_path):
    cap = point_capture([POINT], pixels=4, spots=[[0, 0, 0], [0.1, 0, 0]], sigma_ps=20)
    stack.write_stack(tmp_path / "two", cap.manifest, cap.data)
    (tmp_path / "two" / "spot_00001.exr").unlink()
    _user_error(cli(tmp_path / "two", "-o", tmp_path / "x"), "spot_00001.exr", "--resume")
    out = tmp_path / "out"
    out.mkdir()
    (out / "old.txt").write_text("keep me unless --overwrite")
    _user_error(cli(captures / "single", "-o", out, "--voxels", "8", "--no-plots"), "exists and is not empty")
    assert (out / "old.txt").exists()
    r = cli(captures / "single", "-o", out, "--voxels", "8", "--no-plots", "--overwrite")
    assert r.returncode == 0, r.stderr
    assert not (out / "old.txt").exists() and (out / "volume.npz").exists()


def test_help_lists_the_options():
    r = cli("--help")
    assert r.returncode == 0
    for opt in ("--method", "--voxel-size-m", "--voxels", "--bounds", "--filter", "--threshold", "--ground-truth",
                "--pileup-correction"):
        assert opt in r.stdout
