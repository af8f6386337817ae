"""How much of a detection's noise is rendering noise, and rendering to a noise target."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import transient_mi  # noqa: F401
from transient_core import stack
from spad_detector import DetectorParams, detect_stack
from spad_detector.model import build_model
from spad_detector.render_noise import NoiseRatio, spp_for_threshold, warning_line

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "nlos_point_targets.xml"
SMALL = {"width": "4", "height": "4", "spots_x": "2", "spots_y": "2", "n_bins": "96", "bin_width_ps": "40",
         "t0_ps": "11000", "include_wall_return": "false"}


def _model(**kw):
    p = DetectorParams(dark_count_rate_cps=0.0, **kw).validate()
    return build_model(p, bin_width_ps=1.0, n_bins=400, t0_ps=0.0)


def test_ratio_closed_form_without_jitter():
    """mu = N pde x, V = N^2 pde^2 s^2: ratio = N pde s^2 / x in every bin (exact)."""
    model = _model(jitter_ps=0.0)
    x, s2, N = 1e-4, 1e-9, 100_000
    ideal = np.full((3, 400), x)
    nr = NoiseRatio()
    nr.add_spot(model, ideal, np.full_like(ideal, s2), N)
    rep = nr.report(spp=64, replicates=8)
    expected = N * 0.7 * s2 / x
    assert rep["ratio"] == pytest.approx(expected, rel=1e-9)
    cls = [c for c in rep["classes"] if c["bins"]]
    assert len(cls) == 1 and cls[0]["counts_above"] == 1.0 and cls[0]["share_of_counts"] == pytest.approx(1.0)
    assert rep["spp_for_threshold"] == spp_for_threshold(64, rep["ratio"], 0.1, 8)
    assert rep["spp_for_threshold"] % 8 == 0 and rep["spp_for_threshold"] >= 64 * expected / 0.1


def test_ratio_of_an_impulse_after_jitter_is_scaled_by_sum_of_squared_taps():
    """One bin of light, jittered: sum V / sum mu = N pde s^2 sum(k^2) / x (kernel inside the window)."""
    model = _model(jitter_ps=25.0)
    x, s2, N = 2e-3, 1e-8, 50_000
    ideal = np.zeros((1, 400))
    ideal[0, 200] = x
    var = np.zeros_like(ideal)
    var[0, 200] = s2
    nr = NoiseRatio()
    nr.add_spot(model, ideal, var, N)
    k2 = float(np.square(model.kernel).sum())
    assert model.kernel.sum() == pytest.approx(1.0, abs=1e-6)
    assert nr.report()["pixel_totals"]["ratio_pooled"] == pytest.approx(N * 0.7 * s2 * k2 / x, rel=1e-6)
    # with the exact total variance the totals ratio is N pde s^2 / x (no jitter averaging for a total)
    nr2 = NoiseRatio()
    nr2.add_spot(model, ideal, var, N, total_variance=np.array([s2]))
    assert nr2.report()["pixel_totals"]["ratio_pooled"] == pytest.approx(N * 0.7 * s2 / x, rel=1e-6)


def test_warning_line_names_ratio_and_spp():
    nr = NoiseRatio(threshold=0.1)
    nr.add_spot(_model(jitter_ps=0.0), np.full((1, 400), 1e-4), np.full((1, 400), 1e-9), 100_000)
    rep = nr.report(spp=64, replicates=8)
    line = warning_line(rep)
    assert line.startswith("warning: rendering noise is 0.7x the photon noise")
    assert f"--spp {rep['spp_for_threshold']} (now 64)" in line and "\n" not in line
    quiet = NoiseRatio(threshold=1.0)
    quiet.add_spot(_model(jitter_ps=0.0), np.full((1, 400), 1e-4), np.full((1, 400), 1e-9), 100_000)
    assert warning_line(quiet.report(spp=64)) is None


@pytest.fixture(scope="module")
def small_capture(tmp_path_factory):
    from transient_mi.render_capture import render

    out = tmp_path_factory.mktemp("noise") / "ideal"
    render(SCENE, out, defines=SMALL, spp=64, seed=3, progress=False)
    return out


def test_capture_stores_variance_files_and_summary(small_capture):
    m = stack.read_manifest(small_capture)
    v = m["variance"]
    assert v["directory"] == "variance" and v["replicates"] == 8 and v["degrees_of_freedom"] == 7
    assert v["summary"]["pixel_total_rel_std"]["median"] > 0
    # the summary, made from the arrays in memory, is the files' read back
    from transient_mi.capture_error import variance_summary

    assert v["summary"] == variance_summary(small_capture, m)
    for j in range(m["n_files"]):
        var, tvar = stack.read_variance(small_capture, j, m)
        assert var.shape == (4, 4, 96) and tvar.shape == (4, 4)
        assert np.all(var >= 0) and var.sum() > 0 and np.all(tvar >= 0)
    # the data readers ignore the variance directory
    assert stack.read_stack(small_capture)[1].shape == (4, 4, 4, 96)


def test_detect_reports_render_noise_and_warns_once(small_capture, tmp_path):
    lines = []
    out = detect_stack(small_capture, tmp_path / "counts", DetectorParams(auto_gate=True), pulses=10**6, seed=1,
                       progress=False, warn=lines.append)
    rn = stack.read_manifest(out)["detector"]["resolved"]["render_noise"]
    assert rn["available"] and rn["ratio"] > 0.1 and rn["exceeds_threshold"]
    assert len(lines) == 1 and lines[0].startswith("warning: rendering noise is")
    assert "variance" not in stack.read_manifest(out)  # the counts capture has no variance files
    # fewer pulses: the photon noise grows faster than the rendering noise (ratio ~ N)
    lines2 = []
    out2 = detect_stack(small_capture, tmp_path / "counts2", DetectorParams(auto_gate=True), pulses=10, seed=1,
                        progress=False, warn=lines2.append, noise_threshold=1e6)
    rn2 = stack.read_manifest(out2)["detector"]["resolved"]["render_noise"]
    assert rn2["pixel_totals"]["ratio_pooled"] < rn["pixel_totals"]["ratio_pooled"] * 1e-3
    assert lines2 == []


def test_detect_says_when_variance_is_unknown(tmp_path):
    from transient_mi.render_capture import render

    ideal = tmp_path / "one_rep"
    render(SCENE, ideal, defines=dict(SMALL, spots_x="1", spots_y="1"), spp=13, seed=0, progress=False)
    m = stack.read_manifest(ideal)
    assert m["variance"]["directory"] is None and "single replicate" in m["variance"]["reason"]
    assert not (ideal / "variance").exists()
    out = detect_stack(ideal, tmp_path / "c", DetectorParams(), pulses=1000, seed=0, progress=False)
    rn = stack.read_manifest(out)["detector"]["resolved"]["render_noise"]
    assert rn == {"available": False, "reason": rn["reason"]} and "no variance" in rn["reason"]


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "transient_mi", *map(str, args)], capture_output=True, text=True,
                          cwd=ROOT, timeout=900)


def test_noise_target_render_meets_target_and_resumes_to_the_same_bytes(tmp_path):
    """render --noise-target: pilot, fresh capture at the chosen spp, ratio met and recorded; resume is exact."""
    from transient_mi.noise_target import PLAN_MARGIN, GroupState, NoiseTargetSpec
    from transient_mi.render_capture import prepare_render, run_render

    defines = dict(SMALL, spots_x="1", spots_y="1")

    def spec():
        return NoiseTargetSpec(target=0.5, params=DetectorParams(auto_gate=True), pulses=50, max_spp=1 << 14)

    a = tmp_path / "a"
    job = prepare_render(SCENE, a, defines=defines, spp=16, seed=7, noise_target=spec())
    logs = []
    run_render(job, progress=False, log=logs.append)
    m = stack.read_manifest(a)
    nt = m["render"]["noise_target"]
    s0 = nt["spots"][0]
    assert s0["pilot_spp"] == 16 and s0["spp"] > 16 and s0["spp"] % 8 == 0
    assert s0["spp"] == spp_for_threshold(16, s0["pilot_ratio"], PLAN_MARGIN * 0.5, 8)
    assert s0["met"] == (s0["ratio"] <= 0.5) and nt["met"] == s0["met"]
    assert any("pilot at spp 16" in line for line in logs)
    assert not (a / ".partial").exists()
    # the ratio detect measures on the capture is the one the render recorded
    out = detect_stack(a, tmp_path / "ac", DetectorParams(auto_gate=True), pulses=50, seed=0, progress=False,
                       warn=lambda line: None)
    rn = stack.read_manifest(out)["detector"]["resolved"]["render_noise"]
    assert rn["ratio"] == pytest.approx(s0["ratio"], rel=1e-5)

    # interrupted after three replicates of the capture, then resumed: the same bytes
    b = tmp_path / "b"
    calls = {"n": 0}
    orig = GroupState.merge

    def failing_merge(self, other):
        calls["n"] += 1
        if calls["n"] == 3:
            raise KeyboardInterrupt
        return orig(self, other)

    GroupState.merge = failing_merge
    try:
        with pytest.raises(KeyboardInterrupt):
            run_render(prepare_render(SCENE, b, defines=defines, spp=16, seed=7, noise_target=spec()),
                       progress=False, log=lambda line: None)
    finally:
        GroupState.merge = orig
    assert (b / ".partial" / "group_00000.npz").is_file()
    logs_b = []
    run_render(prepare_render(SCENE, b, defines=defines, spp=16, seed=7, noise_target=spec(), resume=True),
               progress=False, log=logs_b.append)
    assert any("resumed" in line for line in logs_b) and not any("pilot" in line for line in logs_b)
    for name in ("spot_00000.exr", "variance/spot_00000.exr"):
        assert (a / name).read_bytes() == (b / name).read_bytes(), name


def test_noise_target_bad_input_is_one_line(tmp_path):
    r = _cli("render", SCENE, "-o", tmp_path / "x", "--noise-target", "-1")
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        "error: --noise-target -1.0: must be a finite number > 0 (e.g. 0.1)"]
    r = _cli("render", SCENE, "-o", tmp_path / "y", "--noise-target", "0.1", "--spp", "13")
    assert r.returncode == 2 and "needs >= 2 independent replicates" in r.stderr and len(r.stderr.splitlines()) == 1
    r = _cli("render", ROOT / "scenes" / "cornell_box.xml", "-o", tmp_path / "z", "--noise-target", "0.1")
    assert r.returncode == 2 and "no photon budget" in r.stderr
    r = _cli("render", SCENE, "-o", tmp_path / "w", "--pulses", "1000")
    assert r.returncode == 2 and "only used with --noise-target" in r.stderr
    assert not any((tmp_path / n).exists() for n in "xyzw")
