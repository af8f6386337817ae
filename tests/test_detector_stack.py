"""detect_stack: capture in, counts capture out; manifest contents, atomicity, auto gate, budget."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from detector_helpers import LASER, make_ideal_capture, poison_spot
from transient_core.errors import UserInputError
from transient_core.stack import read_manifest, read_spot, read_stack
from transient_core.units import C_M_PER_PS
from stats_helpers import ALPHA, z_bound
from spad_detector import DetectorParams, detect_stack, param_names, three_bounce_range_ps

T, W_PS = 300, 16.0


def _ideal(tmp_path, name="ideal", S=2, H=3, W=4, flux=1e-3, **kw):
    data = np.zeros((S, H, W, T), np.float32)
    data[..., 200:210] = flux
    return tmp_path / name, make_ideal_capture(tmp_path / name, data, bin_width_ps=W_PS, **kw)


def test_counts_capture_has_counts_manifest_and_every_parameter(tmp_path):
    src, m_ideal = _ideal(tmp_path)
    params = DetectorParams(pde=0.6, dark_count_rate_cps=100.0, gate_open_ps=2800.0, gate_close_ps=3600.0,
                            afterpulse_prob=0.01)
    out = detect_stack(src, tmp_path / "counts", params, pulses=20_000, seed=3, engine="analytic",
                       progress=False)
    m, data = read_stack(out)
    assert m["kind"] == "counts" and m["quantity"] == "counts" and m["status"] == "complete"
    assert data.dtype == np.uint32 and data.shape == (2, 3, 4, T)
    d = m["detector"]
    for name in param_names():
        assert name in d, name
    assert d["pde"] == 0.6 and d["dark_count_rate_cps"] == 100.0 and d["afterpulse_prob"] == 0.01
    assert d["pulses"] == 20_000 and d["seed"] == 3 and d["engine"] == "analytic"
    assert d["jitter_convention"] == "FWHM" and d["resolved"]["engines_used"] == ["analytic", "analytic"]
    assert d["resolved"]["exact"] is False  # afterpulsing is first order in the analytic engine
    for key in ("geometry", "render", "time", "include_first_last", "capture"):
        assert m[key] == m_ideal[key], key
    assert m["laser"] == m_ideal["laser"]
    assert m["source_ideal"] == str(src.resolve())
    assert data[..., 200:210].sum() > 0


def test_same_seed_same_bytes_on_disk(tmp_path):
    src, _ = _ideal(tmp_path)
    p = DetectorParams()
    a = detect_stack(src, tmp_path / "a", p, pulses=5000, seed=1, progress=False)
    b = detect_stack(src, tmp_path / "b", p, pulses=5000, seed=1, progress=False)
    c = detect_stack(src, tmp_path / "c", p, pulses=5000, seed=2, progress=False)
    for j in range(2):
        name = f"spot_{j:05d}.exr"
        assert (a / name).read_bytes() == (b / name).read_bytes()
    assert read_stack(a)[1].tobytes() != read_stack(c)[1].tobytes()
    # spots draw from their own streams: spot 1 is independent of spot 0
    assert not np.array_equal(read_spot(a, 0), read_spot(a, 1))


def test_on_spot_gets_each_spots_ideal_and_counts_as_written(tmp_path):
    """``on_spot(j, ideal, counts)`` is called once per spot, in order, with the ideal histograms as the capture
    holds them and the counts as written (the demo sums both without reading the files back); the counts are the
    same bytes as without it."""
    src, _ = _ideal(tmp_path)
    seen = []
    out = detect_stack(src, tmp_path / "counts", DetectorParams(), pulses=5000, seed=1, progress=False,
                       on_spot=lambda j, ideal, counts: seen.append((j, ideal.copy(), counts.copy())))
    plain = detect_stack(src, tmp_path / "plain", DetectorParams(), pulses=5000, seed=1, progress=False)
    assert [j for j, _, _ in seen] == [0, 1]
    for j, ideal, counts in seen:
        assert ideal.dtype == np.float32 and np.array_equal(ideal, read_spot(src, j))
        assert counts.dtype == np.uint32 and np.array_equal(counts, read_spot(out, j))
        assert (out / f"spot_{j:05d}.exr").read_bytes() == (plain / f"spot_{j:05d}.exr").read_bytes()


def test_bad_spot_data_leaves_nothing_behind(tmp_path):
    src, m = _ideal(tmp_path)
    poison_spot(src, 1, m, float("nan"))
    before = set(p.name for p in tmp_path.iterdir())
    with pytest.raises(UserInputError, match=r"spot_00001.exr\[0, 0, 0\] = nan"):
        detect_stack(src, tmp_path / "counts", DetectorParams(), pulses=1000, progress=False)
    assert set(p.name for p in tmp_path.iterdir()) == before  # no output, no temporary directory


def test_parameters_are_validated_before_any_work(tmp_path):
    src, _ = _ideal(tmp_path)
    for params, kw, text in [
        (DetectorParams(pde=2.0), {}, "pde=2.0"),
        (DetectorParams(), {"pulses": 1, "exposure_s": 1.0}, "not both"),
        (DetectorParams(repetition_rate_hz=1e9), {}, "longer than the laser period"),
        (DetectorParams(), {"engine": "quantum"}, "engine='quantum'"),
        (DetectorParams(), {"seed": -4}, "seed=-4"),
    ]:
        with pytest.raises(UserInputError, match=text):
            detect_stack(src, tmp_path / "out", params, progress=False, **kw)
        assert not (tmp_path / "out").exists()
    with pytest.raises(UserInputError, match="is the ideal capture itself"):
        detect_stack(src, src, DetectorParams(), progress=False)
    counts = detect_stack(src, tmp_path / "counts", DetectorParams(), pulses=10, progress=False)
    with pytest.raises(UserInputError, match="kind='counts'"):
        detect_stack(counts, tmp_path / "again", DetectorParams(), progress=False)
    with pytest.raises(UserInputError, match="already holds a capture"):
        detect_stack(src, counts, DetectorParams(), pulses=10, progress=False)


def test_into_a_render_directory_and_overwrite(tmp_path):
    out = tmp_path / "render"
    out.mkdir()
    (out / "preview.png").write_bytes(b"png")
    src, _ = _ideal(out)
    detect_stack(src, out, DetectorParams(), pulses=1000, progress=False)
    m = read_manifest(out)
    assert m["source_ideal"] == "ideal" and (out / "preview.png").exists() and read_manifest(src)["kind"] == "ideal"
    first = read_stack(out)[1]
    with pytest.raises(UserInputError, match="already holds a capture"):
        detect_stack(src, out, DetectorParams(), pulses=1000, progress=False)
    detect_stack(src, out, DetectorParams(), pulses=1000, seed=5, progress=False, overwrite=True)
    assert read_manifest(out)["detector"]["seed"] == 5 and read_stack(out)[1].tobytes() != first.tobytes()
    assert not [p for p in out.iterdir() if p.name.startswith(".")]


def test_laser_power_override_scales_the_signal(tmp_path):
    src, _ = _ideal(tmp_path, flux=2e-4)
    quiet = dict(dark_count_rate_cps=0.0, jitter_ps=0.0)
    a = detect_stack(src, tmp_path / "a", DetectorParams(**quiet), pulses=50_000, progress=False)
    b = detect_stack(src, tmp_path / "b", DetectorParams(laser_power_w=3e-3, **quiet), pulses=50_000,
                     progress=False)
    mb = read_manifest(b)
    assert math.isclose(mb["detector"]["resolved"]["photon_scale"], 3.0, rel_tol=1e-12)
    assert math.isclose(mb["laser"]["photons_per_pulse"], 3 * LASER["photons_per_pulse"], rel_tol=1e-12)
    ka, kb = read_stack(a)[1].sum(), read_stack(b)[1].sum()
    # low flux (0.0014 / 0.0042 detections per cycle, 2 blind cycles after each): rates p / (1 + 2 p)
    pa, pb = 1 - math.exp(-0.7 * 2e-3), 1 - math.exp(-0.7 * 6e-3)
    n = 2 * 3 * 4 * 50_000
    for k, p in ((ka, pa), (kb, pb)):
        r = p / (1 + 2 * p)
        assert abs(k - n * r) <= 3 * math.sqrt(n * r)
    e = detect_stack(src, tmp_path / "e", DetectorParams(**quiet), exposure_s=1e-3, progress=False)
    assert read_manifest(e)["detector"]["pulses"] == 50_000


def test_confocal_capture_refuses_crosstalk(tmp_path):
    data = np.zeros((1, 2, 2, T), np.float32)
    data[..., 100] = 1e-3
    make_ideal_capture(tmp_path / "conf", data, bin_width_ps=W_PS, capture="confocal")
    with pytest.raises(UserInputError, match="confocal capture's pixels were recorded under different laser"):
        detect_stack(tmp_path / "conf", tmp_path / "c", DetectorParams(crosstalk_prob=0.01), progress=False)
    detect_stack(tmp_path / "conf", tmp_path / "c", DetectorParams(), pulses=100, progress=False)
    assert read_manifest(tmp_path / "c")["capture"] == "confocal"


def test_auto_gate_passes_the_hidden_volume_and_suppresses_the_first_bounce(tmp_path):
    S, H, W = 1, 4, 4
    data = np.zeros((S, H, W, T), np.float32)
    data[..., 0:3] = 30.0  # the wall's first-bounce return: very strong, at ~0 ps
    # a hidden point 0.5 m in front of the wall: three-bounce arrival per pixel
    m = make_ideal_capture(tmp_path / "ideal", data, bin_width_ps=W_PS)
    geo = m["geometry"]
    o = np.array([0.0, 0.0, 0.5])
    S0 = np.array(geo["spots"][0])
    P = np.array(geo["pixel_centers"]).reshape(-1, 3)
    t = (np.linalg.norm(o - S0) + np.linalg.norm(P - o, axis=1)) / C_M_PER_PS
    b = (t / W_PS).astype(int).reshape(H, W)
    for y in range(H):
        for x in range(W):
            data[0, y, x, b[y, x]] = 2e-3
    make_ideal_capture(tmp_path / "ideal2", data, bin_width_ps=W_PS)
    ungated = read_stack(detect_stack(tmp_path / "ideal2", tmp_path / "u", DetectorParams(), pulses=20_000,
                                      progress=False))[1]
    gated_dir = detect_stack(tmp_path / "ideal2", tmp_path / "g", DetectorParams(auto_gate=True),
                             pulses=20_000, progress=False)
    gated = read_stack(gated_dir)[1]
    # without the gate the first bounce takes every cycle the TCSPC is ready: no three-bounce counts
    assert ungated[..., :3].sum() > 0.9 * ungated.sum() and ungated[..., 100:].sum() == 0
    # with it, the first bounce is gone and the hidden point is seen in every pixel
    assert gated[..., :20].sum() == 0
    sig = np.array([gated[0, y, x, b[y, x] - 6:b[y, x] + 7].sum() for y in range(H) for x in range(W)])
    p = 1 - math.exp(-0.7 * 2e-3)
    exp = 20_000 * p / (1 + 2 * p)
    assert np.all(np.abs(sig - exp) <= 3 * math.sqrt(exp) + 0.01 * exp)  # jitter loses < 1 % outside +-6 bins
    res = read_manifest(gated_dir)["detector"]["resolved"]
    assert res["gate"] == "auto_per_spot" and res["gate_open_ps"] < t.min() - 120.0 and res["gate_close_ps"] > t.max()
    assert res["gate_open_ps_per_spot"] == [res["gate_open_ps"]] and res["gate_close_ps_per_spot"] == [res["gate_close_ps"]]


def test_per_spot_auto_gate_blocks_a_strong_return_and_keeps_the_signal(tmp_path):
    """A strong return 800 ps before each spot's earliest three-bounce arrival (the paper geometry's
    first-bounce margin is >= 767 ps) gives no counts; the hidden point is still seen."""
    S, H, W = 2, 3, 3
    m = make_ideal_capture(tmp_path / "probe", np.zeros((S, H, W, T), np.float32), bin_width_ps=W_PS, t0_ps=-1000.0)
    geo = m["geometry"]
    spots = np.array(geo["spots"])
    P = np.array(geo["pixel_centers"]).reshape(-1, 3)
    o = np.array([0.0, 0.0, 0.5])
    windows = [three_bounce_range_ps(m, 0.1, 1.5, spot=j) for j in range(S)]
    data = np.zeros((S, H, W, T), np.float32)
    for j in range(S):
        # a strong return 800 ps before spot j's earliest three-bounce arrival
        b_first = int((windows[j][0] - 800.0 - m["time"]["t0_ps"]) / W_PS)
        assert b_first >= 0
        data[j, ..., b_first] = 30.0
        t = (np.linalg.norm(o - spots[j]) + np.linalg.norm(P - o, axis=1)) / C_M_PER_PS
        for k, tk in enumerate(t):
            data[j, k // W, k % W, int((tk - m["time"]["t0_ps"]) / W_PS)] += 2e-3
    make_ideal_capture(tmp_path / "ideal", data, bin_width_ps=W_PS, t0_ps=-1000.0)
    counts = read_stack(detect_stack(tmp_path / "ideal", tmp_path / "g", DetectorParams(auto_gate=True),
                                     pulses=20_000, progress=False))[1]
    for j in range(S):
        b_first = int((windows[j][0] - 800.0 - m["time"]["t0_ps"]) / W_PS)
        w = int(100.0 / W_PS) + 1  # +-100 ps around the return (the jitter's spread)
        assert counts[j, ..., b_first - w:b_first + w + 1].sum() == 0
    # the signal: each pixel detects a pulse with p = 1 - exp(-PDE x 2e-3) and the TCSPC's 50 ns blinds 2 whole
    # 20 ns cycles after each count, so its mean is N p / (1 + 2 p) (renewal law, as in the test above; dark counts
    # add ~1e-2 per pixel). The counts are sub-Poisson, so sqrt(mean) over-estimates their sd: the bound's
    # false-failure rate is at most ALPHA for the family of S spots.
    p = 1 - math.exp(-0.7 * 2e-3)
    expected = H * W * 20_000 * p / (1 + 2 * p)
    for j in range(S):
        assert abs(counts[j].sum() - expected) <= z_bound(ALPHA, S) * math.sqrt(expected), (j, counts[j].sum())


def test_three_bounce_range_bounds_the_hidden_volume(tmp_path):
    _, m = _ideal(tmp_path, S=3, include_first_last=True)
    t_early, t_late = three_bounce_range_ps(m, 0.2, 0.9)
    geo = m["geometry"]
    rng = np.random.default_rng(0)
    pts = np.c_[rng.uniform(-0.5, 0.5, 20000), rng.uniform(-0.5, 0.5, 20000), rng.uniform(0.2, 0.9, 20000)]
    corners = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (0.2, 0.9)])
    S = np.array(geo["spots"])
    P = np.array(geo["pixel_centers"]).reshape(-1, 3)
    lo, de = np.array(geo["laser_origin"]), np.array(geo["detector_origin"])

    def times(o):
        d = (np.linalg.norm(o[:, None, None] - S[None, :, None], axis=-1)
             + np.linalg.norm(o[:, None, None] - P[None, None, :], axis=-1)
             + np.linalg.norm(S - lo, axis=-1)[None, :, None] + np.linalg.norm(P - de, axis=-1)[None, None, :])
        return d / C_M_PER_PS

    ts = times(pts)
    assert t_early <= ts.min() and t_late >= ts.max()
    assert math.isclose(t_late, times(corners).max(), rel_tol=1e-12)  # the latest arrival is exact
    assert ts.min() - t_early < 0.05 / C_M_PER_PS  # and the earliest is tight


def test_manifest_is_plain_json(tmp_path):
    src, _ = _ideal(tmp_path)
    out = detect_stack(src, tmp_path / "counts", DetectorParams(auto_gate=True), pulses=100, progress=False)
    m = json.loads((out / "manifest.json").read_text())
    assert m["detector"]["auto_gate"] is True and m["detector"]["resolved"]["gate"] == "auto_per_spot"


def test_one_window_cannot_gate_every_spot_but_per_spot_windows_can(tmp_path):
    """Laser and detector 2.2 m off to the side (the paper scene): far spots' first-bounce returns arrive
    after near spots' earliest three-bounce light, so a window shared by all spots would pass them, while
    each spot's own window opens after its own return (triangle inequality: every three-bounce path from
    S is longer than L -> S -> D)."""
    S_pos = [[x, 0.0, 0.0] for x in (-0.375, -0.125, 0.125, 0.375)]
    m = make_ideal_capture(tmp_path / "side", np.zeros((4, 4, 4, T), np.float32), bin_width_ps=W_PS,
                           spots=S_pos, include_first_last=True)
    geo = m["geometry"]
    geo["laser_origin"] = geo["detector_origin"] = [-2.0, 0.0, 1.0]
    L = np.array(geo["laser_origin"])
    first = [2 * np.linalg.norm(np.array(s) - L) / C_M_PER_PS for s in S_pos]
    shared = three_bounce_range_ps(m, 0.25, 0.75)
    own = [three_bounce_range_ps(m, 0.25, 0.75, spot=j) for j in range(4)]
    assert shared[0] < max(first)  # a shared window would let a first-bounce return in
    for j in range(4):
        assert own[j][0] - 120.0 - first[j] > 10 * 47.0  # gate 50 % point > 10 edge sigmas after the return
        assert own[j][0] >= shared[0] and own[j][1] <= shared[1]
