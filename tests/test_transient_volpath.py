"""transient_volpath against Mitsuba's own ``volpath`` and against closed forms in homogeneous media.

Every statistical check states its false-failure rate (the probability that it fails although the code
is right); standard errors come from independent seeds, never hand-tuned (see ``stats_helpers``).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import transient_mi  # noqa: F401  (first: LLVM + plug-ins)
import mitsuba as mi

from stats_helpers import ALPHA, mean_se, t_bound, welch_df, z_bound
from transient_core.units import C_M_PER_PS

T = mi.ScalarTransform4f


def _tfilm(w, h, n_bins, bw, t0=0.0):
    return {"type": "transient_film", "width": w, "height": h, "n_bins": n_bins, "bin_width_ps": bw, "t0_ps": t0,
            "rfilter": {"type": "box"}}  # as the hdrfilm of the comparisons


def _hdrfilm(w, h):
    """Mitsuba's film in the format ours records: RGB in rgb variants (one value per channel), else luminance."""
    fmt = "rgb" if mi.is_rgb else "luminance"
    return {"type": "hdrfilm", "width": w, "height": h, "rfilter": {"type": "box"}, "pixel_format": fmt}


def _grey(v):
    return {"type": "spectrum", "value": float(v)}


# ------------------------------------------------------------------ scenes


def _grid():
    """A 6^3 density grid in [0, 1]: a smooth blob plus a fixed pseudo-random texture (seeded)."""
    n = 6
    x = (np.arange(n) + 0.5) / n - 0.5
    zz, yy, xx = np.meshgrid(x, x, x, indexing="ij")
    blob = np.exp(-(xx ** 2 + yy ** 2 + zz ** 2) / 0.08)
    noise = np.random.default_rng(7).uniform(0.0, 0.4, (n, n, n))
    return np.clip(0.6 * blob + noise, 0.0, 1.0).astype(np.float32)[..., None]


def _medium(kind, sigma_t=2.0, albedo=0.85):
    if kind == "homogeneous":
        return {"type": "homogeneous", "id": "smoke", "sigma_t": sigma_t, "albedo": albedo,
                "phase": {"type": "hg", "g": 0.3}}
    if kind == "heterogeneous":  # null scattering (delta tracking) and ratio tracking on the shadow rays
        return {"type": "heterogeneous", "id": "smoke", "scale": 2.0 * sigma_t, "albedo": albedo,
                "sigma_t": {"type": "gridvolume", "grid": mi.VolumeGrid(_grid()),
                            "to_world": T().translate([-0.6, -0.6, -0.6]).scale(1.2)},
                "phase": {"type": "hg", "g": 0.3}}
    if kind == "rgb":  # spectrally varying extinction (RGB variants: channel sampling)
        return {"type": "homogeneous", "id": "smoke", "scale": 4.0,
                "sigma_t": {"type": "rgb", "value": [0.15, 0.45, 1.0]},
                "albedo": {"type": "rgb", "value": [0.9, 0.6, 0.8]}, "phase": {"type": "hg", "g": 0.3}}
    raise ValueError(kind)


def _cube_scene(integrator, film, spp, medium="homogeneous", boundary="null"):
    """A scattering medium inside a cube (``null`` BSDF, or ``dielectric``) on a diffuse floor, lit by an area
    light."""
    return mi.load_dict({
        "type": "scene",
        "integrator": integrator,
        "sensor": {"type": "perspective", "fov": 45.0,
                   "to_world": T().look_at(origin=[0.3, 1.4, 3.0], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": film, "sampler": {"type": "independent", "sample_count": spp}},
        "smoke": _medium(medium),
        "cube": {"type": "cube", "to_world": T().scale(0.6), "bsdf": {"type": boundary},
                 "interior": {"type": "ref", "id": "smoke"}},
        "floor": {"type": "rectangle", "to_world": T().translate([0, -0.6, 0]).rotate([1, 0, 0], -90).scale(3.0),
                  "bsdf": {"type": "diffuse", "reflectance": _grey(0.6)}},
        "lamp": {"type": "rectangle",
                 "to_world": T().translate([0.4, 1.8, 0.3]).rotate([1, 0, 0], 90).scale(0.5),
                 "emitter": {"type": "area", "radiance": _grey(8.0)}},
    })


def _fog_scene(integrator, film, spp):
    """Global fog (the sensor's medium) around a diffuse plane, a small spherical area light in the fog."""
    return mi.load_dict({
        "type": "scene",
        "integrator": integrator,
        "fog": {"type": "homogeneous", "id": "fog", "sigma_t": 0.6, "albedo": 0.8},
        "sensor": {"type": "perspective", "fov": 40.0,
                   "to_world": T().look_at(origin=[0, 0.3, 3.0], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": film, "sampler": {"type": "independent", "sample_count": spp},
                   "medium": {"type": "ref", "id": "fog"}},
        "bulb": {"type": "sphere", "center": [0.5, 0.6, 1.2], "radius": 0.15,
                 "emitter": {"type": "area", "radiance": _grey(10.0)}},
        "plane": {"type": "rectangle", "to_world": T().scale(2.0),
                  "bsdf": {"type": "diffuse", "reflectance": _grey(0.7)}},
    })


def _ours_steady(make, n_seeds, W, H, spp, max_depth=-1):
    out = []
    for s in range(n_seeds):
        scene = make({"type": "transient_volpath", "max_depth": max_depth}, _tfilm(W, H, 4, 1e6), spp)
        res = scene.integrator().render_transient(scene, scene.sensors()[0], seed=1000 + s)
        assert res.dropped_contributions == 0 and res.invalid_contributions == 0
        out.append(res.steady.astype(np.float64))
    return np.stack(out)


def _mitsuba_images(make, n_seeds, W, H, spp, max_depth=-1):
    out = []
    for s in range(n_seeds):
        scene = make({"type": "volpath", "max_depth": max_depth}, _hdrfilm(W, H), spp)
        img = np.asarray(mi.render(scene, seed=2000 + s), dtype=np.float64)
        out.append(img[..., :3] if mi.is_rgb else img[..., 0])  # [H, W, 3] (rgb: as our steady) or [H, W]
    return np.stack(out)


def _heterogeneous_cube_scene(integrator, film, spp):
    return _cube_scene(integrator, film, spp, medium="heterogeneous")


def _glass_cube_scene(integrator, film, spp):
    return _cube_scene(integrator, film, spp, boundary="dielectric")


def _fog_hidden_scene(integrator, film, spp):
    return _fog_scene(dict(integrator, hide_emitters=True), film, spp)


@pytest.mark.parametrize("make,max_depth", [(_cube_scene, -1), (_cube_scene, 3), (_heterogeneous_cube_scene, -1),
                                            (_glass_cube_scene, -1), (_fog_scene, -1), (_fog_hidden_scene, -1)],
                         ids=["cube_medium", "cube_medium_depth3", "cube_heterogeneous", "glass_cube_medium", "global_fog",
                              "global_fog_hide_emitters"])
def test_time_integrated_image_equals_mitsuba_volpath(make, max_depth):
    """Summed over time, every pixel equals Mitsuba's ``volpath`` image (box filter, same scene).

    Welch t statistics per pixel from 16 + 16 independent seeds, Bonferroni over the pixels and the image
    mean: family-wise false-failure rate ``ALPHA`` = 0.1 % per scene (Welch's t is approximate).
    """
    a, b = _both(make, max_depth)
    _assert_same_means(a, b)


N_SEEDS, SPP, W_IMG = 16, 256, 6


def _both(make, max_depth):
    """Per-seed images ``[N_SEEDS, W*W]`` of ours (time-integrated) and of Mitsuba's volpath."""
    n, W = N_SEEDS, W_IMG
    a = _ours_steady(make, n, W, W, SPP, max_depth).reshape(n, -1)
    b = _mitsuba_images(make, n, W, W, SPP, max_depth).reshape(n, -1)
    return a, b


def _assert_same_means(a, b):
    n = a.shape[0]
    a = np.concatenate([a, a.mean(1, keepdims=True)], 1)
    b = np.concatenate([b, b.mean(1, keepdims=True)], 1)
    ma, sa, _ = mean_se(a)
    mb, sb, _ = mean_se(b)
    se = np.sqrt(sa ** 2 + sb ** 2)
    dark = se == 0  # pixels that see no light (the sky above the floor): black in both
    assert np.all(ma[dark] == 0) and np.all(mb[dark] == 0)
    assert dark.sum() <= a.shape[1] // 4, "too few lit pixels: the scene does not test what it names"
    t = np.where(dark, 0.0, (ma - mb) / np.where(dark, 1.0, se))
    k = int((~dark).sum())
    for i in np.nonzero(~dark)[0]:
        df = welch_df(sa[i] ** 2 * n, n, sb[i] ** 2 * n, n)
        bound = t_bound(n, ALPHA, k, df=df)
        assert abs(t[i]) <= bound, f"value {i}: ours {ma[i]:.5g} vs volpath {mb[i]:.5g}, t = {t[i]:+.2f} > {bound:.2f}"
    # the comparison has power: the image means agree to a few per cent
    assert se[-1] < 0.03 * mb[-1]


_RGB_SCRIPT = """
import json, sys
sys.path.insert(0, {tests!r})
import test_transient_volpath as t
assert t.mi.variant() == "llvm_ad_rgb", t.mi.variant()
make = lambda i, f, s: t._cube_scene(i, f, s, medium="rgb")
a, b = t._both(make, -1)
print("JSON" + json.dumps([a.tolist(), b.tolist()]))
"""


def test_rgb_variant_spectral_extinction_equals_mitsuba_volpath():
    """RGB variant, extinction and albedo varying per channel (one channel sampled per path for the free
    flights, as volpath): every channel of every pixel equals Mitsuba's ``volpath`` RGB.

    Run in a subprocess (``TRANSIENT_MI_VARIANT=llvm_ad_rgb``); same statistics as the mono comparison:
    family-wise false-failure rate ``ALPHA`` = 0.1 %.
    """
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    tests = str(Path(__file__).resolve().parent)
    env = dict(os.environ, TRANSIENT_MI_VARIANT="llvm_ad_rgb")
    out = subprocess.run([sys.executable, "-c", _RGB_SCRIPT.format(tests=tests)], env=env, capture_output=True,
                         text=True, timeout=600, check=False)
    assert out.returncode == 0, out.stderr[-2000:]
    line = [x for x in out.stdout.splitlines() if x.startswith("JSON")][-1]
    a, b = (np.asarray(x) for x in json.loads(line[4:]))
    _assert_same_means(a, b)


# ------------------------------------------------------------- ballistic peak


def _slab_scene(sigma_t, albedo, max_depth, spp, *, medium=True, heterogeneous=False):
    """A radiance meter at z = 3 looking down -z through a 1 m null-BSDF cube (z in [-0.5, 0.5]) at an
    area emitter (radiance 2) at z = -1.5 facing it."""
    d = {
        "type": "scene",
        "integrator": {"type": "transient_volpath", "max_depth": max_depth},
        "sensor": {"type": "radiancemeter", "origin": [0.05, 0.02, 3.0], "direction": [0, 0, -1],
                   "film": _tfilm(1, 1, 100, 250.0, 125.0), "sampler": {"type": "independent", "sample_count": spp}},
        "lamp": {"type": "rectangle", "to_world": T().translate([0, 0, -1.5]),
                 "emitter": {"type": "area", "radiance": _grey(2.0)}},
    }
    if medium:
        inner = {"type": "homogeneous", "sigma_t": sigma_t, "albedo": albedo}
        if heterogeneous:
            # density 1/2 along the ray; one corner voxel of density 1 raises the majorant to 2x: about half the
            # tentative collisions on the ray are null events (trilinear interpolation stays 1/2 near the axis)
            grid = np.full((4, 4, 4, 1), 0.5, dtype=np.float32)
            grid[0, 0, 0, 0] = 1.0
            inner = {"type": "heterogeneous", "scale": 2.0 * sigma_t, "albedo": albedo,
                     "sigma_t": {"type": "gridvolume", "grid": mi.VolumeGrid(grid),
                                 "to_world": T().translate([-0.5, -0.5, -0.5])}}
        d["cube"] = {"type": "cube", "to_world": T().scale(0.5), "bsdf": {"type": "null"}, "interior": inner}
    return mi.load_dict(d)


@pytest.mark.parametrize("sigma_t,albedo,max_depth,het", [(1.3, 0.0, -1, False), (0.7, 0.8, 1, False),
                                                          (1.3, 0.0, -1, True)],
                         ids=["absorbing", "scattering_unscattered_only", "heterogeneous_null_events"])
def test_ballistic_peak_is_attenuated_by_beer_lambert(sigma_t, albedo, max_depth, het):
    """The unscattered arrival: in the bin of the straight path (4.5 m) the radiance meter reads
    ``L_e exp(-sigma_t d)`` with ``d`` = 1 m of medium, the no-medium reading times Beer-Lambert. In the
    heterogeneous case (density sigma_t along the ray under a majorant of 2 sigma_t) the path is cut into
    null-scattering segments: their lengths must add up to the straight path (all light in one bin).

    Each sample passes the slab (weight ``L_e``) with probability ``p = exp(-sigma_t d)`` (or is absorbed /
    scatters out of the recorded depth: weight 0): the bin's mean over ``N`` samples is a binomial
    proportion with the exact standard error ``L_e sqrt(p (1 - p) / N)``; a two-sided z-test at
    ``ALPHA``: false-failure rate 0.1 % (normal approximation at N = 65536).
    """
    n_renders, spp = 64, 1024  # N = 65536 samples (a 1-pixel film with spp = K lanes compiles a K-term sum)
    N = n_renders * spp
    Le, d, L = 2.0, 1.0, 4.5
    ref = _slab_scene(sigma_t, albedo, max_depth, 256, medium=False)
    r0 = ref.integrator().render_transient(ref, ref.sensors()[0], seed=3)
    scene = _slab_scene(sigma_t, albedo, max_depth, spp, heterogeneous=het)
    h = np.zeros(r0.histogram.shape[-1])
    for s in range(n_renders):
        h += scene.integrator().render_transient(scene, scene.sensors()[0], seed=3 + s).histogram[0, 0] / n_renders
    b = int((L / C_M_PER_PS - 125.0) // 250.0)
    assert np.argmax(r0.histogram[0, 0]) == b and r0.histogram[0, 0, b] == pytest.approx(Le, rel=1e-6)
    p = math.exp(-sigma_t * d)
    z = (h[b] - Le * p) / (Le * math.sqrt(p * (1 - p) / N))
    assert abs(z) <= z_bound(ALPHA), f"peak {h[b]:.5g} vs {Le * p:.5g}: z = {z:+.2f}"
    if albedo == 0 or max_depth == 1:  # nothing else arrives: only the ballistic bin holds light
        assert h.sum() == pytest.approx(h[b], rel=1e-6)


# ------------------------------------------------------- single scattering


SIG_T, ALBEDO, G = 0.8, 0.6, 0.4
LIGHT = np.array([0.6, 0.0, -1.0])
INTENSITY = 3.0
BW = 200.0  # ps
N_BINS = 60


def _hg(cos_theta, g):
    return (1 - g * g) / (4 * math.pi * (1 + g * g - 2 * g * cos_theta) ** 1.5)


def _single_scattering_bins():
    """Closed form: radiance meter at the origin looking down -z in an infinite medium, isotropic point
    light at LIGHT; light scattered once at ``x(s) = -s z`` arrives after ``s + r(s)``.

    ``L = int sigma_s e^{-sigma_t s} p(theta) I e^{-sigma_t r} / r^2 ds`` binned by ``(s + r) / c``; the
    integral over each bin is evaluated with 2000 midpoints per bin of the 1-D ray parameter.
    """
    d = np.array([0.0, 0.0, -1.0])
    edges_m = np.arange(N_BINS + 1) * BW * C_M_PER_PS
    r0 = float(np.linalg.norm(LIGHT))
    out = np.zeros(N_BINS)
    for k in range(N_BINS):
        lo, hi = edges_m[k], edges_m[k + 1]
        if hi <= r0:
            continue
        # s + r(s) is increasing in s (d/ds = 1 + cos >= 0); invert by bisection
        def s_of(L):
            if L <= r0:
                return 0.0
            a, b = 0.0, L
            for _ in range(80):
                m = 0.5 * (a + b)
                if m + np.linalg.norm(LIGHT - m * d) < L:
                    a = m
                else:
                    b = m
            return 0.5 * (a + b)
        s0, s1 = s_of(lo), s_of(hi)
        n = 2000
        s = s0 + (np.arange(n) + 0.5) * (s1 - s0) / n
        x = s[:, None] * d
        v = LIGHT - x
        r = np.linalg.norm(v, axis=1)
        # light travels LIGHT -> x -> origin: scattering angle between (x - LIGHT)/r and -d
        cos_t = ((-v / r[:, None]) @ -d)
        f = SIG_T * ALBEDO * np.exp(-SIG_T * (s + r)) * _hg(cos_t, G) * INTENSITY / r ** 2
        out[k] = f.sum() * (s1 - s0) / n
    return out


def test_single_scattering_time_profile_matches_closed_form():
    """max_depth = 2 records exactly single scattering (one medium vertex + next-event estimation).

    Per-bin t statistics from 64 independent seeds against the numerically integrated closed form, at
    Student's t with 63 degrees of freedom, Bonferroni over the bins with light: family-wise false-failure
    rate ``ALPHA`` = 0.1 %. The quadrature error is below 1e-6 of every bin (2000 midpoints), far under
    the standard errors (> 1e-3 relative).
    """
    ref = _single_scattering_bins()
    n_seeds, spp = 64, 1024  # (a 1-pixel film with spp = K lanes compiles a K-term reduction: keep K small)
    hists = []
    for s in range(n_seeds):
        scene = mi.load_dict({
            "type": "scene",
            "integrator": {"type": "transient_volpath", "max_depth": 2},
            "fog": {"type": "homogeneous", "id": "fog", "sigma_t": SIG_T, "albedo": ALBEDO,
                    "phase": {"type": "hg", "g": G}},
            "sensor": {"type": "radiancemeter", "origin": [0, 0, 0], "direction": [0, 0, -1],
                       "medium": {"type": "ref", "id": "fog"}, "film": _tfilm(1, 1, N_BINS, BW, 0.0),
                       "sampler": {"type": "independent", "sample_count": spp}},
            "light": {"type": "point", "position": LIGHT.tolist(), "intensity": _grey(INTENSITY)},
        })
        res = scene.integrator().render_transient(scene, scene.sensors()[0], seed=77 + s)
        assert res.invalid_contributions == 0
        hists.append(res.histogram[0, 0].astype(np.float64))
    m, se, n = mean_se(np.stack(hists))
    lit = ref > 0
    assert np.array_equal(lit, m > 0), "light recorded before it can arrive (or missing after)"
    k = int(lit.sum())
    assert k >= 40
    t = (m[lit] - ref[lit]) / se[lit]
    bound = t_bound(n, ALPHA, k)
    worst = int(np.argmax(np.abs(t)))
    assert np.all(np.abs(t) <= bound), f"bin {worst}: t = {t[worst]:+.2f} > {bound:.2f}"
    assert se[lit].sum() < 0.02 * ref.sum()  # power: the profile is resolved to a few per cent


# ---------------------------------------------------------------- time origin


def test_without_media_the_peak_is_at_the_two_segment_path_length_from_the_camera_centre():
    """No media, point light over a plane, max_depth = 2: every pixel's arrivals peak in the bin of
    ``|x - camera centre| + |x - light|`` for its pixel-centre point ``x`` (within one bin: the pixel
    footprint spreads the path lengths); the first segment is timed from the centre of projection, not
    from ``ray.o`` on the near-clip plane (1 cm = 33 ps further). Deterministic bounds, no statistics."""
    W = H = 12
    cam, light = np.array([0.25, 0.15, 2.0]), np.array([-0.5, 0.6, 1.0])
    bw, t0, n_bins = 25.0, 8000.0, 320
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "transient_volpath", "max_depth": 2},
        "sensor": {"type": "perspective", "fov": 10.0, "near_clip": 0.01,
                   "to_world": T().look_at(origin=cam.tolist(), target=[0, 0, 0], up=[0, 1, 0]),
                   "film": _tfilm(W, H, n_bins, bw, t0), "sampler": {"type": "independent", "sample_count": 16}},
        "light": {"type": "point", "position": light.tolist(), "intensity": _grey(5.0)},
        "plane": {"type": "rectangle", "to_world": T().scale(3.0),
                  "bsdf": {"type": "diffuse", "reflectance": _grey(0.8)}},
    })
    res = scene.integrator().render_transient(scene, scene.sensors()[0], seed=3)
    j, i = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    pos = mi.Point2f((i.ravel() + 0.5) / W, (j.ravel() + 0.5) / H)
    ray, _ = scene.sensors()[0].sample_ray(mi.Float(0), mi.Float(0), pos, mi.Point2f(0.5))
    si = scene.ray_intersect(ray)
    x = np.stack([np.asarray(si.p.x), np.asarray(si.p.y), np.asarray(si.p.z)], -1).reshape(H, W, 3)
    opl = np.linalg.norm(x - light, axis=-1) + np.linalg.norm(x - cam, axis=-1)
    expected = np.floor((opl / C_M_PER_PS - t0) / bw).astype(int)
    assert np.all((expected > 0) & (expected < n_bins - 1))
    peak = np.argmax(res.histogram, axis=-1)
    assert np.all(res.histogram.sum(-1) > 0)
    assert np.max(np.abs(peak - expected)) <= 1


# ------------------------------------------------------------------- errors


@pytest.mark.parametrize("key,value,words", [
    ("max_depth", -2, "max_depth=-2"), ("max_depth", 0, "max_depth=0"), ("rr_depth", 0, "rr_depth=0"),
    ("hide_emitters", "yes", "hide_emitters"), ("variance_replicates", 0, "variance_replicates=0"),
])
def test_bad_parameters_raise_one_line(key, value, words):
    with pytest.raises(Exception) as e:
        mi.load_dict({"type": "transient_volpath", key: value})
    msg = str(e.value)
    assert "transient_volpath" in msg and words in msg


def test_spad_array_sensor_without_medium_renders_the_nlos_capture():
    """Under a spad_array without a sensor medium transient_volpath runs the NLOS estimator: the bytes of
    transient_nlos_path (NLOS captures in fog: tests/test_nlos_fog.py)."""
    from nlos_helpers import nlos_scene, square

    scene = nlos_scene(width=2, height=2, n_bins=1100, hidden=[square((0.0, 0.0, 0.4), 0.2, 0.7)])
    ref = scene.integrator().render_transient(scene, scene.sensors()[0], seed=0, spp=4).histogram
    integ = mi.load_dict({"type": "transient_volpath", "max_depth": 4})
    out = integ.render_transient(scene, scene.sensors()[0], seed=0, spp=4).histogram
    assert ref.sum() > 0 and out.tobytes() == ref.tobytes()


# -------------------------------------------------------------- determinism


def test_same_seed_same_bytes():
    W = H = 8
    a, b = [_fog_scene({"type": "transient_volpath"}, _tfilm(W, H, 64, 100.0), 16) for _ in range(2)]
    ra = a.integrator().render_transient(a, a.sensors()[0], seed=5)
    rb = b.integrator().render_transient(b, b.sensors()[0], seed=5)
    rc = b.integrator().render_transient(b, b.sensors()[0], seed=6)
    assert ra.histogram.sum() > 0
    assert ra.histogram.tobytes() == rb.histogram.tobytes()
    assert ra.histogram.tobytes() != rc.histogram.tobytes()


# -------------------------------------------------------------- example scene


def test_fog_scene_renders_with_the_cli(tmp_path):
    """``scenes/fog_camera.xml`` renders with ``transient-mi render`` (small -D overrides); a complete capture."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    out = tmp_path / "fog"
    env = dict(os.environ, TRANSIENT_MI_PROGRESS="0")
    r = subprocess.run([sys.executable, "-m", "transient_mi", "render", "scenes/fog_camera.xml", "-o", str(out),
                        "-D", "width=8", "-D", "height=8", "-D", "spp=4", "-D", "n_bins=200"],
                       cwd=root, env=env, capture_output=True, text=True, timeout=300, check=False)
    assert r.returncode == 0, r.stderr[-2000:]
    m = json.loads((out / "manifest.json").read_text())
    assert m["status"] == "complete" and m["render"]["integrator"].startswith("TransientVolPath")
    assert m["dropped"]["invalid_path_lengths"] == 0
