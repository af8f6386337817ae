"""The photon-budget study on tiny settings: outputs, error against budget, SNR against the closed forms."""

from __future__ import annotations

import csv
import json
import math
import shutil

import numpy as np
import pytest

from stats_helpers import z_bound

#: 8x8 array, 2x2 laser spots, 8 ps bins, 256 spp (8 replicates of 32); 32x32x16 voxels.
TINY = dict(defines={"array": 8, "spp": 256, "estimator": "monte_carlo"}, quick=True, dark_count_rates_cps=(25.0,), dead_times_ns=(10.0,),
            seeds=(0, 1, 2), voxels=(32, 32, 16), progress=False)
#: Starved (5 pulses, ~0.07 detected counts per pixel per spot) to plenty (5000 pulses, ~70).
EXPOSURES = (1e-7, 1e-6, 1e-4)
#: 10 mW (the paper's; ~1.4 % detection probability per pulse) and 100 mW (~13 %: pile-up).
POWERS = (0.01, 0.1)
#: Family-wise false-alarm probability of the statistical checks (3 sigma, two-sided).
ALPHA = 0.0027


def z_bonferroni(n_tests: int) -> float:
    """Two-sided normal quantile for a family-wise false-alarm probability ALPHA over n_tests."""
    return z_bound(ALPHA, max(n_tests, 1))


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    import transient_mi  # noqa: F401
    from transient_mi.study import run_photon_budget_study

    out = tmp_path_factory.mktemp("pb") / "study"
    return run_photon_budget_study("paper_mannequin", out, exposures_s=EXPOSURES, laser_powers_w=POWERS, **TINY)


def test_outputs_tables_and_figures(study):
    import matplotlib.image as mpimg

    out = study.out_dir
    assert study.study == "photon_budget" and out.is_dir()
    assert not list(out.parent.glob(f".{out.name}.*")), "temporary directory left behind"
    for name in ("results_csv", "results_json", "timings_csv", "timings_json", "snr_bins_csv", "snr_pixels_csv"):
        assert study.tables[name].is_file(), name
    assert set(study.figures) == {"error_vs_photons", "snr_vs_photons", "reconstructions"}
    for p in study.figures.values():
        img = mpimg.imread(p)
        assert img.ndim == 3 and img.shape[0] > 100 and img.shape[1] > 100
    assert study.summary.is_file() and "Photon-budget study" in study.summary.read_text()
    assert (out / "ideal" / "manifest.json").is_file() and (out / "ground_truth.ply").is_file()

    n = len(POWERS) * len(EXPOSURES) * len(TINY["seeds"])
    with open(study.tables["results_csv"]) as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(study.rows) == n
    keys = {(float(r["laser_power_w"]), float(r["exposure_s"]), int(r["seed"])) for r in rows}
    assert len(keys) == n  # one row per (budget, dark, dead time, seed)
    for r in study.rows:
        assert r["pulses_per_spot"] == round(r["exposure_s"] * 50e6)
        assert r["chamfer_m"] > 0 and 0 <= r["iou"] <= 1 and r["exact"] is True
        assert r["counts_per_pixel_per_spot"] >= 0 and 0 < r["p_det_mean"] <= r["p_det_max"] < 1
    data = json.loads(study.tables["results_json"].read_text())
    assert data["study"] == "photon_budget" and len(data["rows"]) == n
    assert data["settings"]["detection_seeds"] == [0, 1, 2] and data["settings"]["voxels"] == [32, 32, 16]
    with open(study.tables["timings_csv"]) as f:
        timings = list(csv.DictReader(f))
    assert len(timings) == n and all(float(t["detect_s"]) >= 0 and float(t["total_s"]) > 0 for t in timings)
    assert not any(k.endswith("_s") and k != "exposure_s" for k in rows[0])  # timings kept out of results


def test_detected_counts_scale_with_exposure(study):
    """The mean detected counts are proportional to the number of pulses: the renewal law's mean N p / (1 + m p)
    is linear in N (pile-up changes the slope, not the proportionality)."""
    agg = [a for a in study.aggregate if a["laser_power_w"] == POWERS[0]]
    a_lo, a_hi = agg[0], agg[-1]
    ratio = a_hi["pulses_per_spot"] / a_lo["pulses_per_spot"]
    n_pix_spots = 8 * 8 * 4 * len(TINY["seeds"])
    # Both means are totals of independent counts over pixels, spots and seeds, each sub-Poisson under dead time, so
    # sqrt(total) over-estimates their sd: relative sd of the ratio <= sqrt(1/C_lo + 1/C_hi). The only departure
    # from proportionality is the start of each acquisition (the detector is ready at the first pulse): at most
    # m p_max / N_lo relative (m = 2 blind cycles). False-failure rate <= ALPHA (one check).
    c_lo = a_lo["counts_per_pixel_per_spot_mean"] * n_pix_spots
    c_hi = a_hi["counts_per_pixel_per_spot_mean"] * n_pix_spots
    rel_sd = math.sqrt(1 / c_lo + 1 / c_hi)
    p_max = max(r["p_det_max"] for r in study.rows if r["laser_power_w"] == POWERS[0])
    start = 2 * p_max / a_lo["pulses_per_spot"]
    got = a_hi["counts_per_pixel_per_spot_mean"] / a_lo["counts_per_pixel_per_spot_mean"]
    assert abs(got / ratio - 1) <= z_bound(ALPHA, 1) * rel_sd + start, (got, ratio, rel_sd, start)


def test_reconstruction_error_decreases_with_photon_budget(study):
    """From starved (< 1 detected count per pixel per spot) to plenty, on the seed means."""
    S = len(TINY["seeds"])
    agg = sorted((a for a in study.aggregate if a["laser_power_w"] == POWERS[0]), key=lambda a: a["exposure_s"])
    assert agg[0]["counts_per_pixel_per_spot_mean"] < 1 and agg[-1]["counts_per_pixel_per_spot_mean"] > 10
    for key, sign in (("chamfer_m", -1), ("depth_mae_m", -1), ("iou", +1)):
        means = [a[f"{key}_mean"] for a in agg]
        assert all(sign * (b - a) > 0 for a, b in zip(means, means[1:])), (key, means)
        lo, hi = agg[0], agg[-1]
        se = math.sqrt((lo[f"{key}_sd"] ** 2 + hi[f"{key}_sd"] ** 2) / S)
        assert sign * (hi[f"{key}_mean"] - lo[f"{key}_mean"]) > 3 * se, (key, lo, hi)


def test_per_bin_snr_follows_sqrt_n_at_low_flux(study):
    """Per-bin counts are Poisson when the per-pulse detection probability is small: SNR = sqrt(N) within the
    derived standard error of the Fano factor (snr.py), family-wise over the classes where it holds."""
    from transient_mi.study.snr import MIN_COINCIDENCES

    low = {(r["laser_power_w"], r["exposure_s"]) for r in study.rows if r["p_det_max"] < 0.05}
    classes = [r for r in study.snr_bins if (r["laser_power_w"], r["exposure_s"]) in low
               and r["coincidences"] >= MIN_COINCIDENCES]
    assert len(classes) >= 5
    counts = [r["mean_counts"] for r in classes]
    assert max(counts) / min(counts) > 30  # the check spans more than a decade and a half of counts per bin
    z = z_bonferroni(len(classes))
    for r in classes:
        assert r["snr"] == pytest.approx(r["mean_counts"] / math.sqrt(r["var_counts"]))
        assert r["snr_poisson"] == pytest.approx(math.sqrt(r["mean_counts"]))
        f_lo, f_hi = 1 - z * r["fano_sd"], 1 + z * r["fano_sd"]
        # SNR / sqrt(N) = F^(-1/2): the Fano interval mapped onto the SNR
        assert f_hi ** -0.5 <= r["snr"] / r["snr_poisson"] <= f_lo ** -0.5, r


def test_signal_and_background_split(study):
    """Counts split into the scene's photons and background by their intensities per bin (snr.py)."""
    from transient_core.stack import read_manifest
    from scipy.integrate import quad
    from scipy.stats import norm

    from spad_detector.gate import auto_gate, gate_sigma_ps
    from transient_mi.paper import paper_detector

    m = read_manifest(study.out_dir / "ideal")
    d = paper_detector()
    t = m["time"]
    t_lo, t_hi = t["t0_ps"], t["t0_ps"] + t["n_bins"] * t["bin_width_ps"]
    gates = [auto_gate(m, d.gate_transition_ps, d.auto_gate_depth_min_m, d.auto_gate_depth_max_m, spot=j)
             for j in range(m["n_files"])]
    # the gate (Gaussian edges, 50 % points open/close, repeated every laser period) integrated by quadrature: the
    # time per pulse it is open for dark counts that land on the capture's time axis, mean over spots
    s_ps, period = gate_sigma_ps(d.gate_transition_ps), 1e12 / 50e6

    def g(tt, o, c):
        return min(1.0, sum(norm.cdf((tt - o - k * period) / s_ps) - norm.cdf((tt - c - k * period) / s_ps)
                            for k in (-2, -1, 0, 1, 2)))

    # a dark count at time tau is stamped at tau + jitter (Gaussian, 25 ps FWHM) and counted if that is on the axis
    s_j = d.jitter_ps / (2 * math.sqrt(2 * math.log(2)))

    def seen(tt, o, c):
        return g(tt, o, c) * (norm.cdf((t_hi - tt) / s_j) - norm.cdf((t_lo - tt) / s_j))

    # (the model draws dark counts on the capture's time axis only: those that would jitter in from beyond its end,
    # ~4 ps worth of the ~9000 ps open, are not simulated)
    open_ps = [quad(seen, t_lo, t_hi, args=gt, points=[x for x in gt if t_lo < x < t_hi], limit=400,
                    epsabs=1e-6)[0] for gt in gates]
    gate_open_s = float(np.mean(open_ps)) * 1e-12
    for r in study.snr_bins:
        assert r["signal_counts"] + r["background_counts"] == pytest.approx(r["mean_counts"])
        assert 0 <= r["signal_counts"] <= r["mean_counts"] * (1 + 1e-12)
        assert r["signal_snr_shot_limit"] == pytest.approx(math.sqrt(r["signal_counts"]))
        assert r["signal_snr_poisson"] == pytest.approx(r["signal_counts"] / math.sqrt(r["mean_counts"]))
    for r in study.rows:
        assert r["signal_counts_per_pixel_per_spot"] + r["background_counts_per_pixel_per_spot"] == \
            pytest.approx(r["counts_per_pixel_per_spot"])
        # the paper's 25 cps add ~1e-6 counts per pulse in the gate: essentially every count is signal
        assert r["background_counts_per_pixel_per_spot"] <= 1e-3 * r["counts_per_pixel_per_spot"] + 1e-9
        bg = r["expected_background_low_flux_per_pixel_per_spot"]
        # 25 dark counts per second while the gate is open (quadrature above; the model integrates it in closed form)
        assert bg == pytest.approx(25.0 * r["pulses_per_spot"] * gate_open_s, rel=1e-6), (gates, t_lo, t_hi, open_ps, r["pulses_per_spot"])


def test_pixel_totals_follow_the_dead_time_renewal_model(study):
    """At 100 mW each pulse is detected with probability ~5-35 %, and the TCSPC's 50 ns blinds 2 whole cycles after
    each count: the mean counts follow N p / (1 + 2 p) (pile-up) and the counts are sub-Poisson with
    Fano factor (1 - p) / (1 + 2 p)^2, both within the classes' standard errors."""
    S = len(TINY["seeds"])
    pred = [r for r in study.snr_pixels if r["predicted_fano"] is not None]
    assert pred and all(r["regime"] == "whole_blind_cycles" for r in pred)
    z = z_bonferroni(2 * len(pred))
    for r in pred:
        assert abs(r["fano"] - r["predicted_fano"]) <= z * r["fano_sd"], r
        se_mean = math.sqrt(r["var_counts"] / (r["n_pixels"] * S))
        assert abs(r["mean_counts"] - r["predicted_mean"]) <= z * se_mean, r
    strong = [r for r in pred if r["laser_power_w"] == POWERS[1]]
    assert strong
    for r in strong:  # the effect is real: fewer counts than the low-flux expectation ...
        se_mean = math.sqrt(r["var_counts"] / (r["n_pixels"] * S))
        assert r["expected_counts_low_flux"] - r["mean_counts"] > 5 * se_mean
    # ... and counts more regular than Poisson
    assert any((1 - r["fano"]) > 3 * r["fano_sd"] for r in strong)


def test_in_memory_detection_equals_detect_stack(study, tmp_path):
    """A study row's counts are those `transient-mi detect --seed S` writes (same bytes)."""
    from transient_core.stack import read_stack
    from spad_detector import detect_stack
    from transient_mi.paper import paper_detector
    from transient_mi.study.detection import Detection, IdealCapture

    ideal = study.out_dir / "ideal"
    params = paper_detector(dark_count_rate_cps=25.0, dead_time_ns=10.0, laser_power_w=0.1)
    detect_stack(ideal, tmp_path / "counts", params, exposure_s=1e-6, seed=2, progress=False)
    _, ref = read_stack(tmp_path / "counts")
    det = Detection(IdealCapture(ideal), params, exposure_s=1e-6)
    mine = np.stack([det.counts(j, 2)[0] for j in range(det.ideal.n_files)])
    assert mine.dtype == ref.dtype and np.array_equal(mine, ref)


def test_same_seed_same_bytes(tmp_path):
    """Everything but the timings is byte-identical between two runs with the same arguments."""
    import transient_mi  # noqa: F401
    from transient_mi.study import run_photon_budget_study

    kw = dict(TINY, exposures_s=(1e-6,), seeds=(0, 1), voxels=(16, 16, 8),
              defines={"array": 4, "spp": 32, "estimator": "monte_carlo"})
    a = run_photon_budget_study("paper_mannequin", tmp_path / "a", **kw)
    b = run_photon_budget_study("paper_mannequin", tmp_path / "b", **kw)
    for name in ("results.csv", "results.json", "snr_bins.csv", "snr_pixels.csv"):
        assert (a.out_dir / name).read_bytes() == (b.out_dir / name).read_bytes(), name
    c = run_photon_budget_study("paper_mannequin", tmp_path / "c", **dict(kw, seeds=(2, 3)))
    assert (c.out_dir / "results.csv").read_bytes() != (a.out_dir / "results.csv").read_bytes()


def test_other_scene_with_point_targets_and_without_ground_truth(tmp_path):
    """A scene other than the paper's: metrics against given point targets, or none (and no error figure)."""
    import transient_mi  # noqa: F401
    from transient_mi.study import run_photon_budget_study

    targets = tmp_path / "targets.json"
    targets.write_text(json.dumps([[0.2, 0.15, 0.4], [-0.15, -0.1, 0.55], [0.05, -0.25, 0.7]]))
    kw = dict(defines={"width": "6", "height": "6", "spots_x": "2", "spots_y": "2", "spp": "16"},
              exposures_s=(1e-5,), dark_count_rates_cps=(25.0,), dead_times_ns=(10.0,), seeds=(0, 1),
              voxels=(16, 16, 16), progress=False)
    r = run_photon_budget_study("nlos_point_targets", tmp_path / "pts", ground_truth=targets, **kw)
    assert all(row["localisation_error_m"] is not None and row["chamfer_m"] is None for row in r.rows)
    assert "error_vs_photons" in r.figures
    r = run_photon_budget_study("nlos_point_targets", tmp_path / "none", **kw)
    assert all(row["localisation_error_m"] is None and row["iou"] is None for row in r.rows)
    assert "error_vs_photons" not in r.figures and "snr_vs_photons" in r.figures
    assert "No error metrics" in r.summary.read_text()


@pytest.mark.parametrize("kwargs, match", [
    (dict(exposures_s=()), "exposures_s"),
    (dict(exposures_s=(1e-6, -1.0)), "exposures_s: -1.0"),
    (dict(exposures_s=(1e-12,)), "need at least 1"),
    (dict(dark_count_rates_cps=(float("nan"),)), "dark_count_rates_cps"),
    (dict(dead_times_ns=(-1.0,)), "dead_times_ns"),
    (dict(seeds=(0,)), "seeds"),
    (dict(seeds=(0, 0)), "distinct"),
    (dict(voxels=(1, 2, 3)), "voxels 1,2,3"),
    (dict(laser_powers_w=(0.0,)), "laser_powers_w"),
    (dict(defines={"nonsense": 1}), "has no parameter 'nonsense'"),
    (dict(defines={"array": "four"}), "-D array='four'"),
    (dict(scene="no_such_scene"), "SCENE 'no_such_scene'"),
    (dict(method="magic"), "method='magic'"),
])
def test_bad_arguments_fail_before_any_work(tmp_path, kwargs, match):
    import transient_mi  # noqa: F401
    from transient_core.errors import UserInputError
    from transient_mi.study import run_photon_budget_study

    kw = dict(TINY, exposures_s=(1e-6,))
    kw.update(kwargs)
    scene = kw.pop("scene", "paper_mannequin")
    with pytest.raises(UserInputError, match=match):
        run_photon_budget_study(scene, tmp_path / "out" / "study", **kw)
    assert not (tmp_path / "out").exists()
    shutil.rmtree(tmp_path, ignore_errors=True)
