"""Colour and polarization per time bin: ``rgb`` and ``spectral`` variants record R, G, B per bin,
``*_polarized`` variants the Stokes vector S0..S3 (in the sensor's frame, as Mitsuba's ``stokes``
integrator).

Statistical comparisons with Mitsuba's steady-state integrators use independent seeds and a Welch t-test
with a false-failure rate of 1e-3 for each test's family of comparisons (Bonferroni). The polarization
closed forms (Brewster's angle, Malus's law) are deterministic given the sampled path (delta BSDFs) and
are checked to float precision; they have no statistical false-failure rate.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import transient_mi
import mitsuba as mi

from stats_helpers import ALPHA, t_bound, welch_df

T = mi.ScalarTransform4f


@pytest.fixture
def variant():
    """Switch to a variant for one test, and back to the session's afterwards."""
    before = transient_mi.variant()
    yield transient_mi.set_variant
    transient_mi.set_variant(before)


def _render(scene, seed, spp):
    return scene.integrator().render_transient(scene, scene.sensors()[0], seed=seed, spp=spp)


def _cbox(film, integrator):
    d = mi.cornell_box()
    d["sensor"]["film"] = film
    d["integrator"] = integrator
    return mi.load_dict(d)


def _film(W, H, **kw):
    return dict({"type": "transient_film", "width": W, "height": H, "n_bins": 1500, "bin_width_ps": 100.0,
                 "t0_ps": 0.0, "rfilter": {"type": "box"}}, **kw)


@pytest.mark.parametrize("name", ["llvm_ad_rgb", "llvm_ad_spectral"])
def test_time_integrated_rgb_equals_mitsuba_path(variant, name):
    """Summed over time, every channel equals Mitsuba's ``path`` RGB image (Welch t per channel, 3
    channels, false-failure rate 1e-3 for the three together)."""
    variant(name)
    W = H = 16
    depth, spp, seeds = 5, 32, 10
    tr = _cbox(_film(W, H), {"type": "transient_path", "max_depth": depth})
    pt = _cbox({"type": "hdrfilm", "width": W, "height": H, "rfilter": {"type": "box"}, "pixel_format": "rgb"},
               {"type": "path", "max_depth": depth})
    a, b = [], []
    for s in range(seeds):
        res = _render(tr, 100 + s, spp)
        assert res.histogram.shape == (H, W, 1500, 3) and res.dropped_contributions == 0
        a.append(res.histogram.sum(axis=(0, 1, 2), dtype=np.float64) / (W * H))
        b.append(np.asarray(mi.render(pt, spp=spp, seed=200 + s), dtype=np.float64)[..., :3].mean(axis=(0, 1)))
    a, b = np.array(a), np.array(b)
    assert np.all(a.mean(0) > 0) and not np.allclose(a.mean(0)[0], a.mean(0)[2])  # colour, not grey
    for c in range(3):
        va, vb = a[:, c].var(ddof=1), b[:, c].var(ddof=1)
        se = math.sqrt(va / seeds + vb / seeds)
        bound = t_bound(seeds, ALPHA, 3, df=welch_df(va, seeds, vb, seeds))
        assert abs(a[:, c].mean() - b[:, c].mean()) < bound * se, (c, a[:, c].mean(), b[:, c].mean())


def _mirror_scene(theta_deg, *, integrator=None, film=None, ior=1.5, extra=None, fov=0.5):
    """A camera looking at a smooth dielectric plane (z = 0) at ``theta_deg`` from its normal, seeing the
    reflection of a large area light placed mirror-symmetrically. The camera's up is in the plane of
    incidence, so s-polarized light (perpendicular to it) lies along the image's x axis."""
    th = math.radians(theta_deg)
    cam = [0.0, -2.0 * math.sin(th), 2.0 * math.cos(th)]
    light_c = [0.0, 3.0 * math.sin(th), 3.0 * math.cos(th)]
    d = {
        "type": "scene",
        "integrator": integrator or {"type": "transient_path", "max_depth": 3},
        "sensor": {"type": "perspective", "fov": fov,
                   "to_world": T().look_at(origin=cam, target=[0, 0, 0], up=[0, 0, 1]),
                   "film": film or _film(3, 3, n_bins=2000, bin_width_ps=5.0, t0_ps=12000.0),
                   "sampler": {"type": "independent", "sample_count": 64}},
        "plane": {"type": "rectangle", "to_world": T().scale(4.0),
                  "bsdf": {"type": "dielectric", "int_ior": ior, "ext_ior": 1.0}},
        "light": {"type": "rectangle",
                  "to_world": T().look_at(origin=light_c, target=[0, 0, 0], up=[0, 0, 1]) @ T().scale(1.0),
                  "emitter": {"type": "area", "radiance": {"type": "spectrum", "value": 1.0}}},
    }
    d.update(extra or {})
    return mi.load_dict(d)


def test_reflection_at_brewsters_angle_is_s_polarized_in_every_bin(variant):
    """At Brewster's angle (atan 1.5 = 56.31 deg) a smooth dielectric reflects only s-polarized light:
    in every bin holding light, S1 = S0 (linear polarization along the image's x axis, perpendicular to
    the plane of incidence), S2 = S3 = 0; the reflectance is the Fresnel R_s. 10 degrees off Brewster
    the light is only partly polarized (S1 / S0 = (R_s - R_p) / (R_s + R_p) < 1), as Fresnel says."""
    variant("llvm_ad_mono_polarized")
    n = 1.5
    for theta in (math.degrees(math.atan(n)), math.degrees(math.atan(n)) - 10.0):
        res = _render(_mirror_scene(theta), 1, 64)
        h = res.histogram[1, 1]  # [T, 4]
        assert h.shape == (2000, 4)
        lit = h[:, 0] > 1e-3 * h[:, 0].max()
        assert lit.sum() >= 1
        ti = math.radians(theta)
        tt = math.asin(math.sin(ti) / n)
        rs = (math.sin(ti - tt) / math.sin(ti + tt)) ** 2
        rp = (math.tan(ti - tt) / math.tan(ti + tt)) ** 2
        dolp = (rs - rp) / (rs + rp)
        s = h[lit]
        np.testing.assert_allclose(s[:, 1] / s[:, 0], dolp, atol=2e-3)
        np.testing.assert_allclose(s[:, 2:] / s[:, :1], 0.0, atol=2e-3)
        # unit radiance: the reflected S0 is (R_s + R_p) / 2 of it (the plane reflects with that probability)
        assert s[:, 0].sum() == pytest.approx((rs + rp) / 2, rel=0.15)


def test_malus_law_through_two_polarizers_in_every_bin(variant):
    """Unpolarized light through two ideal linear polarizers at relative angle phi: I = I_0 / 2 cos^2 phi,
    in every bin (the light arrives in one bin; delta BSDFs make it deterministic)."""
    variant("llvm_ad_mono_polarized")

    def scene(phi):
        sheets = {}
        for k, (z, ang) in enumerate(((0.6, 0.0), (0.9, phi))):
            sheets[f"pol{k}"] = {"type": "rectangle",
                                 "to_world": T().translate([0, 0, z]) @ T().scale(1.0),
                                 "bsdf": {"type": "polarizer", "theta": {"type": "spectrum", "value": ang}}}
        sheets["light"] = {"type": "rectangle", "to_world": T().translate([0, 0, 1.5]) @ T().rotate([1, 0, 0], 180),
                           "emitter": {"type": "area", "radiance": {"type": "spectrum", "value": 1.0}}}
        return mi.load_dict(dict({
            "type": "scene", "integrator": {"type": "transient_path", "max_depth": 4},
            "sensor": {"type": "perspective", "fov": 1.0,
                       "to_world": T().look_at(origin=[0, 0, 0], target=[0, 0, 1], up=[0, 1, 0]),
                       "film": _film(3, 3, n_bins=1000, bin_width_ps=5.0, t0_ps=3000.0),
                       "sampler": {"type": "independent", "sample_count": 16}}}, **sheets))

    ref = _render(scene(0.0), 1, 16).histogram[1, 1]
    assert ref[:, 0].sum() == pytest.approx(0.5, rel=1e-4)  # an ideal polarizer passes half of unpolarized light
    for phi in (30.0, 60.0, 90.0):
        h = _render(scene(phi), 1, 16).histogram[1, 1]
        np.testing.assert_allclose(h[:, 0], ref[:, 0] * math.cos(math.radians(phi)) ** 2, atol=1e-6)


def test_time_integrated_stokes_equals_mitsuba_stokes_integrator(variant):
    """Summed over time, S0..S3 equal Mitsuba's ``stokes`` integrator over ``path`` (a rough conductor
    and a dielectric off Brewster, so every component is non-trivial): Welch t per component, 4
    components, false-failure rate 1e-3 for the four together."""
    variant("llvm_ad_mono_polarized")
    extra = {"blob": {"type": "sphere", "center": [0.35, 0.0, 0.2], "radius": 0.2,
                      "bsdf": {"type": "roughconductor", "alpha": 0.3}}}
    theta = 40.0
    tr = _mirror_scene(theta, film=_film(8, 8, n_bins=2000, bin_width_ps=10.0, t0_ps=0.0),
                       integrator={"type": "transient_path", "max_depth": 4}, extra=extra, fov=30.0)
    st = _mirror_scene(theta, film={"type": "hdrfilm", "width": 8, "height": 8, "rfilter": {"type": "box"}},
                       integrator={"type": "stokes", "integrator": {"type": "path", "max_depth": 4}}, extra=extra,
                       fov=30.0)
    seeds, spp = 10, 32
    a, b = [], []
    for s in range(seeds):
        res = _render(tr, 10 + s, spp)
        assert res.dropped_contributions == 0
        a.append(res.histogram.sum(axis=2, dtype=np.float64).mean(axis=(0, 1)))
        img = np.asarray(mi.render(st, spp=spp, seed=50 + s), dtype=np.float64)  # [H, W, 3 + 12]: RGB, S0.RGB ...
        b.append([img[..., 3 + 3 * i].mean() for i in range(4)])  # mono: R = G = B
    a, b = np.array(a), np.array(b)
    assert abs(a[:, 1].mean()) > 1e-3 * a[:, 0].mean()  # partly polarized light
    for c in range(4):
        va, vb = a[:, c].var(ddof=1), b[:, c].var(ddof=1)
        se = math.sqrt(va / seeds + vb / seeds) + 1e-12
        bound = t_bound(seeds, ALPHA, 4, df=welch_df(va, seeds, vb, seeds))
        assert abs(a[:, c].mean() - b[:, c].mean()) < bound * se, (c, a[:, c].mean(), b[:, c].mean())


def _emitter_view(film):
    """A camera looking straight at a large area emitter (1 m away, filling the view) whose radiance rises
    linearly from 1 at 360 nm to 3 at 830 nm (a ``regular`` spectrum)."""
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "transient_path", "max_depth": 2},
        "sensor": {"type": "perspective", "fov": 20.0,
                   "to_world": T().look_at(origin=[0, 0, 1], target=[0, 0, 0], up=[0, 1, 0]), "film": film},
        "lamp": {"type": "rectangle", "emitter": {"type": "area", "radiance": {
            "type": "regular", "wavelength_min": 360.0, "wavelength_max": 830.0, "values": "1, 3"}}},
    })


def _band_integral(lo, hi):
    """Closed form of the band integral of L(lambda) = 1 + 2 (lambda - 360) / 470 over [lo, hi] (nm)."""
    F = lambda x: x + (x - 360.0) ** 2 / 470.0  # noqa: E731
    return F(hi) - F(lo)


def test_spectral_bands_integrate_the_spectrum_over_each_band(variant):
    """``spectral_bands_nm``: each band channel estimates the radiance integrated over its band. Against
    the closed-form integral of a linear spectrum, per band (Student t over seeds, 4 bands, false-failure
    rate 1e-3 for the four together); the capture's bands are named and the intensity rule is ``sum``."""
    variant("llvm_ad_spectral")
    edges = [360, 450, 550, 700, 830]
    scene = _emitter_view(_film(8, 8, n_bins=200, bin_width_ps=100.0, spectral_bands_nm="360, 450, 550, 700, 830"))
    assert scene.sensors()[0].film().channel_names() == ("360-450nm", "450-550nm", "550-700nm", "700-830nm")
    seeds, spp = 12, 16
    est = []
    for s in range(seeds):
        res = _render(scene, 300 + s, spp)
        assert res.histogram.shape == (8, 8, 200, 4) and res.dropped_contributions == 0
        est.append(res.histogram.sum(axis=2, dtype=np.float64).mean(axis=(0, 1)))
    est = np.array(est)
    bound = t_bound(seeds, ALPHA, 4)
    for c in range(4):
        ref = _band_integral(edges[c], edges[c + 1])
        se = est[:, c].std(ddof=1) / math.sqrt(seeds)
        assert abs(est[:, c].mean() - ref) < bound * se, (c, est[:, c].mean(), ref, se)
    from transient_core import stack
    assert stack.intensity_rule(["360-450nm", "450-550nm"]) == "sum"


@pytest.mark.parametrize("name, value, why", [
    ("llvm_ad_rgb", "400, 500", "needs a *_spectral variant"),
    ("llvm_ad_spectral", "500, 400", "increasing"),
    ("llvm_ad_spectral", "300, 400", "within 360..830"),
    ("llvm_ad_spectral", "400.5, 500", "whole-nanometre"),
    ("llvm_ad_spectral", "400", "at least two"),
    ("llvm_ad_spectral", "a, b", "allowed"),
])
def test_spectral_bands_bad_values_are_one_line_errors(variant, name, value, why):
    variant(name)
    with pytest.raises(Exception) as e:
        _emitter_view(_film(4, 4, spectral_bands_nm=value))
    from transient_mi.scene_io import mitsuba_error_message

    msg = mitsuba_error_message(e.value)
    assert "\n" not in msg and msg.startswith("transient_film: spectral_bands_nm=") and why in msg, msg
