"""The exact and analytic engines: agreement where both apply, determinism, afterpulsing, crosstalk."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from detector_helpers import ALPHA, chisq_gof, two_sample_chisq
from spad_detector import DetectorParams, detect
from spad_detector.pileup import sample_renewal_counts


def _nlos_like(n_pix: int, T: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(T) + 0.5
    centre = rng.uniform(0.4 * T, 0.6 * T, (n_pix, 1))
    bump = np.exp(-0.5 * ((t - centre) / 6.0) ** 2)
    return 0.15 * bump / bump.sum(1, keepdims=True)


def _both(ideal, params, N, w, seed=1):
    out = {}
    for engine in ("analytic", "exact"):
        c, info = detect(ideal, params, N, bin_width_ps=w, seed=seed, engine=engine, return_info=True)
        out[engine] = (c.astype(float), info[0])
    return out


@pytest.mark.parametrize("params", [
    # the paper's detector, gated around the signal: whole blind cycles (m = 2 from the TCSPC)
    DetectorParams(gate_open_ps=200.0, gate_close_ps=800.0),
    # a paralyzable SPAD alone (m = 0): its extensions never reach the next window
    DetectorParams(gate_open_ps=200.0, gate_close_ps=800.0, dead_time_model="paralyzable",
                   tcspc_max_count_rate_hz=None, jitter_ps=60.0),
], ids=["paper_m2", "paralyzable_m0"])
def test_engines_agree_in_the_exact_regime_with_jitter(params):
    T, w, n_pix, N = 128, 8.0, 64, 30_000
    ideal = _nlos_like(n_pix, T)
    r = _both(ideal, params, N, w)
    assert r["analytic"][1]["exact"] and r["analytic"][1]["pixels_by_regime"]["whole_blind_cycles"] == n_pix
    a, e = r["analytic"][0], r["exact"][0]
    assert two_sample_chisq(a.sum(0), e.sum(0)) > ALPHA
    ka, ke = a.sum(1), e.sum(1)
    assert abs(ka.sum() - ke.sum()) <= 3 * math.sqrt(ka.var(ddof=1) * n_pix + ke.var(ddof=1) * n_pix)
    # per pixel, the analytic counts keep the renewal (sub-binomial) spread of the exact engine
    f = ka.var(ddof=1) / ke.var(ddof=1)
    assert stats.f.cdf(f, n_pix - 1, n_pix - 1) > ALPHA / 2 and stats.f.sf(f, n_pix - 1, n_pix - 1) > ALPHA / 2


@pytest.mark.parametrize("params", [
    DetectorParams(ambient_rate_cps=3e7, tcspc_max_count_rate_hz=None, jitter_ps=25.0),
    DetectorParams(ambient_rate_cps=1e7, tcspc_max_count_rate_hz=None, dead_time_ns=35.0),
], ids=["ungated_10ns", "ungated_35ns"])
def test_engines_agree_in_the_markov_chain_regime(params):
    T, w, n_pix, N = 128, 8.0, 32, 30_000
    ideal = _nlos_like(n_pix, T, seed=2)
    r = _both(ideal, params, N, w, seed=3)
    assert r["analytic"][1]["pixels_by_regime"]["markov_chain"] == n_pix  # exact mean, approximate variance
    a, e = r["analytic"][0], r["exact"][0]
    assert two_sample_chisq(a.sum(0), e.sum(0)) > ALPHA
    assert abs(a.sum() - e.sum()) <= 3 * math.sqrt(a.sum() + e.sum())


@pytest.mark.parametrize("engine", ["analytic", "exact"])
def test_same_seed_same_bytes(engine):
    ideal = _nlos_like(16, 64)
    params = DetectorParams(afterpulse_prob=0.05, crosstalk_prob=0.02)
    a = detect(ideal.reshape(4, 4, 64), params, 5000, bin_width_ps=10.0, seed=7, engine=engine)
    b = detect(ideal.reshape(4, 4, 64), params, 5000, bin_width_ps=10.0, seed=7, engine=engine)
    c = detect(ideal.reshape(4, 4, 64), params, 5000, bin_width_ps=10.0, seed=8, engine=engine)
    assert a.dtype == np.uint32 and a.tobytes() == b.tobytes() and a.tobytes() != c.tobytes()
    g = detect(ideal.reshape(4, 4, 64), params, 5000, bin_width_ps=10.0, rng=np.random.default_rng(7),
               engine=engine)
    assert g.tobytes() == a.tobytes()


def test_event_order_and_slots_are_numpys_bytes():
    """The exact engine's two numba helpers give the arrays of the numpy calls they replace: the slots of
    ``searchsorted`` over the flattened, row-offset CDF (a pixel without light, values just below 1), the order of
    ``argsort(kind="stable")`` with ties (equal times keep their input order) and, for times the radix cannot take
    (``-0.0``, negative), numpy's own order. Deterministic."""
    from spad_detector.engines._event_order import GUIDE, event_slots, guide_table, time_order

    rng = np.random.default_rng(11)
    n_pix, n_slots = 40, 157
    lam = rng.random((n_pix, n_slots)) ** 4
    lam[3] = 0.0
    tot = lam.sum(1)
    with np.errstate(invalid="ignore", divide="ignore"):
        cdf = np.where(tot[:, None] > 0, np.cumsum(lam, axis=1) / tot[:, None], 1.0)
    cdf[:, -1] = 1.0
    cdf_flat = (cdf + 2.0 * np.arange(n_pix)[:, None]).ravel()
    pix = np.repeat(np.arange(n_pix, dtype=np.int64), rng.poisson(np.where(tot > 0, 300, 0)))
    u = rng.random(pix.size)
    u[:6] = [0.0, np.nextafter(1.0, 0.0), cdf[0, 10], cdf[0, 0], 5 / GUIDE, np.nextafter(5 / GUIDE, 0.0)]  # (pixel
    # 0: values at slots, the first, at a guide threshold and just below it, and the ends)
    want = np.searchsorted(cdf_flat, u + 2.0 * pix, side="right") - pix * n_slots
    assert np.array_equal(event_slots(cdf_flat, n_slots, pix, u, guide_table(cdf_flat, n_slots)), want)
    t = rng.integers(0, 50, 20_000) * 1000.0 + np.round(rng.random(20_000) * 1000.0, 1)
    t[::5] = t[7]  # (ties)
    t[11] = 0.0
    assert np.array_equal(time_order(t), np.argsort(t, kind="stable"))
    for bad in (-0.0, -3.0):
        t2 = t.copy()
        t2[13] = bad
        assert np.array_equal(time_order(t2), np.argsort(t2, kind="stable"))


def test_exact_engine_counts_are_the_bytes_of_the_numpy_ordering(monkeypatch):
    """The exact engine with its numba slots and radix order gives the counts (bytes) of the same seed with numpy's
    ``searchsorted`` and stable ``argsort`` in their place (afterpulses and crosstalk on: every path of the event
    loop)."""
    from spad_detector.engines import exact

    ideal = _nlos_like(16, 64).reshape(4, 4, 64)
    params = DetectorParams(afterpulse_prob=0.05, crosstalk_prob=0.02)
    ours = detect(ideal, params, 20_000, bin_width_ps=10.0, seed=5, engine="exact")
    monkeypatch.setattr(exact, "event_slots", lambda cdf_flat, n_slots, pix, u, guide: np.searchsorted(
        cdf_flat, u + 2.0 * pix, side="right") - pix * n_slots)
    monkeypatch.setattr(exact, "time_order", lambda t: np.argsort(t, kind="stable"))
    numpys = detect(ideal, params, 20_000, bin_width_ps=10.0, seed=5, engine="exact")
    assert ours.sum() > 0 and ours.tobytes() == numpys.tobytes()


def test_auto_engine_picks_analytic_when_exact_and_exact_when_cheap():
    ideal = _nlos_like(4, 64)
    gated = DetectorParams(gate_open_ps=150.0, gate_close_ps=500.0)
    _, info = detect(ideal, gated, 1000, bin_width_ps=8.0, return_info=True)
    assert info[0]["engine"] == "analytic" and info[0]["exact"]
    _, info = detect(ideal, DetectorParams(), 1000, bin_width_ps=8.0, return_info=True)
    assert info[0]["engine"] == "exact"  # ungated dark counts: the analytic one would approximate


def test_renewal_sampler_matches_a_direct_simulation():
    rng = np.random.default_rng(0)
    n_cycles, p, m, n = 40, 0.3, 2, 40_000
    K = sample_renewal_counts(rng, n_cycles, np.full(n, p), np.full(n, m))
    # direct simulation of the detector: ready -> fires with p -> blind m cycles
    fire = rng.random((n, n_cycles)) < p
    blind = np.zeros(n, dtype=int)
    direct = np.zeros(n, dtype=int)
    for c in range(n_cycles):
        ready = blind == 0
        hit = ready & fire[:, c]
        direct += hit
        blind = np.where(hit, m, np.maximum(blind - 1, 0))
    kmax = int(max(K.max(), direct.max())) + 1
    assert two_sample_chisq(np.bincount(K, minlength=kmax), np.bincount(direct, minlength=kmax)) > ALPHA
    # m = 0 is the binomial
    K0 = sample_renewal_counts(rng, n_cycles, np.full(n, p), np.zeros(n, int))
    exp = n * stats.binom.pmf(np.arange(n_cycles + 1), n_cycles, p)
    assert chisq_gof(np.bincount(K0, minlength=n_cycles + 1), exp) > ALPHA


# -------------------------------------------------------------- afterpulsing


def test_afterpulses_follow_their_probability_and_delay():
    T, w, n_pix, N = 200, 100.0, 32, 100_000  # 20 ns window = the period
    ideal = np.zeros((n_pix, T))
    ideal[:, 20] = 0.01
    p_ap, delay_ns, dead_ns = 0.2, 2.0, 10.0
    params = DetectorParams(pde=1.0, dark_count_rate_cps=0.0, jitter_ps=0.0, tcspc_max_count_rate_hz=None,
                            dead_time_ns=dead_ns, afterpulse_prob=p_ap, afterpulse_delay_ns=delay_ns)
    c, info = detect(ideal, params, N, bin_width_ps=w, seed=12, engine="exact", return_info=True)
    info = info[0]
    primary = info["avalanches"] - info["afterpulse_avalanches"]
    # afterpulses per primary avalanche: an afterpulse can afterpulse again, so a geometric number
    # with mean p / (1 - p) and variance p / (1 - p)^2 (the SPAD is always ready again at this flux)
    frac = info["afterpulse_avalanches"] / primary
    exp = p_ap / (1 - p_ap)
    assert abs(frac - exp) <= 3 * math.sqrt(p_ap / primary) / (1 - p_ap)
    # first-generation afterpulses land dead_time + Exp(delay) after the signal bin
    hist = c.sum(0).astype(float)
    late = np.arange(T) * w + 0.5 * w - 20.5 * w  # delay of each bin's centre after the signal
    sel = (late > dead_ns * 1e3) & (late < 2 * dead_ns * 1e3)
    mean_delay = (hist[sel] * late[sel]).sum() / hist[sel].sum()
    # truncated exponential mean over [dead, 2 dead] (second generation starts at 2 dead)
    tau, a = delay_ns * 1e3, dead_ns * 1e3
    trunc_mean = a + tau - a * math.exp(-a / tau) / (1 - math.exp(-a / tau))
    # (its standard deviation is below tau; bin centres shift the mean by less than half a bin)
    assert abs(mean_delay - trunc_mean) <= 3 * tau / math.sqrt(hist[sel].sum()) + 0.5 * w
    # the analytic engine's first-order afterpulsing puts the same counts there
    ca = detect(ideal, params, N, bin_width_ps=w, seed=12, engine="analytic").sum(0).astype(float)
    assert two_sample_chisq(ca[sel], hist[sel]) > ALPHA
    assert abs(ca[sel].sum() - hist[sel].sum()) <= 3 * math.sqrt(ca[sel].sum() + hist[sel].sum())


# ----------------------------------------------------------------- crosstalk


def test_crosstalk_reaches_the_four_neighbours_at_the_same_time():
    T, w, N, p_xt = 64, 10.0, 200_000, 0.1
    ideal = np.zeros((3, 3, T))
    ideal[1, 1, 30] = 0.02  # only the centre pixel sees light
    params = DetectorParams(pde=1.0, dark_count_rate_cps=0.0, jitter_ps=0.0, crosstalk_prob=p_xt)
    c, info = detect(ideal, params, N, bin_width_ps=w, seed=13, engine="exact", return_info=True)
    c = c.astype(float)
    centre = c[1, 1].sum()
    edges = np.array([c[0, 1].sum(), c[1, 0].sum(), c[1, 2].sum(), c[2, 1].sum()])
    corners = np.array([c[0, 0].sum(), c[0, 2].sum(), c[2, 0].sum(), c[2, 2].sum()])
    # each edge neighbour fires with p_xt per centre avalanche; the edges are not adjacent to each
    # other, so the next paths (centre -> edge -> corner -> edge) are of order p_xt^3
    for k in edges:
        assert abs(k - p_xt * centre) <= 3 * math.sqrt(centre * p_xt * (1 - p_xt)) + 2 * p_xt ** 3 * centre
    assert corners.sum() < edges.sum() * 4 * p_xt
    assert np.all(c[0, 1, :30] == 0) and c[0, 1, 30] == c[0, 1].sum()  # same bin as the signal
    ca = detect(ideal, params, N, bin_width_ps=w, seed=13, engine="analytic").astype(float)
    ea = np.array([ca[0, 1].sum(), ca[1, 0].sum(), ca[1, 2].sum(), ca[2, 1].sum()])
    assert abs(ea.sum() - edges.sum()) <= 3 * math.sqrt(ea.sum() + edges.sum())


# ---------------------------------------------------------------- jitter kernel


def test_jitter_kernel_convolution_matches_a_direct_sum():
    from spad_detector.model import apply_jitter_kernel

    rng = np.random.default_rng(0)
    for first, K in [(-3, 7), (2, 5), (-40, 81), (5, 30)]:  # direct and FFT paths
        x, k = rng.random((3, 50)), rng.random(K)
        ref = np.zeros_like(x)
        for b in range(50):
            for j in range(K):
                if 0 <= b - first - j < 50:
                    ref[:, b] += x[:, b - first - j] * k[j]
        assert np.allclose(apply_jitter_kernel(x, first, k), ref, atol=1e-12)


@pytest.mark.parametrize("kw", [dict(jitter_ps=25.0), dict(jitter_ps=10.0, irf_tail_fraction=0.3, irf_tail_ps=30.0),
                                dict(jitter_ps=0.0, irf_tail_fraction=1.0, irf_tail_ps=12.0)])
def test_jitter_bin_kernel_matches_sampled_delays(kw):
    from spad_detector import Jitter

    w = 8.0
    jit = Jitter.from_params(DetectorParams(**kw))
    first, k = jit.bin_kernel(w)
    assert abs(k.sum() - 1) < 1e-9
    rng = np.random.default_rng(1)
    n = 200_000
    shift = np.floor(rng.random(n) + jit.sample(rng, n) / w).astype(int) - first
    assert shift.min() >= 0 and shift.max() < len(k)
    assert chisq_gof(np.bincount(shift, minlength=len(k)), n * k, ddof=0) > ALPHA


def test_support_trims_only_negligible_intensity():
    from spad_detector.pileup import support

    rng = np.random.default_rng(0)
    lam = rng.random((200, 30)) * (rng.random((200, 30)) < 0.3) * 1e-6
    neg = 2e-7
    ia, ib = support(lam, neg)
    for i in range(len(lam)):
        head = np.cumsum(lam[i])
        tail = np.cumsum(lam[i][::-1])[::-1]
        if head[-1] <= 2 * neg:
            assert (ia[i], ib[i]) == (30, -1)
            continue
        assert ia[i] == np.argmax(head > neg) and ib[i] == np.nonzero(tail > neg)[0].max()
        assert lam[i, :ia[i]].sum() <= neg and lam[i, ib[i] + 1:].sum() <= neg
