"""Every ideal capture says how noisy it is: the replicate variance estimate.

The estimate is the sample variance of ``R`` independent replicate means
divided by ``R`` (transient_mi/integrators/_replicates.py). These tests check
that it is unbiased against the empirical variance across independent seeds,
for the NLOS estimator (randomised QMC, whose replicates have independent
random shifts) and for the camera path tracer (plain Monte Carlo).

Statistics: with ``S`` seeds, per coarse bin ``b``, ``s2_b`` is the sample
variance of the ``S`` stored means (``S - 1`` dof) and ``v_b`` the mean over
the seeds of the estimated variances (``S (R - 1)`` dof). For Gaussian
replicates the two are independent (sample mean and sample variance of a
Gaussian sample are independent) and ``F_b = s2_b / v_b`` follows
``F(S - 1, S (R - 1))``; ``u_b = F_cdf(F_b)`` is then uniform on (0, 1). An
estimator biased by a factor ``c`` shifts every ``u_b`` the same way, which
the mean of the ``B`` values ``u_b`` detects: ``z = (mean(u) - 1/2) sqrt(12 B)``
is standard normal. The test fails if ``|z| > 3.29``: a false-failure rate of
1e-3 (two-sided) under the Gaussian approximation of each replicate mean
(each replicate averages >= 32 samples). Bins are treated as
independent (different pixels are; bins of one pixel are weakly correlated).
"""

from __future__ import annotations

import numpy as np
from scipy import stats

import transient_mi  # noqa: F401
from nlos_helpers import nlos_scene, square

#: Two-sided normal quantile for a false-failure rate of 1e-3.
Z_1E3 = stats.norm.isf(0.5e-3)


def _uniform_mean_z(means, variances, R):
    """``z`` of the uniform-mean test above; ``means``/``variances``: ``[S, B]`` per seed and bin."""
    S = means.shape[0]
    s2 = means.var(axis=0, ddof=1)
    v = variances.mean(axis=0)
    ok = v > 0
    f = s2[ok] / v[ok]
    u = stats.f.cdf(f, S - 1, S * (R - 1))
    B = int(ok.sum())
    return float((u.mean() - 0.5) * np.sqrt(12.0 * B)), B, float(s2[ok].sum() / v[ok].sum())


def test_nlos_variance_estimate_matches_spread_across_seeds():
    """RQMC NLOS estimator: the stored per-bin variance equals the variance across seeds (coarse bins)."""
    hidden = [square((0.05, 0.0, 0.4), 0.2, 0.7)]
    sc = nlos_scene(width=4, height=4, footprint=0.05, hidden=hidden, include_wall_return=False,
                    n_bins=8, bin_width_ps=100.0, t0_ps=12400.0)
    integ, sensor = sc.integrator(), sc.sensors()[0]
    integ.variance_replicates = 8  # direct renders default to one replicate
    S, spp = 16, 512
    h, v = [], []
    for s in range(S):
        res = integ.render_transient(sc, sensor, seed=1000 + s, spp=spp, spot=0)
        assert res.replicates == 8
        # per film bin (summing bins would need their covariances: a sample adds to one bin per spot, so
        # bins of a pixel are negatively correlated; the per-pixel total has its own exact estimate)
        h.append(res.histogram.astype(np.float64).ravel())
        v.append(res.variance.astype(np.float64).ravel())
    z, B, ratio = _uniform_mean_z(np.array(h), np.array(v), 8)
    assert B >= 60
    assert abs(z) < Z_1E3, f"variance estimate vs spread across seeds: z = {z:.2f} (empirical/estimated = {ratio:.3f})"


def test_pixel_total_variance_matches_spread_across_seeds():
    """The per-pixel total variance (covariances included) equals the spread of the totals across seeds."""
    hidden = [square((0.0, 0.05, 0.35), 0.15, 0.7), square((-0.1, -0.1, 0.5), 0.1, 0.5, id_="t2")]
    sc = nlos_scene(width=6, height=6, footprint=0.04, hidden=hidden, include_wall_return=False,
                    n_bins=64, bin_width_ps=40.0, t0_ps=12000.0)
    integ, sensor = sc.integrator(), sc.sensors()[0]
    integ.variance_replicates = 8  # direct renders default to one replicate
    S = 16
    t, v = [], []
    for s in range(S):
        res = integ.render_transient(sc, sensor, seed=2000 + s, spp=256, spot=0)
        t.append(res.histogram.sum(axis=-1, dtype=np.float64).ravel())
        v.append(res.total_variance.ravel())
    z, B, ratio = _uniform_mean_z(np.array(t), np.array(v), 8)
    assert B == 36
    assert abs(z) < Z_1E3, f"total variance vs spread across seeds: z = {z:.2f} (ratio {ratio:.3f})"


def test_camera_variance_estimate_matches_spread_across_seeds():
    """Camera path tracing (plain Monte Carlo): the same check on a lit plane seen by a camera."""
    import mitsuba as mi

    sc = mi.load_dict({
        # cameras record no variance unless asked (variance_replicates defaults to 1 under a camera)
        "type": "scene", "integrator": {"type": "transient_path", "max_depth": 3, "variance_replicates": 8},
        "light": {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0, 0, 1.5]).rotate(
            [1, 0, 0], 180).scale(0.3), "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 5.0}}},
        "floor": {"type": "rectangle", "bsdf": {"type": "diffuse"}},
        "wall": {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0, 1, 1]).rotate([1, 0, 0], 90),
                 "bsdf": {"type": "diffuse"}},
        "cam": {"type": "perspective", "fov": 50,
                "to_world": mi.ScalarTransform4f().look_at([0, -2.5, 1.2], [0, 0, 0.5], [0, 0, 1]),
                "film": {"type": "transient_film", "width": 6, "height": 6, "n_bins": 8, "bin_width_ps": 4000.0},
                "sampler": {"type": "independent", "sample_count": 256}},
    }, optimize=False)
    integ, sensor = sc.integrator(), sc.sensors()[0]
    S = 16
    h, v = [], []
    for s in range(S):
        res = integ.render_transient(sc, sensor, seed=3000 + s, spp=256)
        h.append(res.histogram.astype(np.float64).ravel())
        v.append(res.variance.astype(np.float64).ravel())
    z, B, ratio = _uniform_mean_z(np.array(h), np.array(v), 8)
    assert B >= 60
    assert abs(z) < Z_1E3, f"camera variance vs spread across seeds: z = {z:.2f} (ratio {ratio:.3f})"


def test_direct_camera_render_records_no_variance_by_default():
    import mitsuba as mi

    sc = mi.load_file(str(__import__("pathlib").Path(__file__).resolve().parents[1] / "scenes" / "cornell_box.xml"),
                      spp="8", n_bins="20")
    res = sc.integrator().render_transient(sc, sc.sensors()[0], seed=0, spp=8)
    assert res.replicates == 1 and res.variance is None


def test_replicates_follow_gcd_and_one_replicate_records_no_variance():
    hidden = [square((0.0, 0.0, 0.4), 0.1, 0.7)]
    sc = nlos_scene(width=2, height=2, hidden=hidden, n_bins=32, bin_width_ps=100.0, t0_ps=8000.0)
    integ, sensor = sc.integrator(), sc.sensors()[0]
    assert integ.render_transient(sc, sensor, seed=1, spp=16, spot=0).replicates == 1  # direct renders: one
    integ.variance_replicates = 8
    assert integ.render_transient(sc, sensor, seed=1, spp=12, spot=0).replicates == 4  # gcd(12, 8)
    res = integ.render_transient(sc, sensor, seed=1, spp=13, spot=0)
    assert res.replicates == 1 and res.variance is None and res.total_variance is None
    a = integ.render_transient(sc, sensor, seed=5, spp=64, spot=0)
    b = integ.render_transient(sc, sensor, seed=5, spp=64, spot=0)
    assert a.histogram.tobytes() == b.histogram.tobytes() and a.variance.tobytes() == b.variance.tobytes()
