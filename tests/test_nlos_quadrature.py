"""The deterministic three-bounce estimator (``estimator="quadrature"``, transient_mi.integrators._nlos_quadrature).

* the time spread of one element is the exact distribution of a linear path length over (triangle x cell),
  checked against a dense deterministic grid;
* a small Lambertian patch against the closed form of ``nlos_helpers`` (Gauss-Legendre over patch and target)
  to 1e-4;
* against the Monte Carlo estimator on the letter and on a partly occluded target (their difference within
  Monte Carlo's Student-t interval plus the quadrature's bound);
* self-convergence: the stated error of a coarse level covers its actual error against a fine level;
* the render pipeline stores the bound like a variance and ``detect`` states the ratio; same bytes twice;
* captures it cannot render are refused in one line.
"""

from __future__ import annotations

import functools
import json
import math
import unittest.mock as mock

import numpy as np
import pytest

import transient_mi  # noqa: F401  (LLVM + variant + plug-ins)
from nlos_helpers import nlos_scene, patch_centers, square, three_bounce_reference
from stats_helpers import t_bound
from transient_mi.integrators._nlos_time_spread import spread_pairs
from transient_mi.props import PluginParameterError

#: False-failure rate of each Monte Carlo comparison below (family-wise, Bonferroni over its checks).
ALPHA = 1e-3


def _quadrature(scene, **settings):
    integ = scene.integrator()
    integ.nlos_options.update(estimator="quadrature", **settings)
    return integ


def _render(scene, spots=None, **settings):
    integ = _quadrature(scene, **settings)
    sensor = scene.sensors()[0]
    if spots is None:
        return integ.render_transient(scene, sensor, seed=0, spp=1, spot=0)
    return integ.render_transient(scene, sensor, seed=0, spp=1, spots=spots)


# ---------------------------------------------------------------- time spread


@pytest.mark.parametrize("t,w1,w2,tilt", [((3.2, 4.7, 7.1), 2.3, 0.7, (0.0, 0.0)), ((3.2, 3.2, 7.1), 0.0, 0.7, (0.0, 0.0)),
                                          ((3.2, 7.1, 7.1), 3.0, 0.0, (0.0, 0.0)), ((8.5, 8.6, 8.61), 5.0, 5.0, (0.0, 0.0)),
                                          ((3.25, 3.25, 3.25), 0.0, 0.0, (0.0, 0.0)), ((3.5, 3.6, 12.61), 1e-9, 0.3, (0.0, 0.0)),
                                          ((3.2, 4.7, 7.1), 2.3, 0.7, (0.6, -0.4)), ((8.5, 8.6, 8.61), 5.0, 5.0, (-0.8, 0.3)),
                                          ((3.25, 3.25, 3.25), 4.0, 1.5, (0.5, 0.9)), ((3.2, 7.1, 7.1), 3.0, 0.0, (0.7, 0.5))])
def test_time_spread_is_the_exact_distribution(t, w1, w2, tilt):
    """Bin masses of (triangle with vertex values t) + two centred uniforms of widths w1, w2 whose amplitude is
    linear across the cell (``1 + tilt . v``, ``v`` the cell coordinates in [-1/2, 1/2]), against a dense
    deterministic reference: the triangle's values on a 600 x 600 barycentric grid and the cell's on a 200 x 200
    grid (weighted by the tilt), each histogrammed at 1/50 bin, convolved, summed into bins (deterministic: the
    tolerance is the reference's own discretisation, a fiftieth of a bin of shift at most). A tilt along a zero
    width moves nothing."""
    t = np.sort(np.asarray(t, float))
    n = 600
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    keep = i + j < n  # centroids of the upright sub-triangles and (below) of the inverted ones
    u = np.concatenate([(i[keep] + 1 / 3) / n, (i[i + j < n - 1] + 2 / 3) / n])
    v = np.concatenate([(j[keep] + 1 / 3) / n, (j[i + j < n - 1] + 2 / 3) / n])
    a = t[0] + u * (t[1] - t[0]) + v * (t[2] - t[0])
    g = (np.arange(200) + 0.5) / 200 - 0.5
    c = (g[:, None] * w1 + g[None, :] * w2).reshape(-1)
    wc = (1.0 + tilt[0] * g[:, None] + tilt[1] * g[None, :]).reshape(-1)
    sub = 50
    edges = np.arange(-24 * sub, 24 * sub + 1) / sub
    ha = np.histogram(a, bins=edges)[0] / a.size
    hc = np.histogram(c, bins=edges, weights=wc)[0] / c.size
    fine = np.convolve(ha, hc)  # support starts at 2 * edges[0] = -48 bins
    ref = np.add.reduceat(fine[(48 * sub):(48 * sub + 24 * sub)], np.arange(0, 24 * sub, sub))
    hist = np.zeros((1, 24))
    bound = np.zeros((1, 24))
    out = spread_pairs(hist, bound, np.array([0]), np.array([1.0]), np.array([0.0]), np.array([t[0]]),
                       np.array([t[1] - t[0]]), np.array([t[2] - t[0]]), np.array([w1]), np.array([w2]),
                       np.array([tilt], dtype=float), 24)
    assert out[0] == pytest.approx(0.0, abs=1e-12)
    assert hist.sum() == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(hist[0], ref, atol=5e-3)


def _g_ref(k, y, a, b):
    """``G_k(y) = E[(y - A)_+^k] / k!`` of the triangular distribution on ``0 <= a <= b``, one antiderivative per
    call (the plain form the production code evaluates four points at a time)."""
    if y <= 0.0:
        return 0.0
    mu, var = (a + b) / 3.0, (a * a + b * b - a * b) / 18.0
    mu3 = (b - 2.0 * a) * (a + b) * (2.0 * b - a) / 270.0
    d = y - mu
    far = [1.0, d, 0.5 * (d * d + var), (d ** 3 + 3.0 * d * var - mu3) / 6.0]
    if b <= 0.0:
        return y ** k / math.factorial(k)
    if y >= b:
        return far[k]
    if y <= a:
        return 2.0 / (b * a) * y ** (k + 2) / math.factorial(k + 2)
    return far[k] - (-1) ** k * 2.0 / (b * (b - a)) * (b - y) ** (k + 2) / math.factorial(k + 2)


def _tilted_cdf_ref(x, a, b, w1, w2, t1, t2):
    """``P(T <= x) + t1 E[v1 1{T <= x}] + t2 E[v2 1{T <= x}]`` by nested differences of ``_g_ref`` (both widths
    finite)."""
    cdf = (_g_ref(2, x + w1 / 2 + w2 / 2, a, b) - _g_ref(2, x - w1 / 2 + w2 / 2, a, b)
           - _g_ref(2, x + w1 / 2 - w2 / 2, a, b) + _g_ref(2, x - w1 / 2 - w2 / 2, a, b)) / (w1 * w2)

    def moment(w, wo):  # E[v 1{A + w v + U' <= x}] by parts over v (U' of width wo)
        def K(j, s):
            return (_g_ref(j + 1, s + wo / 2, a, b) - _g_ref(j + 1, s - wo / 2, a, b)) / wo
        lo, hi = x - w / 2, x + w / 2
        return (K(2, hi) - K(2, lo) - w / 2 * (K(1, lo) + K(1, hi))) / w ** 2

    return cdf + t1 * moment(w1, w2) + t2 * moment(w2, w1)


def test_bin_masses_equal_the_plain_antiderivative_form():
    """The production masses (G_2 and G_3 at the four corner points of each edge, shared by the CDF and both tilt
    moments) equal the same mathematics evaluated one antiderivative at a time, to 1e-12 of the pair's mass, on
    random well-conditioned pairs (widths above a tenth of the spread; deterministic)."""
    rng = np.random.default_rng(3)
    for _ in range(300):
        ab = np.sort(rng.exponential(1.5, 2))
        a, b = float(ab[0]), float(ab[1])
        w1, w2 = rng.uniform(0.1, 3.0, 2) * (b + 0.5)
        t1, t2 = rng.uniform(-0.9, 0.9, 2)
        tlo = float(rng.uniform(2.0, 3.0))
        n_ext = 40
        hist = np.zeros((1, n_ext))
        spread_pairs(hist, np.zeros((1, n_ext)), np.array([0]), np.array([1.0]), np.array([0.0]), np.array([tlo]),
                     np.array([a]), np.array([b]), np.array([w1]), np.array([w2]), np.array([[t1, t2]]), n_ext)
        edges = np.arange(n_ext + 1) - tlo
        lo, hi = -(w1 + w2) / 2, b + (w1 + w2) / 2
        cdf = np.array([0.0 if x <= lo else 1.0 if x >= hi else _tilted_cdf_ref(x, a, b, w1, w2, t1, t2)
                        for x in edges])
        np.testing.assert_allclose(hist[0], np.diff(cdf), rtol=0, atol=1e-12)


def test_wide_pairs_equal_the_plain_form():
    """Pairs that span many bins (the paper scene's 1 ps bins: about 80) take the vectorised path (the CDF at every
    edge, then its differences from the last bin down); their masses equal the plain antiderivative form to 1e-12
    of the pair's mass on random well-conditioned pairs of 15 to 150 bins (deterministic), and the light inside the
    axis is the whole pair's, exactly."""
    from transient_mi.integrators._nlos_time_spread import VECTOR_EDGES

    rng = np.random.default_rng(5)
    n_ext = 200
    for _ in range(60):
        ab = np.sort(rng.uniform(0.0, 40.0, 2))
        a, b = float(ab[0]), float(ab[1])
        w1, w2 = rng.uniform(0.1, 1.5, 2) * (b + 5.0)
        t1, t2 = rng.uniform(-0.9, 0.9, 2)
        tlo = float(rng.uniform(2.0, 3.0)) + (w1 + w2) / 2
        assert np.floor(tlo + b + (w1 + w2) / 2) - np.floor(tlo - (w1 + w2) / 2) >= VECTOR_EDGES
        hist = np.zeros((1, n_ext))
        out = spread_pairs(hist, np.zeros((1, n_ext)), np.array([0]), np.array([1.0]), np.array([0.0]),
                           np.array([tlo]), np.array([a]), np.array([b]), np.array([w1]), np.array([w2]),
                           np.array([[t1, t2]]), n_ext)
        assert out[0] == 0.0
        edges = np.arange(n_ext + 1) - tlo
        lo, hi = -(w1 + w2) / 2, b + (w1 + w2) / 2
        cdf = np.array([0.0 if x <= lo else 1.0 if x >= hi else _tilted_cdf_ref(x, a, b, w1, w2, t1, t2)
                        for x in edges])
        np.testing.assert_allclose(hist[0], np.diff(cdf), rtol=0, atol=1e-12)


def _tilted_cdf_exact(x, a, b, h1, h2, c0, c1, c2, c3):
    """The tilted CDF of ``_cdf_widths`` (both widths, both cell tilts, the element's slope) in exact rational
    arithmetic from the inputs' float values: the triangular density as jumps ``J_m`` and slope changes ``s_m`` at
    its knots ``tau = 0, a, b``, so ``G_j(y) = sum_m J_m (y - tau_m)_+^(j+1) / (j+1)! + s_m (y - tau_m)_+^(j+2) /
    (j+2)!`` (a jump only where two knots coincide)."""
    from fractions import Fraction as Fr
    from math import factorial

    x, a, b, h1, h2, c0, c1, c2, c3 = (Fr(float(v)) for v in (x, a, b, h1, h2, c0, c1, c2, c3))
    if a == 0:
        knots = ((0, 2 / b, -2 / b ** 2), (b, 0, 2 / b ** 2))
    elif a == b:
        knots = ((0, 0, 2 / b ** 2), (b, -2 / b, -2 / b ** 2))
    else:
        ca, cb = 2 / (a * b), 2 / (b * (b - a))
        knots = ((0, 0, ca), (a, 0, -(ca + cb)), (b, 0, cb))

    def g(j, y):
        return sum(jump * max(y - t, Fr(0)) ** (j + 1) / factorial(j + 1)
                   + slope * max(y - t, Fr(0)) ** (j + 2) / factorial(j + 2) for t, jump, slope in knots)

    pts = [x + h1 + h2, x - h1 + h2, x + h1 - h2, x - h1 - h2]
    p2, p3 = [g(2, y) for y in pts], [g(3, y) for y in pts]
    d2, d3 = p2[0] - p2[1] - p2[2] + p2[3], p3[0] - p3[1] - p3[2] + p3[3]
    s1, s2 = p2[0] + p2[1] - p2[2] - p2[3], p2[0] + p2[2] - p2[1] - p2[3]
    return float(c0 * d2 + c1 * (d3 - h1 * s1) + c2 * (d3 - h2 * s2)
                 + c3 * ((x - (a + b) / 3) * d2 + h1 * s1 + h2 * s2 - 3 * d3))


def test_far_run_closed_form_is_exact_to_rounding():
    """Where all four points ``x +- h1 +- h2`` lie at or above the middle knot ``a`` the masses take the closed form
    of ``_cdf_far`` (the polynomial parts' differences over the two widths are exact, only the ``(b - y)_+`` tails
    are summed). On random pairs with both cell tilts and the element's slope, including knots that coincide
    (``a = 0``, ``a = b``) or nearly do, it equals the exact rational value to 1e-11 at every such edge, as the form
    that evaluates every point's piece (``_cdf_widths``) does (the CDF runs from 0 to 1; both lose digits to the
    tails' second difference over a narrow width: worst 4.3e-12 and 3.9e-12 here, at b = 166 bins and a width of
    1.1), and it is exactly 1 once every point is past ``b`` (deterministic)."""
    from transient_mi.integrators._nlos_time_spread import _cdf_widths

    from transient_mi.integrators._nlos_time_spread import _cdf_far, _far_factors, _shape, cell_widths

    rng = np.random.default_rng(11)
    for trial in range(120):
        b = float(rng.uniform(1.0, 200.0))
        a = [0.0, b, b * 1e-9, b * (1 - 1e-9)][trial] if trial < 4 else float(b * rng.uniform())
        u1, u2 = rng.uniform(0.5, 120.0, 2)
        t1, t2 = rng.uniform(-0.9, 0.9, 2)
        beta = float(rng.uniform(-1.0, 1.0)) / (b + 1.0)
        k = _shape(a, b)
        _, _, h1, h2, i1, i2, _, _ = cell_widths(u1, u2, t1, t2)
        c0 = i1 * i2
        c1, c2, c3 = t1 * c0 * i1, t2 * c0 * i2, beta * c0
        f = _far_factors(k, h1, h2, c0, c1, c2, c3)
        for x in np.linspace(a + h1 + h2, b + h1 + h2, 12):
            exact = _tilted_cdf_exact(x, a, b, h1, h2, c0, c1, c2, c3)
            assert abs(_cdf_far(x, k, h1, h2, f) - exact) <= 1e-11, (a, b, x)
            assert abs(_cdf_widths(x, k, h1, h2, c0, c1, c2, c3) - exact) <= 1e-11, (a, b, x)
        for x in (b + h1 + h2, b + h1 + h2 + 3.7):
            assert _cdf_far(x, k, h1, h2, f) == 1.0


def test_rounding_residue_below_zero_is_cleared_and_nothing_else():
    """A bin a few 1e-14 of its pixel's largest below zero (a difference of two equal CDF values, rounded) becomes
    0, so the capture writer accepts it (the paper scene's 1 ps bins have such); a negative bin beyond
    ``ROUNDING_RESIDUE`` of the largest is no rounding and is kept for the writer to refuse; the rest is
    untouched."""
    from transient_mi.integrators._nlos_rounding import ROUNDING_RESIDUE, finish_rows

    h = np.array([[1.0, -6e-14, 0.5, 0.0], [2.0, -3.0 * ROUNDING_RESIDUE * 2.0, 1e-30, -1e-300]])
    out = h.copy()
    finish_rows(out, np.zeros_like(h))
    np.testing.assert_array_equal(out, [[1.0, 0.0, 0.5, 0.0], [2.0, h[1, 1], 1e-30, 0.0]])


def test_rounding_residue_of_the_error_files_is_measured_against_the_light():
    """The error files' mixed-visibility part is light spread by the same masses, so its rounding residue is
    relative to the pixel's light, not to the error's own largest bin (the 32 x 32 paper scene at 1 ps bins had
    error bins at -1e-20 where the error's largest was 1e-12 and the light's 1e-8, which the writer refused)."""
    from transient_mi.integrators._nlos_rounding import ROUNDING_RESIDUE, finish_rows

    light = np.array([[1e-8, 5e-9, 0.0]])
    err = np.array([[1e-12, -1e-20, -3.0 * ROUNDING_RESIDUE * 1e-8]])
    out = err.copy()
    finish_rows(light.copy(), out)
    np.testing.assert_array_equal(out, [[1e-12, 0.0, err[0, 2]]])
    alone = err.copy()  # (as light itself: against its own largest, 1e-12, it is no rounding)
    finish_rows(alone, np.zeros_like(err))
    assert alone[0, 1] == -1e-20


# ---------------------------------------------------------------- closed form

X0 = np.array([0.05, -0.03, 0.35])
SIDE = 0.01
W = H = 2
FP = 0.01


def test_small_patch_matches_the_closed_form_to_1e4():
    """Pixel totals of a 1 cm Lambertian square against ``three_bounce_reference`` (Gauss-Legendre, 16 nodes
    per axis over patch and target): relative error <= 1e-4, and within the stated bound."""
    scene = nlos_scene(width=W, height=H, footprint=FP, include_wall_return=False, n_bins=400, bin_width_ps=8.0,
                       t0_ps=11000.0, hidden=[square(X0, SIDE, 0.6)])
    res = _render(scene, element_size_m=0.0025, patch_cells=4)
    centers = patch_centers(W, H, FP)
    for y in range(H):
        for x in range(W):
            ref = three_bounce_reference(np.zeros(3), centers[y, x], FP, X0, SIDE, 0.6, n=16)[0]
            got = float(res.histogram[y, x].astype(np.float64).sum())
            assert abs(got - ref) <= 1e-4 * ref, (x, y, got, ref)
            assert abs(got - ref) <= float(res.total_error_bound[y, x]) + 1e-7 * ref


# ---------------------------------------------------------------- against Monte Carlo


def _mc_vs_quadrature(scene_q, scene_mc, spp, spots, settings, n_windows=8, full=False):
    """Compare pixel x time-window sums: |quadrature - MC| <= t * se_MC + bound (t from the 8 replicates).
    Returns the totals ``(quadrature, MC)``, with ``full`` also MC's standard error of the total and the stated
    total error."""
    q = _render(scene_q, spots=spots, **settings)
    integ = scene_mc.integrator()
    integ.nlos_options.update(estimator="monte_carlo")  # whatever the scene's default estimator
    integ.variance_replicates = 8
    mc = integ.render_transient(scene_mc, scene_mc.sensors()[0], seed=3, spp=spp, spots=spots)
    checks = []
    for rq, rm in zip(q, mc):
        T = rq.histogram.shape[-1]
        P = rq.histogram.shape[0] * rq.histogram.shape[1]
        wq = rq.histogram.astype(np.float64).reshape(P, n_windows, T // n_windows).sum(-1)
        wm = rm.histogram.astype(np.float64).reshape(P, n_windows, T // n_windows).sum(-1)
        # window variance from the replicates' per-bin variances (bins of one window are nearly independent:
        # each sample adds to one bin per spot; see spad_detector.render_noise)
        vm = rm.variance.astype(np.float64).reshape(P, n_windows, T // n_windows).sum(-1)
        wb = rq.error_bound.astype(np.float64).reshape(P, n_windows, T // n_windows).sum(-1)
        lit = vm > 0
        checks.append((wq[lit], wm[lit], np.sqrt(vm[lit]), wb[lit]))
    n = sum(len(c[0]) for c in checks)
    tb = t_bound(8, ALPHA, n)
    for wq, wm, se, wb in checks:
        bad = np.abs(wq - wm) > tb * se + wb
        assert not bad.any(), (wq[bad][:5], wm[bad][:5], se[bad][:5], wb[bad][:5])
    tot_q = sum(float(r.steady.sum()) for r in q)
    tot_m = sum(float(r.steady.sum()) for r in mc)
    if not full:
        return tot_q, tot_m
    # the totals' interval: Monte Carlo's standard error of the total (its replicates) and the stated total error
    se_tot = math.sqrt(sum(float(np.sum(r.total_variance, dtype=np.float64)) for r in mc))
    bound_tot = sum(float(np.sum(r.total_error_bound, dtype=np.float64)) for r in q)
    return tot_q, tot_m, se_tot, bound_tot


LETTER = dict(include_wall_return="false", width="4", height="4", spots_x="2", spots_y="1", n_bins="512",
              bin_width_ps="16")


def test_letter_agrees_with_monte_carlo():
    """The README's letter (4 x 4 pixels, 2 spots): every lit pixel x 64-bin window within Monte Carlo's t
    interval (8 replicates, family-wise false-failure rate 1e-3) plus the bound; totals within 0.2 %."""
    from transient_mi.scene_io import load_scene

    tq, tm_ = _mc_vs_quadrature(load_scene("scenes/nlos_letter.xml", LETTER),
                                load_scene("scenes/nlos_letter.xml", LETTER), 4096, [0, 1],
                                dict(element_size_m=0.01, patch_cells=4))
    assert abs(tq - tm_) <= 2e-3 * tm_


def _occluder_scene(width: int = 3, capture: str = "array"):
    """A target half hidden behind a smaller occluder (mixed visibility, so the quadrature refines), ``width`` x
    ``width`` pixels, 256 bins of 16 ps from 8 ns, no wall return."""
    return nlos_scene(width=width, height=width, footprint=0.05, include_wall_return=False, n_bins=256,
                      bin_width_ps=16.0, t0_ps=8000.0, capture=capture,
                      hidden=[square((0.0, 0.0, 0.5), 0.2, 0.7, id_="far"),
                              square((0.05, 0.05, 0.3), 0.08, 0.5, id_="near")])


def _assert_agree_within_errors(p, q):
    """Two quadrature captures of one scene agree within their stated errors: every pixel's total within the sum
    of their total errors (relative 1e-6 for rounding), the largest bin difference within the sum of their largest
    per-bin errors; ``q`` has light in every pixel."""
    a, b = (r.histogram.astype(np.float64) for r in (p, q))
    ta, tb = a.sum(-1), b.sum(-1)
    assert tb.min() > 0
    err = p.total_error_bound.astype(np.float64) + q.total_error_bound.astype(np.float64)
    assert (np.abs(ta - tb) <= err + 1e-6 * tb).all()
    assert np.abs(a - b).max() <= float(p.error_bound.max()) + float(q.error_bound.max())


def test_occluded_target_agrees_with_monte_carlo():
    """A target half hidden behind a smaller occluder (mixed visibility, refined): within Monte Carlo's
    interval plus the stated error, which here includes the mixed-visibility bound."""
    sq = _occluder_scene()
    q = _render(sq, element_size_m=0.02, patch_cells=2, refine_levels=3)
    assert q.estimator_info["refine_levels"] >= 1  # the occluder's shadow was refined
    assert float(q.error_bound.sum()) > 0  # mixed pairs remain and are bounded
    _mc_vs_quadrature(_occluder_scene(), _occluder_scene(), 2048, [0],
                      dict(element_size_m=0.02, patch_cells=2, refine_levels=3))


def test_visibility_refinement_splits_the_elements_whose_lit_pairs_are_mixed():
    """The refinement's test (:func:`~transient_mi.integrators._nlos_refinement.mixed_lit`) splits an element
    for a pair (cell, spot) that can carry light and sees its samples partly, as the render bounds it: the cell's
    and the spot's masks combined (a spot seeing samples 2-3 and a cell seeing 0-1 light nothing), the cell and the
    spot on one side of a Lambertian element's normal, and for a confocal capture each cell with its own pixel's
    spot only. One element at the origin facing +z."""
    from transient_mi.integrators._nlos_refinement import mixed_lit

    X0 = np.zeros((1, 3))
    n_sh = np.array([[0.0, 0.0, 1.0]])
    front, back = np.array([[0.0, 0.0, 1.0]]), np.array([[0.0, 0.0, -1.0]])

    def test(vc, vs, cell_p, S, cell_spot=(-1,), side_test=True):
        out = np.zeros(1, dtype=bool)
        mixed_lit(np.array(vc, dtype=np.uint8).reshape(len(cell_p), 1), np.array(vs, dtype=np.uint8).reshape(1, -1),
                  0, X0, n_sh, np.asarray(cell_p, dtype=np.float64), np.asarray(S, dtype=np.float64),
                  np.array(cell_spot, dtype=np.int64), side_test, out)
        return bool(out[0])

    assert test([0b0011], [0b1111], front, front)  # the cell sees half: mixed
    assert test([0b1111], [0b0011], front, front)  # the spot sees half: mixed
    assert not test([0b1111], [0b1111], front, front)  # both see all
    assert not test([0b0011], [0b1100], front, front)  # no sample seen from both: no light, nothing to split
    assert not test([0b0011], [0b1111], front, back)  # the spot behind the element: no light
    assert test([0b0011], [0b1111], front, back, side_test=False)  # (not Lambertian: no side test)
    # confocal: the cell pairs with its own spot (0) only; spot 1 sees the element partly
    two = np.array([[0.0, 0.0, 1.0], [0.1, 0.0, 1.0]])
    assert not test([0b1111], [0b1111, 0b0001], front, two, cell_spot=(0,))
    assert test([0b1111], [0b1111, 0b0001], front, two, cell_spot=(-1,))


def test_refined_pairs_give_each_pair_to_the_element_or_to_its_children():
    """:func:`~transient_mi.integrators._nlos_refinement.refined_pairs`: a split element keeps the pairs whose test
    cell and spot see its samples wholly (or not at all) and gives the others to its four children, down the levels;
    so each cell covers the surface once. Element 0 split into 1-4, child 1 split again into 5-8; three cells: the
    first sees element 0 wholly, the second partly (child 1 wholly), the third partly (child 1 partly too)."""
    from transient_mi.integrators._nlos_refinement import refined_pairs

    parent = np.array([-1, 0, 0, 0, 0, 1, 1, 1, 1], dtype=np.int64)
    split_idx = np.array([0, 1, -1, -1, -1, -1, -1, -1, -1], dtype=np.int64)
    cm = np.array([[15, 15], [3, 15], [3, 6]], dtype=np.uint8)  # [test cell, split element]
    whole = np.array([[15], [15]], dtype=np.uint8)  # [split element, spot]: one spot sees both wholly
    area = np.array([1.0] + [1 / 4] * 4 + [1 / 16] * 4)

    def kept(sm, cell_of=(0, 1, 2), cell_spot=(-1, -1, -1), e0=0, ne=9, lit=None):
        lit = np.ones(len(cell_of) * ne, dtype=bool) if lit is None else lit.copy()
        refined_pairs(lit, e0, ne, parent, split_idx, cm, np.asarray(sm, dtype=np.uint8),
                      np.array(cell_of, dtype=np.int64), np.array(cell_spot, dtype=np.int64))
        return lit.reshape(len(cell_of), ne).astype(int).tolist()

    got = kept(whole)
    assert got == [[1, 0, 0, 0, 0, 0, 0, 0, 0], [0, 1, 1, 1, 1, 0, 0, 0, 0], [0, 0, 1, 1, 1, 1, 1, 1, 1]]
    assert np.allclose(np.array(got) @ area, 1.0)  # each cell covers element 0's area once
    assert kept(whole, e0=5, ne=4) == [[0] * 4, [0] * 4, [1] * 4]  # a chunk of the elements 5-8
    # a spot that sees element 0 partly gives every cell's pair to the children
    assert kept([[9], [15]])[0] == [0, 1, 1, 1, 1, 0, 0, 0, 0]
    # confocal: each cell with its own spot (spot 1 sees element 0 partly, spot 0 wholly)
    assert kept([[15, 9], [15, 15]], cell_spot=(0, 1, 0))[:2] == [[1, 0, 0, 0, 0, 0, 0, 0, 0],
                                                                 [0, 1, 1, 1, 1, 0, 0, 0, 0]]
    # cells of the level inside one test cell (the test at half the cells per side) follow it
    assert kept(whole, cell_of=(1, 1)) == [[0, 1, 1, 1, 1, 0, 0, 0, 0]] * 2
    # pairs that carry no light stay without
    none = np.zeros(27, dtype=bool)
    assert kept(whole, lit=none) == [[0] * 9] * 3


def test_refinement_test_traces_the_pairs_that_can_carry_light():
    """:func:`~transient_mi.integrators._nlos_refinement.refinement_test_pairs` (the refinement test's rays from
    the cells): a cell is traced with an element when a spot that sees one of its samples lies on the cell's side of the
    element's shading normal, a cell in the element's plane always (the margin); a confocal cell with its own spot
    only. One element at the origin facing +z; cells in front, behind and in its plane."""
    from transient_mi.integrators._nlos_refinement import refinement_test_pairs

    X0 = np.zeros((1, 3))
    n_sh = np.array([[0.0, 0.0, 1.0]])
    cells = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    S = np.array([[0.1, 0.0, 1.0], [0.1, 0.0, -1.0]])  # a spot in front, one behind

    def traced(vs, cell_spot=(-1, -1, -1)):
        return refinement_test_pairs(np.array([vs], dtype=np.uint8), 0, 1, X0, n_sh, cells, S,
                          np.array(cell_spot, dtype=np.int64)).astype(int).tolist()

    assert traced([15, 15]) == [1, 1, 1]  # each cell has a spot on its side
    assert traced([15, 0]) == [1, 0, 1]  # the spot behind sees nothing: the cell behind carries no light
    assert traced([0, 0]) == [0, 0, 0]  # no spot sees the element
    assert traced([15, 15], cell_spot=(1, 1, 0)) == [0, 1, 1]  # confocal: the front cell with the spot behind


def test_shared_pairs_agree_with_children_in_every_pair():
    """A render gives each pair of a split element to the element or to its children as the pair's own visibility
    asks (:class:`~transient_mi.integrators._nlos_refinement.Refinement`); the fit's forward model gives every pair to
    the children (``pair_refinement=False``). On a target half hidden behind a smaller occluder (mixed visibility,
    two refinement levels) both are estimates of the same capture: every pixel's total agrees within the sum of
    their stated total errors (a pair counted twice, or dropped, would move a whole element's light), and so does
    the whole histogram's largest bin difference within the sum of the largest per-bin errors. Deterministic."""
    shared = _render(_occluder_scene(), element_size_m=0.02, patch_cells=2, refine_levels=2)
    children = _render(_occluder_scene(), element_size_m=0.02, patch_cells=2, refine_levels=2, pair_refinement=False)
    assert shared.estimator_info["refine_levels"] == children.estimator_info["refine_levels"] >= 1
    assert shared.estimator_info["elements"] > children.estimator_info["elements"]  # the split ones stay
    _assert_agree_within_errors(shared, children)


def test_refinement_tests_children_with_the_pairs_their_ancestors_give_them(monkeypatch):
    """With shared pairs a child's visibility is tested from the pairs its ancestors give it only
    (``owned_only`` of :func:`~transient_mi.integrators._nlos_refinement.refine_visibility`): the others are
    integrated by an ancestor, so splitting a child for them adds elements that integrate nothing. On the target
    half hidden behind a smaller occluder (three refinement levels) the restricted test traces fewer pairs, splits
    no more elements than the test of every pair, and the two captures agree: every pixel's total within the sum of
    their stated total errors, the largest bin difference within the sum of the largest per-bin errors.
    Deterministic."""
    import transient_mi.integrators._nlos_quadrature as quad
    import transient_mi.integrators._nlos_refinement as refinement

    traced = []
    trace = refinement.visibility_masks

    def counted(scene, cell_p, normal, pts, e0, e1, idx=None):
        traced[-1] += len(cell_p) * (e1 - e0) if idx is None else len(idx)
        return trace(scene, cell_p, normal, pts, e0, e1, idx)

    monkeypatch.setattr(refinement, "visibility_masks", counted)

    opts = dict(element_size_m=0.02, patch_cells=2, refine_levels=3)
    traced.append(0)
    owned = _render(_occluder_scene(), **opts)
    every_pair = quad.refine_visibility

    def test_every_pair(*a, **k):
        return every_pair(*a, **{**k, "owned_only": False})

    monkeypatch.setattr(quad, "refine_visibility", test_every_pair)
    traced.append(0)
    full = _render(_occluder_scene(), **opts)
    assert owned.estimator_info["refine_levels"] >= 2  # (children were tested)
    assert 0 < traced[0] < traced[1]
    assert owned.estimator_info["elements"] <= full.estimator_info["elements"]
    _assert_agree_within_errors(owned, full)


def test_side_blocks_group_whole_chunks_up_to_the_combinations():
    """:func:`~transient_mi.integrators._nlos_pairs.side_blocks` groups consecutive chunks while their elements
    times the spots stay within ``SIDE_COMBINATIONS`` (one chunk at least), in order and covering every chunk once."""
    from transient_mi.integrators import _nlos_pairs as pairs

    starts = [(0, 3), (3, 6), (6, 9), (9, 10)]
    per = pairs.SIDE_COMBINATIONS
    assert pairs.side_blocks(starts, 1) == [(0, 10, starts)]
    assert pairs.side_blocks(starts, per // 6) == [(0, 6, starts[:2]), (6, 10, starts[2:])]
    assert pairs.side_blocks(starts, per // 2) == [(b0, b1, [(b0, b1)]) for b0, b1 in starts]  # (a chunk of 3)
    assert pairs.side_blocks([], 4) == []


@pytest.mark.parametrize("capture", ["array", "confocal"])
def test_level_takes_the_laser_side_a_block_of_elements_at_a_time(capture, monkeypatch):
    """A level builds the laser side (:class:`~transient_mi.integrators._nlos_pairs.SpotSide`: per element and
    spot) for a block of elements at a time, so a confocal capture (every element with every pixel's spot) holds a
    block's, not the level's. With small chunks, blocks of one chunk each give the same capture, the error and the
    pair count, byte for byte, as one block of every element (the occluder scene: mixed visibility, refined).
    Deterministic."""
    from transient_mi.integrators import _nlos_pairs as pairs

    def render():
        return _render(_occluder_scene(4, capture), element_size_m=0.02, patch_cells=2, refine_levels=2)

    monkeypatch.setattr(pairs, "PAIRS_PER_CHUNK", 64 * 16)  # (16 elements a chunk with 64 cells)
    one = render()
    made = []
    side = pairs.SpotSide

    class Counted(side):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            made.append((self.e0, self.e1))

    import transient_mi.integrators._nlos_quadrature as quad

    monkeypatch.setattr(quad, "SpotSide", Counted)
    monkeypatch.setattr(pairs, "SIDE_COMBINATIONS", 1)
    blocks = render()
    assert len(made) > 3 and all(e1 - e0 <= 64 for e0, e1 in made)  # (a block per chunk: 16 or 64 elements)
    for a, b in ((one.histogram, blocks.histogram), (one.error_bound, blocks.error_bound),
                 (one.steady, blocks.steady), (one.total_error_bound, blocks.total_error_bound)):
        assert a.tobytes() == b.tobytes()
    assert one.estimator_info == blocks.estimator_info


@pytest.mark.parametrize("capture", ["array", "confocal"])
def test_general_bsdf_path_equals_the_lambertian_one(capture, monkeypatch):
    """Lambertian BSDFs are evaluated once per (element, spot) and per wall cell, each pair applying the hemisphere
    test (transient_mi/integrators/_nlos_surfaces.py); the general path evaluates every pair's BSDF with its own
    ``wi``. Forced on the same Lambertian scene (a target half hidden behind a smaller occluder, so mixed pairs
    are in), the general path gives the same capture to the float32 rounding of Mitsuba's BSDF values (relative
    1e-5 of each pixel's total and of the largest bin). Deterministic."""
    import transient_mi.integrators._nlos_surfaces as surfaces

    def render():
        return _render(_occluder_scene(3, capture), element_size_m=0.02, patch_cells=2, refine_levels=1)

    fast = render()
    monkeypatch.setattr(surfaces, "is_lambertian", lambda bsdf: False)
    general = render()
    for got, want in ((general.histogram, fast.histogram), (general.error_bound, fast.error_bound)):
        got, want = got.astype(np.float64), want.astype(np.float64)
        assert want.max() > 0
        np.testing.assert_allclose(got.sum(-1), want.sum(-1), rtol=1e-5, atol=1e-5 * want.sum(-1).max())
        assert np.abs(got - want).max() <= 1e-5 * want.max()


# ---------------------------------------------------------------- self-convergence


#: The self-convergence capture: 3 x 3 pixels of 3 cm, one spot.
SELF_CONVERGENCE = dict(LETTER, spots_x="1", width="3", height="3")


@functools.lru_cache(maxsize=2)
def _self_convergence_reference(scene: str = "nlos_letter") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fine level the self-convergence tests measure against (5 mm elements, 6 cells per side): its histogram,
    its stated error per bin and its pixel totals' stated error, float64."""
    from transient_mi.scene_io import load_scene

    fine = _render(load_scene(f"scenes/{scene}.xml", SELF_CONVERGENCE), element_size_m=0.005, patch_cells=6)
    return (fine.histogram.astype(np.float64), fine.error_bound.astype(np.float64),
            fine.total_error_bound.astype(np.float64))


def _assert_estimate_covers(coarse, reference: tuple) -> np.ndarray:
    """The stated error of ``coarse`` covers its actual error: every pixel's summed squares, the summed squares of
    every lit window of 8 bins, every pixel total. The actual error is seen through the reference
    (:func:`_self_convergence_reference`), which has an error of its own, so what is checked is the triangle
    inequality: the difference from the reference, in root-sum-square over the bins compared, is at most the coarse
    level's stated error plus the reference's (the reference states about a sixteenth of the coarse level's; on the
    letter the window at the letter's first light, where the path length is stationary, needs it: its difference
    from the 5 mm reference is 1.003 times the coarse level's stated error in summed squares, and 1.08 times from a
    3.5 mm, 8-cell one). Returns the stated error (float64)."""
    ref, ref_est, ref_tot = reference
    err = np.abs(coarse.histogram.astype(np.float64) - ref)
    est = coarse.error_bound.astype(np.float64)
    rss = lambda x: np.sqrt(x)  # noqa: E731
    assert (rss((err ** 2).sum(-1)) <= rss((est ** 2).sum(-1)) + rss((ref_est ** 2).sum(-1))).all()
    win = lambda x: x.reshape(*x.shape[:-1], -1, 8).sum(-1)  # noqa: E731
    lit = win(ref) > 1e-3 * ref.max()
    assert lit.sum() > 20
    assert (rss(win(err ** 2))[lit] <= (rss(win(est ** 2)) + rss(win(ref_est ** 2)))[lit]).all()
    tot_err = np.abs(coarse.histogram.astype(np.float64).sum(-1) - ref.sum(-1))
    assert (tot_err <= (coarse.total_error_bound.astype(np.float64) + ref_tot) * (1 + 1e-6)).all()
    return est


@pytest.mark.parametrize("scene", ["nlos_letter", "nlos_tilted_plane"])
def test_error_estimate_covers_the_actual_error(scene):
    """Self-convergence: the quadrature at 2 cm elements and 2 cells per patch side against a fine level (5 mm, 6
    cells) on the letter and on the tilted plane (30 degrees: each element spreads over several bins). The stated
    error (mixed visibility plus the local root mean square of I_h - I_2h over +-2 bins, / 3) is an estimate: it
    must cover every pixel total, every pixel's summed squares (what ``detect`` reports is a sum of squares over
    bins), and the summed squares of every lit window of 8 bins, up to the fine level's own stated error
    (:func:`_assert_estimate_covers`); a single bin may fall short. Deterministic (no seeds)."""
    from transient_mi.scene_io import load_scene

    path = f"scenes/{scene}.xml"
    coarse = _render(load_scene(path, SELF_CONVERGENCE), element_size_m=0.02, patch_cells=2)
    est = _assert_estimate_covers(coarse, _self_convergence_reference(scene))
    # the estimate falls with the element size and the cells (second order: 4x per halving, at least 2x asked)
    mid = _render(load_scene(path, SELF_CONVERGENCE), element_size_m=0.01, patch_cells=4)
    assert float((mid.error_bound.astype(np.float64) ** 2).sum()) < 0.25 * float((est ** 2).sum())


def test_element_slope_lowers_the_actual_error():
    """The element's slope (a weight linear in arrival time over each element, ``element_slope``, default true)
    moves light within each pair and leaves every pixel total as the centroid weight has it; where the elements'
    part of the error dominates (the letter at 2 cm elements and 4 cells per patch side) the summed squared
    difference from the fine level falls to about a quarter (measured 0.26 when written; asked: below a half).
    Deterministic (no seeds)."""
    from transient_mi.scene_io import load_scene

    ref = _self_convergence_reference("nlos_letter")[0]
    got = {}
    for slope in (True, False):
        r = _render(load_scene("scenes/nlos_letter.xml", SELF_CONVERGENCE), element_size_m=0.02, patch_cells=4,
                    element_slope=slope)
        got[slope] = r.histogram.astype(np.float64)
    np.testing.assert_allclose(got[True].sum(-1), got[False].sum(-1), rtol=1e-5)
    assert not np.array_equal(got[True], got[False])
    err = {k: float(((v - ref) ** 2).sum()) for k, v in got.items()}
    assert err[True] < 0.5 * err[False], err


def test_error_estimate_keeps_each_pixels_sum_of_squares():
    """The discretisation estimate is the local root mean square of the two-level difference over +-2 bins, divided
    by 3: it fills a zero crossing of the difference (a bin where it vanishes between two of opposite sign gets
    their root mean square) and keeps each pixel's sum of squares (over 3^2), where a maximum filter would add to
    it."""
    from transient_mi.integrators._nlos_error_estimate import ESTIMATE_DIVISOR, discretisation_error

    rng = np.random.default_rng(5)
    fine = rng.normal(size=(2, 3, 40))
    coarse = rng.normal(size=(2, 3, 40))
    est = discretisation_error(fine, coarse)
    np.testing.assert_allclose((est ** 2).sum(-1), ((fine - coarse) ** 2).sum(-1) / ESTIMATE_DIVISOR ** 2,
                               rtol=1e-12)
    d = np.zeros(12)
    d[5], d[7] = 3.0, -4.0  # d[6] = 0: a zero crossing
    e = discretisation_error(d, np.zeros(12))
    assert e[6] == pytest.approx(np.sqrt((9.0 + 16.0) / 5.0) / ESTIMATE_DIVISOR)
    assert e[0] == 0.0 and e[-1] == 0.0 and (e >= 0).all()
    # the kernel (rows in parallel, the difference formed inside) against scipy's filter of the squares, and the
    # same bytes on one thread as on two
    import numba
    from scipy.ndimage import uniform_filter1d

    from transient_mi.integrators._nlos_error_estimate import local_rms

    big = rng.normal(size=(2, 300, 40))
    other = rng.normal(size=(2, 300, 40))
    scipy_form = np.sqrt(np.maximum(uniform_filter1d(np.square(big - other), 5, axis=-1, mode="reflect"), 0.0))
    np.testing.assert_allclose(local_rms(big, other), scipy_form, rtol=1e-12)
    np.testing.assert_allclose(local_rms(big, other, 0.5), 0.5 * scipy_form, rtol=1e-12)
    np.testing.assert_allclose(local_rms(big[..., :3]), np.sqrt(uniform_filter1d(np.square(big[..., :3]), 5, axis=-1,
                                                                                 mode="reflect")), rtol=1e-12)
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        one = local_rms(big, other)
    finally:
        numba.set_num_threads(threads)
    assert one.tobytes() == local_rms(big, other).tobytes()


def test_one_cell_error_estimate_covers_the_actual_error():
    """Self-convergence with one cell per patch side (the coarse level cannot halve it: the cells' part is
    estimated on the coarse elements, one cell against two): 2 cm elements, one 3 cm cell per pixel, against the
    fine level of :func:`test_error_estimate_covers_the_actual_error`, by the same aggregates. The estimate must
    hold the cells' part: without it (the elements' difference alone) it falls short of the actual error
    somewhere. Deterministic (no seeds)."""
    from transient_mi.integrators import _nlos_quadrature as q
    from transient_mi.scene_io import load_scene

    scene = load_scene("scenes/nlos_letter.xml", SELF_CONVERGENCE)
    one = _render(scene, element_size_m=0.02, patch_cells=1)
    assert one.estimator_info["patch_cells"] == 1
    _assert_estimate_covers(one, _self_convergence_reference())
    # the cells' part is needed: the two-level difference alone (no cell estimate) does not cover the error
    with mock.patch.object(q, "cell_estimate_level", lambda g: None):
        alone = _render(scene, element_size_m=0.02, patch_cells=1)
    with pytest.raises(AssertionError):
        _assert_estimate_covers(alone, _self_convergence_reference())



def test_estimate_levels_without_bound_bins_give_the_same_capture():
    """The coarse and cells levels deposit no per-bin light of mixed visibility (only the fine level's is used):
    the capture and its error are the same bytes as with every level keeping it (the paper's mannequin, 2 x 2
    pixels, one cell: its limbs leave pairs of mixed visibility in every level)."""
    from transient_mi.integrators import _nlos_quadrature as q
    from transient_mi.scene_io import load_scene

    scene = load_scene("scenes/paper_mannequin.xml", dict(include_wall_return="false", array="2", spots="1",
                                                          n_bins="1152", bin_width_ps="10"))
    level, mixed = q._level, []

    def keeping(*a, with_bound=True, **k):
        out = level(*a, with_bound=True, **k)
        mixed.append(float(out["vis_err"].sum()))
        return out

    lean = _render(scene, patch_cells=1)
    with mock.patch.object(q, "_level", keeping):
        full = _render(scene, patch_cells=1)
    assert len(mixed) == 3 and min(mixed) > 0  # fine, coarse and cells levels, each with mixed pairs
    for name in ("histogram", "error_bound", "total_error_bound", "steady"):
        assert getattr(lean, name).tobytes() == getattr(full, name).tobytes(), name



def test_error_parts_sum_to_the_error_and_change_nothing_else():
    """Asked for its error's parts (``error_parts``, the noise target's refinement), a render returns the
    visibility, elements and cells parts (one cell per side: all three), which sum to its error up to float32
    rounding, and the capture and error are the same bytes as without them (the paper's mannequin, 2 x 2 pixels:
    its limbs leave pairs of mixed visibility). Deterministic."""
    from transient_mi.scene_io import load_scene

    scene = load_scene("scenes/paper_mannequin.xml", dict(include_wall_return="false", array="2", spots="1",
                                                          n_bins="1152", bin_width_ps="10"))
    plain = _render(scene, patch_cells=1)
    parted = _render(scene, patch_cells=1, error_parts=True)
    assert plain.error_parts is None
    assert sorted(parted.error_parts) == ["cells", "elements", "visibility"]
    assert all(float(a.max()) > 0 for a in parted.error_parts.values())
    total = sum(a.astype(np.float64) for a in parted.error_parts.values())
    np.testing.assert_allclose(total, parted.error_bound, rtol=1e-6, atol=1e-6 * float(parted.error_bound.max()))
    assert all(a.dtype == np.float32 and a.shape == parted.error_bound.shape for a in parted.error_parts.values())
    for name in ("histogram", "error_bound", "total_error_bound", "steady"):
        assert getattr(plain, name).tobytes() == getattr(parted, name).tobytes(), name


def test_below_three_bounces_only_the_wall_return_is_rendered():
    """``max_depth`` 3 has no three-bounce light: the quadrature integrates no level and the capture is the wall's
    closed-form return alone (every spot's photons in its pixel), with no error."""
    from transient_mi.scene_io import load_scene

    scene = load_scene("scenes/nlos_letter.xml", dict(SELF_CONVERGENCE, max_depth="3", include_wall_return="true"))
    res = _render(scene)
    assert res.estimator_info["pairs"] == 0 and res.estimator_info["elements"] == 0
    assert float(res.histogram.sum()) > 0 and np.count_nonzero(res.histogram.sum(-1)) == 1
    assert not res.error_bound.any() and not res.total_error_bound.any()


# ---------------------------------------------------------------- pipeline


def test_render_stores_the_bound_and_detect_states_the_ratio(tmp_path):
    """`transient-mi render -D estimator=quadrature` writes error_bound/ files and says so in the manifest; the
    same render twice gives the same bytes; `detect` reports the rendering-error ratio of the bound."""
    from transient_core import stack
    from transient_mi.render_capture import render
    from spad_detector import detect_stack

    d = dict(LETTER, estimator="quadrature", width="3", height="3")
    a = render("scenes/nlos_letter.xml", tmp_path / "a", defines=d, progress=False)
    b = render("scenes/nlos_letter.xml", tmp_path / "b", defines=d, progress=False)
    m = stack.read_manifest(a)
    assert m["render"]["estimator"] == "quadrature"
    assert m["variance"]["kind"] == "error_bound" and m["variance"]["directory"] == "error_bound"
    for j in range(m["n_files"]):
        name = stack.spot_filename(j)
        assert (a / name).read_bytes() == (b / name).read_bytes()
        assert (a / "error_bound" / name).read_bytes() == (b / "error_bound" / name).read_bytes()
        bnd, tot = stack.read_variance(a, j, m)
        assert bnd.shape == (3, 3, 512) and (bnd >= 0).all() and (tot > 0).any()
    from transient_mi.capture_error import variance_summary

    assert m["variance"]["summary"] == variance_summary(a, m)  # made in memory, the files' read back
    out = detect_stack(a, tmp_path / "counts", exposure_s=1e-3, seed=1)
    rn = json.loads((out / "manifest.json").read_text())["detector"]["resolved"]["render_noise"]
    assert rn["available"] and rn["estimator"] == "quadrature" and "spp" not in rn
    # the ratio is (bound / photon noise)^2: a worst case, far above the actual error (docs/quadrature.md)
    assert np.isfinite(rn["ratio"]) and rn["ratio"] > 0


def test_unsupported_captures_are_refused_in_one_line():
    from transient_mi.scene_io import load_scene

    s = load_scene("scenes/nlos_point_targets.xml", {"estimator": "quadrature"})  # disks: not meshes
    with pytest.raises(PluginParameterError, match="estimator=quadrature cannot render this capture: the hidden"):
        s.integrator().render_transient(s, s.sensors()[0], seed=0, spp=1, spot=0)
    # (max_depth > 4 is rendered: quadrature + Monte Carlo remainder, tests/test_nlos_quadrature_remainder.py)
    with pytest.raises(Exception, match="estimator='simpson'; allowed: monte_carlo, quadrature"):
        load_scene("scenes/nlos_letter.xml", {"estimator": "simpson"})


def test_noise_target_refines_the_quadrature(tmp_path):
    """`render --noise-target` with the quadrature refines element size and cells until the stated error ratio
    (at the asked budget) meets the target, and the manifest records the settings each spot used."""
    from transient_core import stack
    from transient_mi.noise_target import NoiseTargetSpec
    from transient_mi.render_capture import render
    from spad_detector import DetectorParams

    d = dict(LETTER, estimator="quadrature", width="3", height="3", spots_x="1", element_size_m="0.01", patch_cells="2")
    # (at the first round, 1 cm and 2 cells, it states about 0.05: the target asks for a second)
    spec = NoiseTargetSpec(target=0.01, params=DetectorParams(auto_gate=True), exposure_s=1e-2)
    out = render("scenes/nlos_letter.xml", tmp_path / "nt", defines=d, noise_target=spec, progress=False)
    m = stack.read_manifest(out)
    nt = m["render"]["noise_target"]
    (spot,) = nt["spots"]
    assert spot["met"] and nt["met"] and spot["ratio"] <= 0.01
    assert spot["rounds"] >= 2 and spot["element_size_m"] < 0.01 and spot["patch_cells"] > 2  # it refined
    assert m["variance"]["settings_per_spot"] == [{"element_size_m": spot["element_size_m"],
                                                   "patch_cells": spot["patch_cells"],
                                                   "refine_levels": spot["refine_levels"]}]
    assert "spp_per_spot" not in m["variance"]


def test_noise_target_refinement_shrinks_the_elements_that_set_the_error():
    """A refinement step shrinks the elements' size as their error sees it (the area-weighted root mean square of
    their longest edge) by ``f``, also where the meshes' triangles are smaller than twice ``element_size_m``
    (lowering ``h`` by ``f`` alone would split nothing there), and where a few large triangles set it among many
    small ones (the mannequin's case: ``h f`` suffices, where a count ``1 / f^2`` times larger splits far more); it
    refines the cells only where they are larger than the elements."""
    from transient_mi.integrators._nlos_elements import element_scale_m, fine_count, split4, subdivide
    from transient_mi.noise_target_quadrature import _next_quadrature_level

    rng = np.random.default_rng(3)
    # many small triangles (edges ~1 cm, as the mannequin's): h = 4 cm leaves them whole at the coarse level
    base = rng.uniform(-0.2, 0.2, (400, 1, 3))
    small = base + rng.uniform(-0.01, 0.01, (400, 3, 3))
    f = 0.7
    for h in (0.04, 0.005):  # the count without building the elements is the quadrature's own
        assert fine_count(small, h) == len(split4(subdivide(small, np.arange(400), 2 * h)[0]))
    h, m = _next_quadrature_level(small, 0.004, 0.04, 2, f)
    assert element_scale_m(small, h) <= f * element_scale_m(small, 0.04) * (1 + 1e-9)
    assert element_scale_m(small, 0.04 * f) == element_scale_m(small, 0.04)  # h f alone would have changed nothing
    assert element_scale_m(small, h) > 0.004 / 2 and m == 2  # 2 mm cells: smaller, kept
    # one large square (2 triangles): h f suffices, and 7.5 mm cells are larger than its ~5 mm elements
    sq = np.array([[[0, 0, 0.5], [0.2, 0, 0.5], [0.2, 0.2, 0.5]], [[0, 0, 0.5], [0.2, 0.2, 0.5], [0, 0.2, 0.5]]])
    h, m = _next_quadrature_level(sq, 0.03, 0.01, 4, f)
    assert 0.9 * 0.01 * f <= h <= 0.01 * f  # (the divisions are whole: a step of 5 % below h f may be needed)
    assert element_scale_m(sq, h) < 0.03 / 4 and m == 6
    # the square beside 400 small triangles: the square's elements set the size, and h f is about enough, where
    # the count's rule asked for 1 / f^2 as many elements
    both = np.concatenate([sq, small])
    h, m = _next_quadrature_level(both, 0.001, 0.01, 1, f)
    assert 0.9 * 0.01 * f <= h <= 0.01 * f


def test_noise_target_refines_the_part_of_the_error_that_sets_it():
    """The refinement plan (:func:`~transient_mi.noise_target_quadrature.plan_quadrature_level`) refines the part of the error
    that sets the ratio: a visibility refinement level where the mixed-visibility bound dominates (elements and
    cells kept), more cells per side (an even count) where the one-cell estimate dominates, smaller elements where theirs does
    (cells kept with one per side, the one-cell estimate's share shrinking with them); the planned shares meet
    ``PLAN_MARGIN`` x the target."""
    from transient_mi.integrators._nlos_elements import element_scale_m
    from transient_mi.noise_target import PLAN_MARGIN
    from transient_mi.noise_target_quadrature import (ELEMENTS_ORDER, QUADRATURE_ELEMENT_STEP,
                                                      QUADRATURE_MAX_REFINE_LEVELS, _next_quadrature_level,
                                                      plan_quadrature_level)

    sq = np.array([[[0, 0, 0.5], [0.2, 0, 0.5], [0.2, 0.2, 0.5]], [[0, 0, 0.5], [0.2, 0.2, 0.5], [0, 0.2, 0.5]]])
    # visibility 0.2 of a ratio 0.3 (target 0.1): two levels halve its share twice
    assert plan_quadrature_level(sq, 0.03, 0.01, 1, 1, 0.3, {"visibility": 0.2, "elements": 0.01, "cells": 0.001},
                                 0.1) == (0.01, 1, 3)
    # the one-cell estimate dominates: cells only
    assert plan_quadrature_level(sq, 0.03, 0.01, 1, 1, 0.2, {"visibility": 0.001, "elements": 0.001, "cells": 0.2},
                                 0.1) == (0.01, 2, 1)
    # ... by even counts only (the coarse level halves them: an odd count states far more than its error): one cell
    # to two, then four, never three; the elements' step rounds the cells up to an even count too
    assert plan_quadrature_level(sq, 0.03, 0.01, 1, 1, 2.0, {"visibility": 0.001, "elements": 0.001, "cells": 2.0},
                                 0.1) == (0.01, 4, 1)
    assert _next_quadrature_level(sq, 0.06, 0.04, 2, 0.7) == (pytest.approx(0.028), 4)  # (ceil(2 / 0.7) = 3)
    # the elements dominate: they shrink (their size by the planned steps), one cell per side kept
    h, m, rl = plan_quadrature_level(sq, 0.03, 0.01, 1, 1, 0.2, {"visibility": 0.0, "elements": 0.2, "cells": 0.0},
                                     0.1)
    steps = math.ceil(math.log(math.sqrt(PLAN_MARGIN * 0.1 / 0.2)) / math.log(QUADRATURE_ELEMENT_STEP ** ELEMENTS_ORDER))
    assert (m, rl) == (1, 1)
    assert element_scale_m(sq, h) <= QUADRATURE_ELEMENT_STEP ** steps * element_scale_m(sq, 0.01) * (1 + 1e-9)
    assert element_scale_m(sq, h / 0.95) > QUADRATURE_ELEMENT_STEP ** steps * element_scale_m(sq, 0.01)  # no finer
    # the elements dominate and the one-cell estimate is the smallest part (the demo's 4 x 4 array at 1 s per spot,
    # target 0.01): the elements' steps shrink its share as well (it is estimated on the coarse elements,
    # CELLS_ELEMENTS_ORDER), so one cell per side is kept; without that the plan took a second cell per side
    # (four times the pairs) for a part that the elements' steps left at a tenth of the target
    h, m, rl = plan_quadrature_level(sq, 0.03, 0.04, 1, 1, 0.76, {"visibility": 0.189, "elements": 0.361,
                                                                  "cells": 0.011}, 0.01)
    assert (m, rl) == (1, 3) and h < 0.04
    # visibility beyond its cap goes to the elements
    h, m, rl = plan_quadrature_level(sq, 0.03, 0.01, 1, QUADRATURE_MAX_REFINE_LEVELS, 0.2, {"visibility": 0.2},
                                     0.1)
    assert rl == QUADRATURE_MAX_REFINE_LEVELS and h < 0.01 and m == 1


def test_a_series_starts_its_next_capture_coarser_by_what_the_last_ratio_leaves():
    """:func:`~transient_mi.noise_target_quadrature.coarser_start` (the demo's next array): the elements enlarged by
    ``(PLAN_MARGIN target / ratio)^(1 / (2 COARSEN_ORDER))``, so a ratio growing as the size to ``2 COARSEN_ORDER``
    lands on ``PLAN_MARGIN`` x the target; the cells and visibility levels kept; at most ``MAX_COARSEN``; nothing
    changed for a ratio at or above the target's margin, a missing ratio or a capture without the quadrature's
    settings."""
    from transient_mi.noise_target import PLAN_MARGIN
    from transient_mi.noise_target_quadrature import COARSEN_ORDER, MAX_COARSEN, coarser_start

    start = {"element_size_m": 0.018, "patch_cells": 1, "refine_levels": 2}
    out = coarser_start(start, 0.04, 0.1)
    f = out["element_size_m"] / 0.018
    assert f > 1.0 and (out["patch_cells"], out["refine_levels"]) == (1, 2)
    assert 0.04 * f ** (2 * COARSEN_ORDER) == pytest.approx(PLAN_MARGIN * 0.1, rel=1e-12)
    assert coarser_start(start, 1e-9, 0.1)["element_size_m"] == pytest.approx(0.018 * MAX_COARSEN, rel=1e-12)
    for ratio in (PLAN_MARGIN * 0.1, 0.09, 0.2, float("nan"), 0.0):
        assert coarser_start(start, ratio, 0.1) == start
    assert coarser_start({}, 0.01, 0.1) == {}


@pytest.mark.parametrize("cells", [None, 1])
def test_quadrature_reports_progress_per_chunk(cells):
    """A long quadrature render moves the progress bar as its chunks of pairs are done (not 0 then 100 %): the
    callback sees increasing values up to the total, more than once; with one cell per patch side too (three
    levels: the cells' estimate last)."""
    from transient_mi.integrators import _nlos_pairs
    from transient_mi.scene_io import load_scene

    # (2 cm elements: a few hundred chunks, not the default's thousands; what is asserted does not depend on them)
    scene = load_scene("scenes/nlos_letter.xml", dict(LETTER, estimator="quadrature", element_size_m="0.02",
                                                      patch_cells="4"))
    if cells is not None:
        scene.integrator().nlos_options.update(patch_cells=cells)
    seen = []
    old = _nlos_pairs.PAIRS_PER_CHUNK
    _nlos_pairs.PAIRS_PER_CHUNK = 2000  # several chunks on this small capture
    try:
        scene.integrator().render_transient(scene, scene.sensors()[0], seed=0, spp=1, spot=0,
                                            progress=lambda d, t: seen.append((d, t)))
    finally:
        _nlos_pairs.PAIRS_PER_CHUNK = old
    done = [d for d, _ in seen]
    assert len(seen) > 3 and done == sorted(done) and seen[-1][0] == seen[-1][1] > 0


def test_cell_tilt_keeps_the_weight_non_negative():
    """Where the weight varies faster across a wall cell than its linear model can follow (an element 2 cm above
    a 10 cm cell: the wall's cosine and ``1 / r^4`` change by orders of magnitude across it), the model
    ``1 + t1 v1 + t2 v2`` would go negative at a corner and spread negative light: a 32 x 32 paper capture
    (mannequin turned 17.7 deg) had bins at -3e-9 of their pixel's largest, which the writer refused in a
    dataset run. The slopes are scaled to ``|t1| + |t2| <= MAX_TILT_SUM = 2`` (the weight 0 at one corner), and
    the pair's masses are then >= 0; unscaled slopes of that size give negative masses."""
    from transient_mi.integrators._nlos_pair_kernels import MAX_TILT_SUM, cell_terms, pair_geometry
    from transient_mi.integrators._nlos_time_spread import _masses

    D = np.array([-0.9, 0.05, 1.2])
    cell_p = np.array([[0.0, 0.0, 0.0]])
    ax, ay, wall_n = np.array([0.1, 0.0, 0.0]), np.array([0.0, 0.1, 0.0]), np.array([0.0, 0.0, 1.0])
    ap_n = -D / np.linalg.norm(D)
    # 2 cm above the cell, over its edge at +x, facing the wall
    tri = np.array([[[0.05, 0.0, 0.02], [0.04, 0.01, 0.02], [0.03, -0.01, 0.02]]])
    X0 = tri.mean(axis=1)
    nrm = np.array([[0.0, 0.0, -1.0]])
    bin_m = 0.3e-3  # 1 ps
    geo, cos_p, A, w1, w2, tilt, side_x, lit, _amp = pair_geometry(
        cell_p, np.array([1.0]), *cell_terms(cell_p, D, ax, ay, 1.0, ap_n, wall_n), X0, tri, nrm, np.array([5e-5]),
        nrm, np.array([[0.0, 0.0, 1.0]]), np.array([1], dtype=np.int8), 0, 1, ax, ay, 1.0, bin_m, 1.0, True, wall_n,
        1, np.full((1, 1), 15, dtype=np.uint8), np.ones((1, 1), dtype=np.int8), True, True, False)
    assert lit[0]  # (a spot on the cell's side sees the element)
    assert abs(tilt[0, 0]) + abs(tilt[0, 1]) == pytest.approx(MAX_TILT_SUM)  # it was scaled
    t = np.sort(A[0])
    buf = np.zeros(4096)
    first, last, _ = _masses(buf, 100.0, t[1] - t[0], t[2] - t[0], w1[0], w2[0], tilt[0, 0], tilt[0, 1], 4096)
    assert first <= last and buf[first:last + 1].min() >= -1e-15
    _masses(buf, 100.0, t[1] - t[0], t[2] - t[0], w1[0], w2[0], 3.0 * tilt[0, 0], 3.0 * tilt[0, 1], 4096)
    assert buf[first:last + 1].min() < -1e-6  # unscaled slopes of three times that: negative light


def test_render_command_reports_a_quadrature_noise_target(tmp_path):
    """`transient-mi render --noise-target` on a scene the quadrature renders ends with one line stating the worst
    spot's error ratio and the target (its spots record settings, not spp: the line used to read their spp and
    stopped with a traceback after writing the capture, as the README's paper-scene example did)."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    from transient_core import stack

    root = Path(__file__).resolve().parents[1]
    d = ["-D", "width=3", "-D", "height=3", "-D", "spots_x=1", "-D", "spots_y=1", "-D", "n_bins=64",
         "-D", "bin_width_ps=64"]
    r = subprocess.run([sys.executable, "-m", "transient_mi", "render", "scenes/nlos_letter.xml", "-o",
                        str(tmp_path / "nt"), *d, "--noise-target", "0.1", "--exposure-s", "0.01"],
                       capture_output=True, text=True, cwd=root, timeout=600,
                       env={**os.environ, "TRANSIENT_MI_PROGRESS": "0"})
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    nt = stack.read_manifest(tmp_path / "nt")["render"]["noise_target"]
    worst = max(s["ratio"] for s in nt["spots"])
    assert f"quadrature: stated error ratio up to {worst:.3g} for noise target 0.1: met" in r.stdout, r.stdout


def _random_chunk(rng, C: int, ne: int, G: int):
    """Arguments of ``pair_geometry`` for ``C`` cells on the wall (z = 0, normal +z) and ``ne`` small triangles in
    front of it with random orientations (some face away from the wall), ``G`` spots' masks and sides at random."""
    from transient_mi.integrators._nlos_pair_kernels import cell_terms

    D = np.array([-0.9, 0.05, 1.2])
    ax, ay, wall_n = np.array([0.03, 0.0, 0.0]), np.array([0.0, 0.03, 0.0]), np.array([0.0, 0.0, 1.0])
    cell_p = np.column_stack([rng.uniform(-0.4, 0.4, (C, 2)), np.zeros(C)])
    X0 = np.column_stack([rng.uniform(-0.3, 0.3, (ne, 2)), rng.uniform(0.3, 0.6, ne)])
    nrm = rng.normal(size=(ne, 3))
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    tri = X0[:, None, :] + rng.uniform(-0.01, 0.01, (ne, 3, 3))
    vis_s = rng.integers(0, 16, (ne, G)).astype(np.uint8)
    vis_s[rng.random((ne, G)) < 0.3] = 0
    side_s = rng.choice(np.array([-1, 0, 1], dtype=np.int8), (ne, G))
    wall_side = rng.choice(np.array([-1, 1], dtype=np.int8), C)
    wall_n_sh = np.tile(wall_n, (C, 1))
    head = (cell_p, np.full(C, 1e-3), *cell_terms(cell_p, D, ax, ay, 1.0, -D / np.linalg.norm(D), wall_n), X0, tri,
            nrm, rng.uniform(1e-5, 1e-4, ne), nrm, wall_n_sh, wall_side)
    return head, (ax, ay, 1.0, 0.3e-3, 1.0, True, wall_n), vis_s, side_s


@pytest.mark.parametrize("confocal,lambertian,wall_lambertian", [(False, True, True), (True, True, True),
                                                                  (False, False, True), (False, True, False)])
def test_pair_geometry_lit_is_the_stated_rule_and_reused_buffers_change_nothing(confocal, lambertian,
                                                                                 wall_lambertian):
    """``pair_geometry``'s ``lit`` is the rule it states, checked pair by pair in Python: ``geo > 0``, the element
    in front of a Lambertian wall (``cos_p > 0``), and a spot (a confocal pixel's own) that sees a sample of the
    element on the cell's side of a Lambertian element. An unlit pair's knots, widths and slopes are 0. Written
    into one set of buffers chunk after chunk (as a level does), each chunk's results are the same bytes as fresh
    ones. Deterministic (a fixed seed)."""
    from transient_mi.integrators._nlos_pair_kernels import pair_geometry, pair_results

    rng = np.random.default_rng(5)
    C, ne, G = 6, 40, 6 if confocal else 3
    head, tail, vis_s, side_s = _random_chunk(rng, C, ne, G)
    buffers = pair_results(C * ne)
    for e0, e1 in ((0, 40), (5, 17), (0, 40)):  # (a smaller chunk between two whole ones: stale rows must not leak)
        n_e = e1 - e0  # (one cell per pixel: a pixel's pairs are its cell's)
        args = head + (e0, e1) + tail + (n_e, vis_s, side_s, wall_lambertian, lambertian, confocal)
        fresh = pair_geometry(*args)
        reused = pair_geometry(*args, out=buffers)
        for a, b in zip(fresh, reused):
            assert a.tobytes() == b.tobytes()
        geo, cos_p, A, w1, w2, tilt, side_x, lit, amp = fresh
        for i in range(C * n_e):
            e, k = e0 + i % n_e, i // n_e
            spots = [k] if confocal else range(G)
            want = (geo[i] != 0.0 and not (wall_lambertian and cos_p[i] == 0.0)
                    and any(vis_s[e, s] != 0 and (not lambertian or side_x[i] * side_s[e, s] > 0) for s in spots))
            assert bool(lit[i]) == want, i
            if not want:
                assert not A[i].any() and w1[i] == 0.0 and w2[i] == 0.0 and not tilt[i].any() and (amp[i] == 1.0).all()
        assert 0 < int(lit.sum()) < C * n_e  # (both kinds of pairs were met)
        # the pairs a refined level gives to other elements: no light and no geometry; the owned ones unchanged
        owned = rng.random(C * n_e) < 0.5
        part = pair_geometry(*args, owned=owned)
        for a, b in zip(fresh, part):
            assert a[owned].tobytes() == b[owned].tobytes()
        g2, c2, A2, w12, w22, t2, s2, lit2, amp2 = part
        off = ~owned
        assert not lit2[off].any() and not g2[off].any() and not c2[off].any() and not s2[off].any()
        assert not A2[off].any() and not w12[off].any() and not w22[off].any() and not t2[off].any()
        assert (amp2[off] == 1.0).all()
