"""``transient-mi render``: outputs, determinism, and one-line errors with no partial output."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from transient_core import stack

ROOT = Path(__file__).resolve().parents[1]
CBOX = ROOT / "scenes" / "cornell_box.xml"
SMALL = ["-D", "width=16", "-D", "height=12", "-D", "n_bins=200", "-D", "bin_width_ps=100", "--spp", "4"]


def cli(*args, env=None):
    e = dict(os.environ, TRANSIENT_MI_PROGRESS="0")
    e.update(env or {})
    return subprocess.run([sys.executable, "-m", "transient_mi", *map(str, args)], capture_output=True, text=True,
                          cwd=ROOT, env=e, timeout=600)


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    out = tmp_path_factory.mktemp("r") / "cb"
    r = cli("render", CBOX, "-o", out, *SMALL, "--seed", "7")
    assert r.returncode == 0, r.stderr
    return out, r


def test_render_writes_stack_and_preview(rendered):
    out, r = rendered
    m, data = stack.read_stack(out)
    assert data.shape == (1, 12, 16, 200) and data.dtype == np.float32
    assert m["kind"] == "ideal" and m["capture"] == "camera" and m["status"] == "complete"
    assert m["render"]["spp"] == 4 and m["render"]["seed"] == 7 and m["render"]["defines"]["width"] == "16"
    assert m["render"]["variant"] == "llvm_ad_mono" and len(m["render"]["scene_sha256"]) == 64
    assert (out / "preview.png").stat().st_size > 1000
    assert data.sum() > 0
    assert "wrote" in r.stdout


def test_same_seed_same_bytes_on_disk(rendered, tmp_path):
    out, _ = rendered
    again = tmp_path / "again"
    r = cli("render", CBOX, "-o", again, *SMALL, "--seed", "7")
    assert r.returncode == 0, r.stderr
    assert (out / "spot_00000.exr").read_bytes() == (again / "spot_00000.exr").read_bytes()
    other = tmp_path / "other"
    assert cli("render", CBOX, "-o", other, *SMALL, "--seed", "8").returncode == 0
    assert (out / "spot_00000.exr").read_bytes() != (other / "spot_00000.exr").read_bytes()


def test_existing_output_is_not_overwritten(rendered):
    out, _ = rendered
    r = cli("render", CBOX, "-o", out, *SMALL)
    assert r.returncode == 2 and "exists and is not empty" in r.stderr and "--resume" in r.stderr


def test_resume_with_other_settings_is_refused(rendered):
    out, _ = rendered
    r = cli("render", CBOX, "-o", out, *SMALL, "--seed", "9", "--resume")
    assert r.returncode == 2 and "seed: 7 then, 9 now" in r.stderr


@pytest.mark.parametrize("args,message", [
    (["-D", "n_bins=0"], "n_bins=0 must be an integer >= 1"),
    (["-D", "n_bins=-4"], "n_bins=-4 must be an integer >= 1"),
    (["-D", "bin_width_ps=0"], "bin_width_ps=0 must be > 0"),
    (["-D", "bin_width_ps=-5"], "bin_width_ps=-5 must be > 0"),
    (["--variant", "llvm_ad_bogus"], "variant='llvm_ad_bogus' is not available"),
    (["-D", "width"], "-D 'width': expected name=value"),
    (["-D", "3x=1"], "'3x' is not a valid parameter name"),
    (["-D", "nonexistent=1"], "unused parameters"),
    (["--spp", "-3"], "--spp -3"),
    (["--variant", "scalar_rgb"], "cannot render"),
])
def test_bad_input_one_line_error_no_output(tmp_path, args, message):
    out = tmp_path / "out"
    r = cli("render", CBOX, "-o", out, *args)
    assert r.returncode == 2, r.stderr
    lines = [ln for ln in r.stderr.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0], r.stderr
    assert "Traceback" not in r.stderr
    assert not out.exists()


def test_a_shipped_scene_is_rendered_by_name(rendered, tmp_path):
    """``render cornell_box`` (no such file here): the shipped scene, the same bytes as by its path."""
    assert not (ROOT / "cornell_box").exists()
    out = tmp_path / "by_name"
    r = cli("render", "cornell_box", "-o", out, *SMALL, "--seed", "7")
    assert r.returncode == 0, r.stderr
    assert np.array_equal(stack.read_stack(out)[1], stack.read_stack(rendered[0])[1])
    assert stack.read_manifest(out)["render"]["scene_file"].endswith("transient_mi/scenes/cornell_box.xml")
    r = cli("render", "no_such_scene", "-o", tmp_path / "o")
    assert r.returncode == 2 and r.stderr.strip() == "error: scene file 'no_such_scene' does not exist"


def test_missing_scene_and_unwritable_output(tmp_path):
    r = cli("render", tmp_path / "nope.xml", "-o", tmp_path / "o")
    assert r.returncode == 2 and r.stderr.strip() == f"error: scene file '{tmp_path / 'nope.xml'}' does not exist"
    blocker = tmp_path / "file"
    blocker.write_text("x")
    r = cli("render", CBOX, "-o", blocker / "sub" / "out")
    assert r.returncode == 2 and "is not a directory" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    r = cli("render", CBOX, "-o", "/proc/transient-mi-out")  # read-only filesystem, even for root
    assert r.returncode == 2 and "cannot create a directory in /proc" in r.stderr
    assert not (tmp_path / "o").exists()


def test_malformed_xml_is_one_line(tmp_path):
    bad = tmp_path / "bad.xml"
    bad.write_text("<scene version='3.0.0'><integrator type='transient_path'>")
    r = cli("render", bad, "-o", tmp_path / "o")
    assert r.returncode == 2 and r.stderr.startswith(f"error: {bad}") and len(r.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_rgb_variant_renders_rgb_per_bin_and_is_recorded(tmp_path):
    out = tmp_path / "rgb"
    r = cli("render", CBOX, "-o", out, *SMALL, "--variant", "llvm_ad_rgb")
    assert r.returncode == 0, r.stderr
    m, data = stack.read_stack(out)
    assert m["render"]["variant"] == "llvm_ad_rgb" and data.shape == (1, 12, 16, 200, 3) and data.sum() > 0
    assert m["channels"] == ["R", "G", "B"] and m["intensity"] == "luminance"
    # the preview and any reader of one intensity see the luminance
    assert stack.intensity(data, m).shape == (1, 12, 16, 200) and (out / "preview.png").is_file()


def test_plugins_follow_a_variant_switch():
    code = """
import transient_mi as tm, mitsuba as mi
for v in ["llvm_ad_rgb", "llvm_ad_mono"]:
    tm.set_variant(v)
    d = mi.cornell_box()
    d["sensor"]["film"] = {"type": "transient_film", "width": 8, "height": 8, "n_bins": 100, "bin_width_ps": 300.0}
    d["integrator"] = {"type": "transient_path", "max_depth": 3}
    s = mi.load_dict(d)
    res = s.integrator().render_transient(s, s.sensors()[0], spp=2)
    assert mi.variant() == v and res.histogram.sum() > 0, v
print("ok")
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert r.returncode == 0 and "ok" in r.stdout, r.stderr


def test_missing_parent_directories_are_created(tmp_path):
    out = tmp_path / "a" / "b" / "cb"
    r = cli("render", CBOX, "-o", out, *SMALL)
    assert r.returncode == 0, r.stderr
    assert stack.read_manifest(out)["status"] == "complete"
