"""Detector parameters, photon budget and bad input: clear errors naming parameter, value and range."""

from __future__ import annotations

import math
import sys

import numpy as np
import pytest

from transient_core.errors import UserInputError
from transient_core.units import photons_per_pulse
from spad_detector import DetectorParams, detect, param_names, resolve_budget
from spad_detector.params import DEFAULT_PULSES, FWHM_PER_SIGMA

IDEAL = np.full((2, 3, 16), 1e-3)


def _detect(params=None, ideal=IDEAL, **kw):
    kw.setdefault("bin_width_ps", 10.0)
    return detect(ideal, params, 100, **kw)


def test_detector_package_does_not_import_mitsuba():
    import subprocess

    code = ("import sys, importlib.util, types; "
            "sys.modules['transient_mi'] = types.ModuleType('transient_mi'); "
            "sys.modules['transient_mi'].__path__ = ['transient_mi']; "
            "import spad_detector as d; "
            "assert 'mitsuba' not in sys.modules and 'drjit' not in sys.modules, sorted(sys.modules)")
    root = __import__("pathlib").Path(__file__).resolve().parents[1]
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=root)
    assert r.returncode == 0, r.stderr


def test_defaults_are_the_papers():
    p = DetectorParams().validate()
    assert p.pde == 0.70 and p.dark_count_rate_cps == 25.0 and p.gate_transition_ps == 120.0
    assert p.jitter_ps == 25.0 and math.isclose(p.jitter_sigma_ps, 25.0 / (2 * math.sqrt(2 * math.log(2))))
    assert p.tcspc_max_count_rate_hz == 20e6 and p.tcspc_dead_time_ns == 50.0
    assert p.afterpulse_prob == 0.0 and p.crosstalk_prob == 0.0
    assert math.isclose(FWHM_PER_SIGMA, 2.3548200450309493)


@pytest.mark.parametrize("change, text", [
    ({"pde": 1.2}, "pde=1.2: allowed in [0, 1]"),
    ({"pde": -0.1}, "pde=-0.1"),
    ({"dark_count_rate_cps": -5.0}, "dark_count_rate_cps=-5.0: allowed >= 0"),
    ({"ambient_rate_cps": -1.0}, "ambient_rate_cps=-1.0"),
    ({"dark_count_rate_cps": float("nan")}, "dark_count_rate_cps=nan: must be a finite number"),
    ({"jitter_ps": -1.0}, "jitter_ps=-1.0"),
    ({"gate_open_ps": 500.0, "gate_close_ps": 100.0}, "gate_close_ps=100.0 <= gate_open_ps=500.0"),
    ({"gate_open_ps": 500.0}, "give both gate times"),
    ({"gate_open_ps": 1.0, "gate_close_ps": 2.0, "auto_gate": True}, "not both"),
    ({"gate_transition_ps": -3.0}, "gate_transition_ps=-3.0"),
    ({"dead_time_ns": -1.0}, "dead_time_ns=-1.0"),
    ({"dead_time_model": "sticky"}, "dead_time_model='sticky': allowed nonparalyzable, paralyzable"),
    ({"tcspc_max_count_rate_hz": 0.0}, "tcspc_max_count_rate_hz=0.0: allowed > 0"),
    ({"afterpulse_prob": 1.0}, "afterpulse_prob=1.0: allowed in [0, 1)"),
    ({"crosstalk_prob": 2.0}, "crosstalk_prob=2.0"),
    ({"irf_tail_fraction": 0.2}, "irf_tail_ps=0.0: must be > 0"),
    ({"repetition_rate_hz": -5.0}, "repetition_rate_hz=-5.0"),
    ({"irf_file": "/nonexistent/irf.csv"}, "irf_file='/nonexistent/irf.csv': no such file"),
    ({"auto_gate_depth_min_m": 2.0}, "auto_gate_depth_max_m=1.5 must be > auto_gate_depth_min_m=2.0"),
])
def test_bad_parameters_name_parameter_value_and_range(change, text):
    with pytest.raises(UserInputError) as e:
        _detect(DetectorParams(**change))
    assert text in str(e.value)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("value, text", [
    (np.nan, "ideal[1, 2, 5] = nan"), (-1e-3, "ideal[1, 2, 5] = -0.001"), (np.inf, "ideal[1, 2, 5] = inf")])
def test_ideal_with_negative_or_nan_values_is_refused(value, text):
    bad = IDEAL.copy()
    bad[1, 2, 5] = value
    with pytest.raises(UserInputError, match=text.replace("[", r"\[").replace("]", r"\]")):
        _detect(ideal=bad)


def test_other_bad_calls():
    with pytest.raises(UserInputError, match="n_pulses=0"):
        detect(IDEAL, None, 0, bin_width_ps=1.0)
    with pytest.raises(UserInputError, match="engine='fast'"):
        _detect(engine="fast")
    with pytest.raises(UserInputError, match="bin_width_ps=0"):
        _detect(bin_width_ps=0)
    with pytest.raises(UserInputError, match="auto_gate needs the capture geometry"):
        _detect(DetectorParams(auto_gate=True))
    with pytest.raises(UserInputError, match="longer than the laser period"):
        _detect(ideal=np.zeros((1, 4000)), bin_width_ps=10.0)  # 40 ns window, 20 ns period
    with pytest.raises(UserInputError, match="longer than the laser period"):
        _detect(DetectorParams(gate_open_ps=0.0, gate_close_ps=30000.0))
    with pytest.raises(UserInputError, match="seed=-1"):
        _detect(seed=-1)


def test_measured_irf_coarser_than_bins_is_refused(tmp_path):
    t = np.arange(-50.0, 200.0, 10.0)
    w = np.exp(-0.5 * (t / 10.0) ** 2) + 0.05 * np.exp(-np.clip(t, 0, None) / 50.0) * (t > 0)
    f = tmp_path / "irf.csv"
    np.savetxt(f, np.c_[t, w], delimiter=",")
    _detect(DetectorParams(irf_file=str(f)), bin_width_ps=10.0)  # same resolution: fine
    with pytest.raises(UserInputError, match="bin_width_ps=2 is finer than the measured IRF's sampling step 10 ps"):
        _detect(DetectorParams(irf_file=str(f)), bin_width_ps=2.0)
    bad = tmp_path / "bad.csv"
    np.savetxt(bad, np.c_[t[::-1], w], delimiter=",")
    with pytest.raises(UserInputError, match="uniform grid"):
        _detect(DetectorParams(irf_file=str(bad)))


def test_params_dict_round_trip_and_names():
    p = DetectorParams(pde=0.5, gate_open_ps=1.0, gate_close_ps=2.0, tcspc_max_count_rate_hz=None)
    d = p.to_dict()
    assert set(param_names()) <= set(d)
    assert DetectorParams.from_dict(d) == p
    with pytest.raises(UserInputError, match="unknown detector parameter"):
        DetectorParams.from_dict({"pde": 0.5, "qe": 0.1})


LASER = {"wavelength_nm": 1550.0, "repetition_rate_hz": 50e6, "average_power_w": 1e-3, "pulse_energy_j": 2e-11,
         "photons_per_pulse": photons_per_pulse(2e-11, 1550.0)}


def test_budget_pulses_exposure_and_overrides():
    p = DetectorParams()
    assert resolve_budget(p, LASER).n_pulses == DEFAULT_PULSES
    assert resolve_budget(p, LASER, pulses=1234).n_pulses == 1234
    b = resolve_budget(p, LASER, exposure_s=0.01)
    assert b.n_pulses == 500_000 and b.photon_scale == 1.0 and math.isclose(b.exposure_s, 0.01)
    b = resolve_budget(DetectorParams(repetition_rate_hz=10e6), LASER, exposure_s=0.01)
    assert b.n_pulses == 100_000
    # same average power at a fifth of the rate: five times the pulse energy
    assert math.isclose(b.photon_scale, 5.0, rel_tol=1e-12)
    b = resolve_budget(DetectorParams(laser_power_w=4e-3), LASER)
    assert math.isclose(b.photon_scale, 4.0, rel_tol=1e-12)
    assert math.isclose(b.laser["photons_per_pulse"], 4 * LASER["photons_per_pulse"], rel_tol=1e-12)
    b = resolve_budget(DetectorParams(wavelength_nm=775.0), LASER)
    assert math.isclose(b.photon_scale, 0.5, rel_tol=1e-12)  # photons carry twice the energy
    assert resolve_budget(p, None).repetition_rate_hz == 50e6


@pytest.mark.parametrize("kw, text", [
    ({"pulses": 10, "exposure_s": 1.0}, "give one of them, not both"),
    ({"pulses": 0}, "pulses=0"),
    ({"pulses": 2.5}, "pulses=2.5"),
    ({"exposure_s": -1.0}, "exposure_s=-1.0"),
    ({"exposure_s": 1e-12}, "need at least 1"),
])
def test_budget_bad_input(kw, text):
    with pytest.raises(UserInputError, match=text):
        resolve_budget(DetectorParams(), LASER, **kw)


def test_laser_override_needs_a_laser_block():
    with pytest.raises(UserInputError, match="no laser block"):
        resolve_budget(DetectorParams(laser_power_w=1.0), None)
    with pytest.raises(UserInputError, match="photons_per_pulse"):
        resolve_budget(DetectorParams(laser_power_w=1.0), {"wavelength_nm": 1550.0})
