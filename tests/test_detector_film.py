"""``spad_film``: a transient_film carrying the detector parameters, validated when the scene loads."""

from __future__ import annotations

import pytest

import transient_mi  # noqa: F401  (first: LLVM + plug-ins)
import mitsuba as mi

from spad_detector import DetectorParams


def _film(**kw):
    d = {"type": "spad_film", "width": 4, "height": 3, "n_bins": 64, "bin_width_ps": 8.0, "t0_ps": 100.0}
    d.update(kw)
    return mi.load_dict(d)


def test_spad_film_is_a_transient_film_with_detector_parameters():
    f = _film(pulses=5000, pde=0.5, dark_count_rate_cps=100.0, ambient_rate_cps=10, jitter_ps=30.0,
              gate_open_ps=200.0, gate_close_ps=400.0, gate_transition_ps=50.0, dead_time_ns=40.0,
              dead_time_model="paralyzable", tcspc_max_count_rate_hz=0.0, afterpulse_prob=0.01,
              afterpulse_delay_ns=5.0, crosstalk_prob=0.02, repetition_rate_hz=10e6, laser_power_w=0.002,
              wavelength_nm=905.0, irf_tail_fraction=0.1, irf_tail_ps=30.0, seed=9, engine="exact")
    assert hasattr(f, "is_transient") and f.width == 4 and f.height == 3 and f.n_bins == 64
    assert f.time_axis().t0_ps == 100.0
    kw = f.detect_kwargs()
    assert set(kw) == {"params", "pulses", "exposure_s", "seed", "engine"}
    assert kw["pulses"] == 5000 and kw["exposure_s"] is None and kw["seed"] == 9 and kw["engine"] == "exact"
    assert kw["params"] == DetectorParams(
        pde=0.5, dark_count_rate_cps=100.0, ambient_rate_cps=10.0, jitter_ps=30.0, gate_open_ps=200.0,
        gate_close_ps=400.0, gate_transition_ps=50.0, dead_time_ns=40.0, dead_time_model="paralyzable",
        tcspc_max_count_rate_hz=None, afterpulse_prob=0.01, afterpulse_delay_ns=5.0, crosstalk_prob=0.02,
        repetition_rate_hz=10e6, laser_power_w=0.002, wavelength_nm=905.0, irf_tail_fraction=0.1,
        irf_tail_ps=30.0)
    assert f.detector_params() is kw["params"] and f.detector_pulses() == (5000, None) and f.detector_seed() == 9
    assert str(f).startswith("SpadFilm[")


def test_spad_film_defaults_and_auto_gate():
    f = _film(exposure_s=0.01, auto_gate=True)
    kw = f.detect_kwargs()
    assert kw["params"] == DetectorParams(auto_gate=True) and kw["exposure_s"] == 0.01 and kw["pulses"] is None
    assert _film().detect_kwargs()["params"] == DetectorParams()


@pytest.mark.parametrize("kw, text", [
    ({"pde": 1.5}, "spad_film: pde=1.5: allowed in [0, 1]"),
    ({"dark_count_rate_cps": -2.0}, "spad_film: dark_count_rate_cps=-2.0"),
    ({"gate_open_ps": 500.0, "gate_close_ps": 100.0}, "gate must close after it opens"),
    ({"pulses": 10, "exposure_s": 1.0}, "not both"),
    ({"pulses": 0}, "pulses=0"),
    ({"engine": "fast"}, "engine='fast'"),
    ({"dead_time_model": "sticky"}, "dead_time_model='sticky'"),
    ({"auto_gate": True, "gate_open_ps": 1.0, "gate_close_ps": 2.0}, "not both"),
    ({"n_bins": 0}, "n_bins=0"),
])
def test_spad_film_rejects_bad_parameters(kw, text):
    with pytest.raises(Exception) as e:
        _film(**kw)
    assert text in str(e.value)


def test_render_pipeline_detect_step_uses_the_film_parameters(tmp_path):
    """The render pipeline's detection step (ideal in OUT/ideal, counts in OUT) with a spad_film's kwargs."""
    import types

    import numpy as np

    from detector_helpers import make_ideal_capture
    from transient_core.stack import read_manifest, read_stack
    from transient_mi import render_capture

    film = _film(pulses=2000, auto_gate=True, pde=0.5, seed=4)
    out = tmp_path / "out"
    out.mkdir()
    data = np.zeros((2, 3, 4, 64), np.float32)
    data[..., 40:44] = 1e-3
    make_ideal_capture(out / "ideal", data, bin_width_ps=8.0, t0_ps=100.0)
    job = types.SimpleNamespace(out_dir=out, detect_kwargs=film.detect_kwargs())
    assert render_capture._detect_into(job, out / "ideal") == out
    m, counts = read_stack(out)
    assert m["kind"] == "counts" and counts.shape == (2, 3, 4, 64) and counts.dtype == np.uint32
    d = m["detector"]
    assert d["pulses"] == 2000 and d["pde"] == 0.5 and d["seed"] == 4 and d["resolved"]["gate"] == "auto_per_spot"
    assert read_manifest(out / "ideal")["kind"] == "ideal"
    assert not [p for p in out.iterdir() if p.name.startswith(".")]


def test_detection_seed_follows_the_render_seed_unless_given():
    f = _film()
    a, b = f.detect_kwargs(render_seed=5)["seed"], f.detect_kwargs(render_seed=6)["seed"]
    assert a != b and a == f.detect_kwargs(render_seed=5)["seed"]
    assert _film(seed=3).detect_kwargs(render_seed=5)["seed"] == 3
