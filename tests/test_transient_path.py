"""transient_path + transient_film against closed forms and Mitsuba's own ``path``.

Tolerances are statistical: standard errors are estimated from independent
seeds, never hand-tuned.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import transient_mi  # noqa: F401  (first: LLVM + plug-ins)
import mitsuba as mi

from transient_core.units import C_M_PER_PS
from stats_helpers import ALPHA, t_bound, welch_df
from transient_mi.time_axis import TimeAxis, gaussian_kernel_taps


def _render(scene, seed=0, spp=0):
    return scene.integrator().render_transient(scene, scene.sensors()[0], seed=seed, spp=spp)


def _film(w, h, n_bins, bw, t0, sigma=0.0):
    return {"type": "transient_film", "width": w, "height": h, "n_bins": n_bins, "bin_width_ps": bw,
            "t0_ps": t0, "kernel_sigma_ps": sigma}


# ----------------------------------------------------------------- point light


CAM = [0.25, 0.15, 2.0]
LIGHT = [-0.5, 0.6, 1.0]


def _plane_scene(film, spp=16):
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "transient_path", "max_depth": 2},
        "sensor": {
            "type": "perspective", "fov": 10.0,
            "to_world": mi.ScalarTransform4f().look_at(origin=CAM, target=[0, 0, 0], up=[0, 1, 0]),
            "film": film, "sampler": {"type": "independent", "sample_count": spp},
        },
        "light": {"type": "point", "position": LIGHT, "intensity": {"type": "spectrum", "value": 5.0}},
        "plane": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale(3.0),
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "spectrum", "value": 0.8}}},
    })


def _pixel_centre_points(scene, W, H):
    """World points seen through each pixel centre (via Mitsuba's own camera model)."""
    sensor = scene.sensors()[0]
    j, i = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    pos = mi.Point2f((i.ravel() + 0.5) / W, (j.ravel() + 0.5) / H)
    ray, _ = sensor.sample_ray(mi.Float(0), mi.Float(0), pos, mi.Point2f(0.5))
    si = scene.ray_intersect(ray)
    return np.stack([np.asarray(si.p.x), np.asarray(si.p.y), np.asarray(si.p.z)], -1).reshape(H, W, 3)


@pytest.mark.parametrize("bin_width_ps,t0_ps", [(25.0, 8000.0), (50.0, 9000.0), (100.0, 5000.0)])
def test_point_light_plane_peaks_at_two_segment_path_length(bin_width_ps, t0_ps):
    W = H = 24
    n_bins = int((16000 - t0_ps) / bin_width_ps)
    scene = _plane_scene(_film(W, H, n_bins, bin_width_ps, t0_ps))
    res = _render(scene, seed=3)
    x = _pixel_centre_points(scene, W, H)
    opl = np.linalg.norm(x - np.array(LIGHT), axis=-1) + np.linalg.norm(x - np.array(CAM), axis=-1)
    expected = TimeAxis(t0_ps, bin_width_ps, n_bins).bin_index(opl)
    assert np.all((expected > 0) & (expected < n_bins - 1))
    peak = np.argmax(res.histogram, axis=-1)
    assert np.all(res.histogram.sum(-1) > 0)
    assert np.max(np.abs(peak - expected)) <= 1
    assert res.dropped_contributions == 0


def test_contributions_outside_the_time_range_are_dropped_and_counted():
    # A window that ends in the middle of the arrivals: the histogram holds exactly the contributions
    # that arrive inside it, the rest are counted as dropped and still in the steady-state image.
    W = H = 16
    bw, t0 = 32.0, 8192.0
    full = _render(_plane_scene(_film(W, H, 200, bw, t0)), seed=5)
    arrivals = np.nonzero(full.histogram.sum(axis=(0, 1)))[0]
    assert full.dropped_contributions == 0 and full.dropped_fraction == 0.0
    cut = int((arrivals[0] + arrivals[-1]) // 2)
    part = _render(_plane_scene(_film(W, H, cut, bw, t0)), seed=5)
    np.testing.assert_array_equal(part.histogram, full.histogram[..., :cut])
    # the steady image is the same light; only float32 summation order may differ (a few ulp)
    np.testing.assert_allclose(part.steady, full.steady, rtol=4 * np.finfo(np.float32).eps)
    lost = float(full.histogram[..., cut:].sum(dtype=np.float64))
    assert part.dropped_contributions > 0
    assert part.dropped_fraction == pytest.approx(lost / float(full.steady.sum(dtype=np.float64)), rel=1e-4)


def test_shifting_t0_shifts_histogram_exactly():
    # Power-of-two bin width and t0 >= t/2 make (t - t0)/w exact in float64,
    # so a shift of k bins in t0 moves every contribution by exactly k bins.
    W = H = 16
    k = 7
    a = _render(_plane_scene(_film(W, H, 200, 32.0, 8192.0)), seed=5)
    b = _render(_plane_scene(_film(W, H, 200, 32.0, 8192.0 + k * 32.0)), seed=5)
    assert a.histogram.sum() > 0
    np.testing.assert_array_equal(a.histogram[..., k:], b.histogram[..., :-k])


def test_gaussian_kernel_conserves_energy_and_has_the_right_width():
    W = H = 16
    plain = _render(_plane_scene(_film(W, H, 300, 25.0, 8000.0)), seed=2)
    blurred = _render(_plane_scene(_film(W, H, 300, 25.0, 8000.0, sigma=60.0)), seed=2)
    # Same paths, same energy: totals agree to float32 summation accuracy.
    np.testing.assert_allclose(blurred.histogram.sum(-1), plain.histogram.sum(-1), rtol=2e-5)
    t = TimeAxis(8000.0, 25.0, 300).centers_ps()

    def var(h):
        w = h / h.sum(-1, keepdims=True, dtype=np.float64)
        m = (w * t).sum(-1, keepdims=True)
        return (w * (t - m) ** 2).sum(-1)

    # Convolution adds the kernel's variance to every pixel's arrival-time variance.
    taps = gaussian_kernel_taps(60.0, 25.0)
    m = (np.arange(len(taps)) - len(taps) // 2) * 25.0
    np.testing.assert_allclose(var(blurred.histogram) - var(plain.histogram), (taps * m * m).sum(), rtol=1e-3)


def test_kernel_taps_sum_to_one_with_gaussian_plus_bin_variance():
    for sigma, bw in [(25.0, 1.0), (10.0, 4.0), (12.0, 10.0)]:
        w = gaussian_kernel_taps(sigma, bw)
        m = np.arange(len(w)) - len(w) // 2
        assert abs(w.sum() - 1.0) < 1e-12
        assert abs((w * m).sum()) < 1e-12
        s = sigma / bw  # bin-integrated Gaussian: variance s^2 + 1/12 (Sheppard), for s >~ 1
        np.testing.assert_allclose((w * m * m).sum(), s * s + 1 / 12, rtol=1e-3)


# ------------------------------------------------------------------ binning rule


def test_arrival_exactly_on_a_bin_boundary_goes_to_the_later_bin():
    from transient_mi.integrators._lanes import LaneHistogram, LaneLayout

    opl32 = np.array([1.0, 2.5, 3.14159, 4.0], dtype=np.float32)
    t = opl32.astype(np.float64) / C_M_PER_PS  # >= 3335 ps
    for ti, o in zip(t, opl32):
        # t0 = t - 1.5 is exact (Sterbenz), 1.5 / 0.5 = 3 exactly: t sits on the 2|3 boundary.
        axis = TimeAxis(float(ti - 1.5), 0.5, 10)
        assert axis.bin_index(o) == 3
        assert axis.bin_index(np.nextafter(o, np.float32(0))) == 2
        h = LaneHistogram(LaneLayout(1, 1, 1), axis, pad=0)
        _, in_range, b, _ = h.bin_index(mi.Float(float(o)))
        assert int(b[0]) == 3 and bool(in_range[0])


def test_lane_binning_matches_reference_rule():
    from transient_mi.integrators._lanes import LaneHistogram, LaneLayout

    rng = np.random.default_rng(0)
    opl = rng.uniform(0.5, 6.0, 20000).astype(np.float32)
    axis = TimeAxis(2000.0, 7.3, 2000)
    h = LaneHistogram(LaneLayout(1, 1, 1), axis, pad=0)
    _, in_range, b, _ = h.bin_index(mi.Float(opl))
    ref = axis.bin_index(opl)
    ok = (ref >= 0) & (ref < axis.n_bins)
    np.testing.assert_array_equal(np.asarray(in_range), ok)
    np.testing.assert_array_equal(np.asarray(b)[ok], ref[ok])


# --------------------------------------------------------- against Mitsuba's path


def _cbox(film, integrator):
    d = mi.cornell_box()
    d["sensor"]["film"] = film
    d["integrator"] = integrator
    return mi.load_dict(d)


def test_time_integrated_cornell_box_equals_mitsuba_path():
    W = H = 32
    depth, spp, seeds = 6, 32, 12
    # Paths up to 6 segments in a 2 m box seen from 3.9 m stay far below 150 ns.
    tr = _cbox(dict(_film(W, H, 1500, 100.0, 0.0), rfilter={"type": "box"}),  # the same filter as the hdrfilm
              {"type": "transient_path", "max_depth": depth})
    pt = _cbox({"type": "hdrfilm", "width": W, "height": H, "rfilter": {"type": "box"},
                "pixel_format": "luminance"}, {"type": "path", "max_depth": depth})
    regions = {
        "all": (slice(None), slice(None)), "top-left": (slice(0, 16), slice(0, 16)),
        "top-right": (slice(0, 16), slice(16, 32)), "bottom-left": (slice(16, 32), slice(0, 16)),
        "bottom-right": (slice(16, 32), slice(16, 32)),
    }
    a = {r: [] for r in regions}
    b = {r: [] for r in regions}
    for s in range(seeds):
        res = _render(tr, seed=100 + s, spp=spp)
        assert res.dropped_contributions == 0
        img_t = res.histogram.sum(-1, dtype=np.float64)
        img_p = np.asarray(mi.render(pt, spp=spp, seed=200 + s))[..., 0]
        for r, sl in regions.items():
            a[r].append(img_t[sl].mean())
            b[r].append(img_p[sl].mean())
    # Two independent estimators, 12 seeds each: (ma - mb) / se is Welch-t (Welch-Satterthwaite df). False-failure
    # rate 1e-3 for the family of 5 regions (Bonferroni; the regions overlap, which only makes it conservative).
    for r in regions:
        ma, mb = np.mean(a[r]), np.mean(b[r])
        va, vb = np.var(a[r], ddof=1), np.var(b[r], ddof=1)
        se = math.sqrt(va / seeds + vb / seeds)
        bound = t_bound(seeds, ALPHA, len(regions), df=welch_df(va, seeds, vb, seeds))
        assert abs(ma - mb) < bound * se, f"{r}: transient {ma:.5f} vs path {mb:.5f}, bound {bound * se:.5f}"


# --------------------------------------------------------------- inverse square


def _patch_scene(light_pos, radius, radiance, fov_deg, cam_z, W, spp):
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "transient_path", "max_depth": 2},
        "sensor": {
            "type": "perspective", "fov": fov_deg,
            "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, cam_z], target=[0, 0, 0], up=[0, 1, 0]),
            "film": _film(W, W, 400, 20.0, 0.0),
            "sampler": {"type": "independent", "sample_count": spp},
        },
        "patch": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale(0.05),
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "spectrum", "value": 0.5}}},
        "bulb": {"type": "sphere", "center": list(light_pos), "radius": radius,
                 "emitter": {"type": "area", "radiance": {"type": "spectrum", "value": radiance}}},
    })


def test_inverse_square_falloff_with_cosines():
    """Radiance of a Lambertian patch lit by a small spherical lamp at two distances.

    A uniformly emitting sphere (radius r, radiance L) fully above the horizon
    of a point x gives irradiance E = pi L r^2 cos(theta) / d^2 exactly, so the
    patch radiance is rho/pi E. The camera views a square of the (larger)
    patch head-on; pixel samples are uniform over that square, so the expected
    image mean is the average of rho L r^2 cos(theta(x)) / d(x)^2 over it
    (Gauss-Legendre quadrature).

    The lamp radius keeps 1 - cos(alpha) of the lamp's cone >= 1e-3: Mitsuba
    samples sphere lamps in float32, and for much smaller cones (r/d < 0.01)
    its own ``path`` integrator is biased by ~0.05 % from cancellation.
    """
    r, L, rho, cam_z, fov, W = 0.03, 5.0, 0.5, 0.5, 2.0, 8
    half = cam_z * math.tan(math.radians(fov / 2))
    g, gw = np.polynomial.legendre.leggauss(48)
    xs, ws = g * half, gw * half
    X, Y = np.meshgrid(xs, xs, indexing="ij")
    Wq = np.outer(ws, ws) / (2 * half) ** 2
    configs = [(0.3, 30.0), (0.6, 60.0)]
    means, ses, exact = [], [], []
    for d, ang in configs:
        c = np.array([d * math.sin(math.radians(ang)), 0.0, d * math.cos(math.radians(ang))])
        scene = _patch_scene(c, r, L, fov, cam_z, W, spp=32)
        vals = [_render(scene, seed=s).histogram.sum(-1, dtype=np.float64).mean() for s in range(10)]
        means.append(np.mean(vals))
        ses.append(np.std(vals, ddof=1) / math.sqrt(len(vals)))
        dx, dy, dz = c[0] - X, c[1] - Y, c[2]
        dist2 = dx * dx + dy * dy + dz * dz
        exact.append(float((rho * L * r * r * (dz / np.sqrt(dist2)) / dist2 * Wq).sum()))
    # 10 seeds per configuration: (mean - exact) / se is Student-t with 9 degrees of freedom. False-failure rate
    # 1e-3 for the family of 3 checks (2 radiances, 1 ratio; Bonferroni). The ratio's standard error is the delta
    # method's, with 9 degrees of freedom taken for it too (its two relative errors have 9 each).
    bound = t_bound(10, ALPHA, 3)
    for m, se, e in zip(means, ses, exact):
        assert abs(m - e) < bound * se, f"radiance {m:.6g} vs closed form {e:.6g} (bound {bound * se:.3g})"
    ratio = means[0] / means[1]
    ratio_se = ratio * math.sqrt((ses[0] / means[0]) ** 2 + (ses[1] / means[1]) ** 2)
    want = exact[0] / exact[1]
    assert abs(ratio - want) < bound * ratio_se
    # and the analytic ratio itself is the inverse-square law with cosines (to quadrature accuracy)
    d1, a1 = configs[0]
    d2, a2 = configs[1]
    point_ratio = (math.cos(math.radians(a1)) / d1 ** 2) / (math.cos(math.radians(a2)) / d2 ** 2)
    assert abs(want / point_ratio - 1) < 0.01


# ------------------------------------------------------------------ determinism


def test_same_seed_same_bytes_different_seed_different_bytes():
    scene = _cbox(_film(16, 16, 300, 100.0, 10000.0), {"type": "transient_path", "max_depth": 5})
    a = _render(scene, seed=11, spp=8).histogram
    b = _render(scene, seed=11, spp=8).histogram
    c = _render(scene, seed=12, spp=8).histogram
    assert a.tobytes() == b.tobytes()
    assert a.tobytes() != c.tobytes()


def test_non_power_of_two_spp_is_deterministic_and_complete():
    scene = _plane_scene(_film(8, 8, 300, 25.0, 8000.0))
    res = _render(scene, seed=1, spp=13)
    assert res.samples == 8 * 8 * 13
    again = _render(scene, seed=1, spp=13)
    assert res.histogram.tobytes() == again.histogram.tobytes()


def test_transient_film_rejects_bad_parameters():
    for key, val, text in [("n_bins", 0, "n_bins=0"), ("bin_width_ps", 0.0, "bin_width_ps=0"),
                           ("bin_width_ps", -1.0, "bin_width_ps=-1"), ("kernel_sigma_ps", -2.0, "kernel_sigma_ps=-2")]:
        film = _film(4, 4, 10, 1.0, 0.0)
        film[key] = val
        with pytest.raises(Exception, match=text):
            mi.load_dict(film)


def test_mitsuba_integrators_refuse_a_transient_film():
    scene = _cbox(_film(8, 8, 10, 10.0, 0.0), {"type": "path"})
    with pytest.raises(RuntimeError) as info:
        mi.render(scene, spp=1)
    # drjit's custom-op wrapper chains the film's own error
    assert "must be rendered with the transient_path integrator" in str(info.value.__cause__)
