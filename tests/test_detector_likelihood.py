"""The detector model as a differentiable layer: expected counts with first-photon pile-up and jitter,
their vector-Jacobian product, and the Poisson negative log-likelihood. Deterministic checks (float64
central differences, exact closed forms): no statistical false-failure rate."""

from __future__ import annotations

import numpy as np
import pytest

from spad_detector import DetectorParams, expected_counts_low_flux
from spad_detector.likelihood import ExpectedCounts, RenewalExpectedCounts, poisson_nll, poisson_nll_grad
from spad_detector.model import build_model

BW, T, T0 = 4.0, 96, 1000.0


def _layer(jitter_ps=25.0, pulses=10_000):
    p = DetectorParams(pde=0.7, jitter_ps=jitter_ps, dark_count_rate_cps=25.0, gate_open_ps=T0 + 40.0,
                       gate_close_ps=T0 + 300.0, gate_transition_ps=20.0).validate()
    return ExpectedCounts(build_model(p, bin_width_ps=BW, n_bins=T, t0_ps=T0), pulses)


def _ideal(scale, seed=0):
    rng = np.random.default_rng(seed)
    x = rng.random((3, T)) * scale
    x[:, 30:40] += 20 * scale  # a peak
    return x


def _assert_vjp_matches_central_differences(layer, x, scale):
    """``layer.vjp`` against central differences of ``layer`` along a random direction of size ``scale`` (step 1e-4,
    relative tolerance 1e-6)."""
    rng = np.random.default_rng(1)
    g, v = rng.standard_normal((3, T)), rng.standard_normal((3, T)) * scale
    h = 1e-4
    fd = (np.sum(g * layer(x + h * v)) - np.sum(g * layer(x - h * v))) / (2 * h)
    assert np.sum(layer.vjp(x, g) * v) == pytest.approx(fd, rel=1e-6, abs=1e-12)


@pytest.mark.parametrize("scale", [1e-5, 2e-2])  # low flux, and strong pile-up (about 2 photons per cycle)
@pytest.mark.parametrize("jitter_ps", [0.0, 25.0, 200.0])  # none, a short kernel, a long (FFT) one
def test_vjp_matches_central_differences(scale, jitter_ps):
    layer = _layer(jitter_ps)
    x = _ideal(scale)
    _assert_vjp_matches_central_differences(layer, x, scale)


def test_low_flux_limit_is_the_detectors_low_flux_mean():
    layer = _layer()
    x = _ideal(1e-10)  # pile-up ~ 1e-8 relative
    want = expected_counts_low_flux(x, layer.model.params, 10_000, bin_width_ps=BW, t0_ps=T0)
    np.testing.assert_allclose(layer(x), want, rtol=1e-5, atol=1e-12)


def test_pile_up_closed_form_for_one_bin():
    """All light in one bin, no jitter, no dark counts: the mean is N (1 - exp(-pde gate x)) there, and the
    bins after it are emptied by the first photon (exp(-lambda) of the cycles remain)."""
    p = DetectorParams(pde=0.5, jitter_ps=0.0, dark_count_rate_cps=0.0).validate()
    layer = ExpectedCounts(build_model(p, bin_width_ps=BW, n_bins=T, t0_ps=T0), 1000)
    x = np.zeros((1, T))
    x[0, 10], x[0, 20] = 2.0, 1.0
    m = layer(x)[0]
    assert m[10] == pytest.approx(1000 * -np.expm1(-1.0), rel=1e-12)
    assert m[20] == pytest.approx(1000 * np.exp(-1.0) * -np.expm1(-0.5), rel=1e-12)


def test_poisson_nll_and_its_gradient():
    rng = np.random.default_rng(2)
    mu = rng.random(50) * 5 + 0.1
    k = rng.poisson(mu)
    from scipy.stats import poisson

    assert poisson_nll(mu, k) == pytest.approx(-poisson.logpmf(k, mu).sum(), rel=1e-12)
    h = 1e-6
    e = np.zeros_like(mu)
    for i in range(0, 50, 7):
        e[:] = 0
        e[i] = h
        fd = (poisson_nll(mu + e, k) - poisson_nll(mu - e, k)) / (2 * h)
        assert poisson_nll_grad(mu, k)[i] == pytest.approx(fd, rel=1e-5)


def test_chain_gradient_of_the_likelihood_with_respect_to_the_ideal_capture():
    layer = _layer()
    x = _ideal(5e-3)
    k = np.random.default_rng(3).poisson(layer(x))
    grad = layer.vjp(x, poisson_nll_grad(layer(x), k))
    v = np.random.default_rng(4).standard_normal(x.shape) * 5e-3
    h = 1e-4
    fd = (poisson_nll(layer(x + h * v), k) - poisson_nll(layer(x - h * v), k)) / (2 * h)
    assert np.sum(grad * v) == pytest.approx(fd, rel=1e-5)


def _renewal_layer(pulses=10_000):
    """The paper's dead times (SPAD 10 ns, TCSPC 50 ns) at 50 MHz behind a 260 ps gate: the TCSPC blinds two
    whole cycles after each detection (the analytic engine's ``clean`` regime)."""
    p = DetectorParams(pde=0.7, jitter_ps=25.0, dark_count_rate_cps=25.0, gate_open_ps=T0 + 40.0,
                       gate_close_ps=T0 + 300.0, gate_transition_ps=20.0, repetition_rate_hz=50e6).validate()
    return RenewalExpectedCounts(build_model(p, bin_width_ps=BW, n_bins=T, t0_ps=T0), pulses)


@pytest.mark.parametrize("scale", [1e-5, 2e-2])
def test_renewal_vjp_matches_central_differences(scale):
    """The whole-blind-cycles mean's derivative, its factor ``1 / (1 + m P)`` included (float64, step 1e-4
    relative to the light: truncation ~1e-8, tolerance 1e-6)."""
    layer = _renewal_layer()
    x = _ideal(scale)
    assert np.all(layer.blind(x) == 2)
    _assert_vjp_matches_central_differences(layer, x, scale)


def test_renewal_mean_is_the_analytic_engines_mean():
    """The analytic engine's counts (exact renewal draws) of 64 saturated pixels (P 0.5 to 0.88 per cycle)
    against the layer's mean: the total within 5 standard deviations (the renewal count's variance is below
    its mean, so sqrt(total mean) bounds it; false-failure rate < 1e-6). The first-order factor of the
    fit's capture model (``1 / (1 + 1.5 P)``) is 17 % (75 standard deviations) too high here."""
    from spad_detector.engines.analytic import run_analytic

    layer = _renewal_layer()
    rng = np.random.default_rng(5)
    x = np.zeros((64, T))
    x[:, 30:40] = rng.uniform(0.1, 0.3, size=(64, 1))
    mean = layer(x)
    counts, info = run_analytic(layer.model, x, int(layer.n_pulses), np.random.default_rng(6), (8, 8))
    assert info["pixels_by_regime"]["whole_blind_cycles"] == 64, info
    total, sd = float(mean.sum()), float(np.sqrt(mean.sum()))
    assert abs(counts.sum() - total) <= 5 * sd, (counts.sum(), total, sd)
    first_order = float((ExpectedCounts(layer.model, layer.n_pulses)(x) / (1 + 1.5 * layer.probabilities(x)[2].sum(
        -1, keepdims=True))).sum())
    assert abs(first_order - total) > 50 * sd


@pytest.mark.parametrize("renewal", [False, True])
def test_probabilities_made_once_give_the_same_bytes(renewal):
    """A caller's :meth:`probabilities` passed to the mean and its vector-Jacobian product (the fit makes them once
    an iteration) change nothing: the same bytes as each computing its own."""
    layer = _layer()
    if renewal:
        layer = RenewalExpectedCounts(layer.model, layer.n_pulses)
    x = _ideal(2e-2)
    g = np.random.default_rng(3).standard_normal((3, T))
    pr = layer.probabilities(x)
    assert np.array_equal(layer(x, pr), layer(x))
    assert np.array_equal(layer.vjp(x, g, pr), layer.vjp(x, g))
