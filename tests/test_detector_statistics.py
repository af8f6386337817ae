"""The detector model against closed forms, with statistical tolerances (seeded, p > 1e-3 / 3 sigma).

Poisson at low flux, Coates' pile-up and its correction at high flux, dead
time longer than the pulse period (renewal model, continuous sources), dark
counts, jitter width and the gate's shape.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats
from scipy.special import nbdtr

from detector_helpers import ALPHA, bonferroni_z, chisq_gof, variance_ratio_pvalue
from stats_helpers import z_bound
from spad_detector import (DetectorParams, coates_correction, coates_std, detect,
                                   expected_counts_low_flux, first_photon_probabilities, gate_efficiency,
                                   gate_mean, nonparalyzable_rate, paralyzable_rate, pulsed_rate_per_cycle)
from spad_detector.gate import TEN_NINETY_PER_SIGMA, transition_10_90_ps

ENGINES = ["analytic", "exact"]
# no dead time from the TCSPC, no dark counts: isolates the effect under test
QUIET = dict(dark_count_rate_cps=0.0, jitter_ps=0.0, tcspc_max_count_rate_hz=None)


# --------------------------------------------------------------------- low flux


@pytest.mark.parametrize("engine", ENGINES)
def test_low_flux_counts_are_poisson_with_the_efficiency_applied(engine):
    n_pix, T, w, N = 4000, 32, 10.0, 100_000
    ideal = np.zeros((n_pix, T))
    ideal[:, 10:20] = 2e-5  # photons per pulse per bin
    params = DetectorParams(pde=0.7, jitter_ps=0.0)  # paper's dark counts and dead times
    counts = detect(ideal, params, N, bin_width_ps=w, seed=11, engine=engine)
    mu = expected_counts_low_flux(ideal, params, N, bin_width_ps=w)[:, 10:20]
    assert np.allclose(mu, N * 0.7 * 2e-5, rtol=1e-4)  # efficiency applied (dark counts ~1e-5 of it)
    c = counts[:, 10:20].astype(float)
    # mean: all signal bins together, 3 sigma of a Poisson total
    assert abs(c.sum() - mu.sum()) <= 3 * math.sqrt(mu.sum())
    # distribution of a bin's counts: Poisson(mu) goodness of fit
    m = float(mu.mean())
    kmax = 7
    obs = np.bincount(np.minimum(c.ravel().astype(int), kmax), minlength=kmax + 1)
    pmf = stats.poisson.pmf(np.arange(kmax), m)
    exp = c.size * np.append(pmf, 1 - pmf.sum())
    assert chisq_gof(obs, exp, ddof=0) > ALPHA
    # variance = mean: index of dispersion sum (c - mu)^2 / mu ~ chi2(n)
    d = float(((c - mu) ** 2 / mu).sum())
    p = 2 * min(stats.chi2.cdf(d, c.size), stats.chi2.sf(d, c.size))
    assert p > ALPHA


# -------------------------------------------------------------------- high flux


def _decay_profile(T: int, total: float) -> np.ndarray:
    lam = np.exp(-np.arange(T) / 6.0)
    return lam * total / lam.sum()


@pytest.mark.parametrize("engine", ENGINES)
def test_high_flux_histogram_is_coates_pile_up_and_coates_correction_recovers_the_shape(engine):
    T, w, n_pix, N = 24, 50.0, 8, 20_000
    lam = _decay_profile(T, 2.0)  # 2 detectable photons per cycle: strong pile-up
    pde = 0.7
    ideal = np.tile(lam / pde, (n_pix, 1))
    params = DetectorParams(pde=pde, dead_time_ns=10.0, **QUIET)  # 1.2 ns window, 20 ns period: m = 0
    counts = detect(ideal, params, N, bin_width_ps=w, seed=5, engine=engine).astype(float)
    cycles = n_pix * N
    hist = counts.sum(0)
    p = first_photon_probabilities(lam)
    obs = np.append(hist, cycles - hist.sum())
    exp = cycles * np.append(p, math.exp(-lam.sum()))
    assert chisq_gof(obs, exp, ddof=1) > ALPHA
    # the test has power: the histogram is far from the no-pile-up shape
    naive = lam / lam.sum() * hist.sum()
    assert chisq_gof(hist, naive, ddof=1) < 1e-10
    # Coates' correction: true per-cycle intensity within 3 sigma (family-wise over the bins)
    est = coates_correction(hist, cycles)
    sd = coates_std(hist, cycles)
    z = (est - lam) / sd
    assert np.all(np.abs(z) < bonferroni_z(T)), z
    assert stats.chi2.sf(float((z ** 2).sum()), T) > ALPHA


def test_coates_correction_with_dead_time_longer_than_the_period():
    T, w, n_pix, N = 16, 50.0, 16, 20_000
    lam = _decay_profile(T, 1.0)
    # 50 ns TCSPC dead time at 50 MHz with an 0.8 ns window: blind for m = 2 cycles
    params = DetectorParams(pde=1.0, dead_time_ns=10.0, dark_count_rate_cps=0.0, jitter_ps=0.0)
    counts = detect(np.tile(lam, (n_pix, 1)), params, N, bin_width_ps=w, seed=9, engine="analytic")
    hist = counts.sum(0).astype(float)
    est = coates_correction(hist, n_pix * N, blind_cycles=2)
    naive = coates_correction(hist, n_pix * N)
    sd = coates_std(hist, n_pix * N, blind_cycles=2)
    z = (est - lam) / sd
    assert np.all(np.abs(z) < bonferroni_z(T)), z
    # without the blind cycles the correction is badly biased
    assert np.abs((naive - lam) / sd).max() > 10


def test_coates_correction_rejects_impossible_input():
    from transient_core.errors import UserInputError

    with pytest.raises(UserInputError, match="counts exceed"):
        coates_correction(np.array([5.0, 6.0]), 10)
    with pytest.raises(UserInputError, match="live cycles"):
        coates_correction(np.array([5.0, 1.0]), 10, blind_cycles=2)
    with pytest.raises(UserInputError, match="n_cycles"):
        coates_correction(np.array([1.0]), 0)
    import spad_detector.coates
    import spad_detector as det

    assert det.coates_correction is spad_detector.coates.coates_correction


# ---------------------------------------------------- dead time longer than P


def _renewal_moments(N: int, p: float, m: int) -> tuple[float, float]:
    """Exact mean and variance of the number of detections in N cycles (detector ready at cycle 1)."""
    k = np.arange(1, N // (m + 1) + 2, dtype=float)
    x = N - (k - 1) * m - k
    surv = np.where(x >= 0, nbdtr(np.maximum(x, 0), k, p), 0.0)  # P(K >= k)
    mean = surv.sum()
    second = ((2 * k - 1) * surv).sum()
    return float(mean), float(second - mean ** 2)


@pytest.mark.parametrize("engine", ENGINES)
def test_pulsed_count_rate_with_dead_time_longer_than_the_period(engine):
    T, w, n_pix, N = 20, 20.0, 64, 20_000
    ideal = np.zeros((n_pix, T))
    ideal[:, 8:12] = 0.125  # 0.5 photons per cycle (PDE 1)
    # SPAD 10 ns, TCSPC 20 MHz = 50 ns dead time, 50 MHz laser: blind m = 2 whole cycles after a count
    params = DetectorParams(pde=1.0, dark_count_rate_cps=0.0, jitter_ps=0.0)
    K = detect(ideal, params, N, bin_width_ps=w, seed=3, engine=engine).sum(1).astype(float)
    p, m = 1 - math.exp(-0.5), 2
    mean, var = _renewal_moments(N, p, m)
    # the documented asymptotic model: p / (1 + m p) per cycle
    assert abs(mean / N - pulsed_rate_per_cycle(p, m)) < 1e-4
    assert abs(K.mean() - mean) <= 3 * math.sqrt(var / n_pix)
    assert variance_ratio_pvalue(K, var) > ALPHA
    # dead time makes the counts sub-binomial: a binomial variance is rejected
    assert variance_ratio_pvalue(K, N * (mean / N) * (1 - mean / N)) < 1e-6


@pytest.mark.parametrize("model, formula", [("nonparalyzable", nonparalyzable_rate),
                                            ("paralyzable", paralyzable_rate)])
def test_continuous_source_count_rate_with_dead_time_longer_than_the_period(model, formula):
    # dark counts at 2e7/s on an ungated SPAD with a 50 ns dead time (2.5 laser periods)
    n, tau = 2e7, 50e-9
    T, w, n_pix, N = 100, 200.0, 16, 40_000  # the window is the whole 20 ns period
    params = DetectorParams(dark_count_rate_cps=n, dead_time_ns=50.0, dead_time_model=model, jitter_ps=0.0,
                            tcspc_max_count_rate_hz=None)
    counts = detect(np.zeros((n_pix, T)), params, N, bin_width_ps=w, seed=21, engine="exact")
    K = counts.sum(1).astype(float)
    time_s = N * 20e-9
    expected = float(formula(n, tau)) * time_s
    se = K.std(ddof=1) / math.sqrt(n_pix)
    assert abs(K.mean() - expected) <= 3 * se + 1.0  # +1: the detector starts ready (O(1) per pixel)
    if model == "nonparalyzable":
        # renewal variance: interval tau + Exp(1/n)
        mu, s2 = tau + 1 / n, 1 / n ** 2
        assert variance_ratio_pvalue(K, time_s * s2 / mu ** 3) > ALPHA
        # the analytic engine's Markov chain gives the same mean rate
        a = detect(np.zeros((n_pix, T)), params, N, bin_width_ps=w, seed=21, engine="analytic").sum(1)
        s = expected / N
        assert abs(a.mean() - expected) <= 3 * math.sqrt(N * s * (1 - s) / n_pix) + 1.0
    # the stationary counts are uniform over the period
    assert chisq_gof(counts.sum(0), np.full(T, counts.sum() / T), ddof=1) > ALPHA


# ----------------------------------------------------------------- dark counts


@pytest.mark.parametrize("engine", ENGINES)
def test_dark_counts_are_uniform_in_time_with_poisson_totals(engine):
    rate, T, w, n_pix, N = 2e4, 100, 200.0, 64, 500_000  # window = the whole period
    params = DetectorParams(dark_count_rate_cps=rate, jitter_ps=25.0)
    counts = detect(np.zeros((n_pix, T)), params, N, bin_width_ps=w, seed=8, engine=engine).astype(float)
    tau_c = 50e-9  # the TCSPC's 20 MHz dead time dominates (0.1 % loss)
    per_pixel = nonparalyzable_rate(rate, tau_c) * N * 20e-9
    K = counts.sum(1)
    assert abs(K.sum() - n_pix * per_pixel) <= 3 * math.sqrt(n_pix * per_pixel)
    assert variance_ratio_pvalue(K, per_pixel) > ALPHA  # Poisson: variance = mean
    pooled = counts.sum(0)
    assert chisq_gof(pooled, np.full(T, pooled.sum() / T), ddof=1) > ALPHA


# ---------------------------------------------------------------------- jitter


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("tail_fraction, tail_ps", [(0.0, 0.0), (0.3, 40.0)])
def test_jitter_width_matches_the_parameter(engine, tail_fraction, tail_ps):
    T, w, n_pix, N = 400, 1.0, 64, 200_000
    ideal = np.zeros((n_pix, T))
    ideal[:, 100] = 1e-3
    params = DetectorParams(jitter_ps=25.0, irf_tail_fraction=tail_fraction, irf_tail_ps=tail_ps,
                            dark_count_rate_cps=0.0)
    hist = detect(ideal, params, N, bin_width_ps=w, seed=4, engine=engine).sum(0).astype(float)
    n = hist.sum()
    t = np.arange(T) + 0.5
    mean = (hist * t).sum() / n
    var = (hist * (t - mean) ** 2).sum() / (n - 1)
    sigma = 25.0 / (2 * math.sqrt(2 * math.log(2)))  # FWHM convention
    # source uniform in its bin (+1/12) and binning of the stamp (+1/12)
    exp_var = sigma ** 2 + tail_fraction * tail_ps ** 2 * (2 - tail_fraction) + 2 / 12
    exp_mean = 100.5 + tail_fraction * tail_ps
    # n ~ 1e4 detections: the sample mean and variance are normal to a good approximation; false-failure rate
    # ALPHA for the family of (up to) 3 checks
    z = z_bound(ALPHA, 3)
    assert abs(mean - exp_mean) <= z * math.sqrt(exp_var / n)
    # SE of a sample variance: sqrt((mu4 - var^2) / n); mu4 of a Gaussian-dominated shape <= 9 var^2
    assert abs(var - exp_var) <= z * math.sqrt(8 * exp_var ** 2 / n)
    if tail_fraction == 0:
        fwhm = math.sqrt(var - 2 / 12) * 2 * math.sqrt(2 * math.log(2))
        # Gaussian jitter plus two uniform terms: the uniforms' negative excess kurtosis makes mu4 <= 3 var^2, so
        # SE(var) <= var sqrt(2 / n); FWHM = k sqrt(var - 1/6) gives SE(FWHM) = FWHM var sqrt(2 / n) / (2 (var - 1/6))
        se_fwhm = 25.0 * exp_var * math.sqrt(2 / n) / (2 * (exp_var - 2 / 12))
        assert abs(fwhm - 25.0) <= z * se_fwhm


def test_measured_irf_is_applied(tmp_path):
    t = np.arange(-60.0, 61.0, 1.0)
    np.savetxt(tmp_path / "irf.txt", np.c_[t, np.exp(-0.5 * (t / 15.0) ** 2)])
    params = DetectorParams(irf_file=str(tmp_path / "irf.txt"), dark_count_rate_cps=0.0)
    ideal = np.zeros((64, 300))
    ideal[:, 150] = 1e-3
    for engine in ENGINES:
        hist = detect(ideal, params, 200_000, bin_width_ps=1.0, seed=2, engine=engine).sum(0).astype(float)
        x = np.arange(300) + 0.5
        mean = (hist * x).sum() / hist.sum()
        var = (hist * (x - mean) ** 2).sum() / hist.sum()
        # table cells of 1 ps add 1/12, like the source and the binning
        exp_var = 15.0 ** 2 + 3 / 12
        assert abs(mean - 150.5) <= 3 * math.sqrt(exp_var / hist.sum())
        assert abs(var - exp_var) <= 3 * math.sqrt(2 * exp_var ** 2 / hist.sum())


# ------------------------------------------------------------------------ gate


def test_gate_profile_is_the_documented_shape():
    t = np.linspace(-500.0, 3000.0, 7001)
    o, c, tr = 400.0, 1500.0, 120.0
    s = tr / (2 * stats.norm.ppf(0.9))
    documented = stats.norm.cdf((t - o) / s) - stats.norm.cdf((t - c) / s)
    assert np.allclose(gate_efficiency(t, o, c, tr), documented, atol=1e-12)
    # periodic: the same shape one period later
    P = 20000.0
    assert np.allclose(gate_efficiency(t + P, o, c, tr, P), documented, atol=1e-12)
    # bin averages are exact averages of the profile
    edges = np.arange(0.0, 2000.0, 25.0)
    fine = np.linspace(0, 1, 2001)
    avg = [np.trapezoid(gate_efficiency(a + 25.0 * fine, o, c, tr), fine) for a in edges[:-1]]
    assert np.allclose(gate_mean(edges, o, c, tr), avg, atol=1e-7)
    assert np.all(gate_efficiency(t, None, None, tr) == 1.0)


@pytest.mark.parametrize("transition", [30.0, 120.0, 400.0])
def test_gate_ten_ninety_transition_equals_the_parameter(transition):
    t = np.arange(-2000.0, 8000.0, 0.05)
    rise, fall = transition_10_90_ps(t, gate_efficiency(t, 0.0, 5000.0, transition))
    assert abs(rise - transition) < 0.1 and abs(fall - transition) < 0.1
    assert math.isclose(TEN_NINETY_PER_SIGMA, 2.5631031310892007)


@pytest.mark.parametrize("engine", ENGINES)
def test_detected_counts_follow_the_gate(engine):
    T, w, n_pix, N = 150, 10.0, 200, 50_000
    ideal = np.full((n_pix, T), 2e-5)  # flat, low flux
    params = DetectorParams(gate_open_ps=300.0, gate_close_ps=1100.0, gate_transition_ps=120.0, jitter_ps=0.0,
                            dark_count_rate_cps=0.0)
    counts = detect(ideal, params, N, bin_width_ps=w, seed=6, engine=engine).sum(0)
    exp = expected_counts_low_flux(ideal, params, N, bin_width_ps=w).sum(0)
    g = gate_mean(np.arange(T + 1) * w, 300.0, 1100.0, 120.0)
    assert np.allclose(exp, n_pix * N * 0.7 * 2e-5 * g, rtol=1e-3)
    assert chisq_gof(counts, exp, ddof=0) > ALPHA
    # a gate with a 400 ps transition is visibly slower than one with 120 ps (the test has power)
    slow = expected_counts_low_flux(ideal, params.replace(gate_transition_ps=400.0), N, bin_width_ps=w).sum(0)
    assert chisq_gof(counts, slow, ddof=0) < 1e-6
