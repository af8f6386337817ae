"""NLOS estimator properties: confocal = array on the diagonal, mirror symmetry, sampling strategies
agree, higher bounces, determinism."""

import numpy as np
import pytest
from scipy import stats

import transient_mi  # noqa: F401
from nlos_helpers import nlos_scene, patch_centers, render, seed_stats, square, wall_return_reference

N_SEEDS = 8


def _coarse(h, n=8):
    """Rebin the time axis into ``n`` coarse bins (for statistical comparisons)."""
    T = h.shape[-1] - h.shape[-1] % n
    return h[..., :T].reshape(*h.shape[:-1], n, T // n).sum(-1)


def _chi2_pvalue(a, se_a, b, se_b, n_a=N_SEEDS, n_b=N_SEEDS):
    """p-value of 'a and b estimate the same values' (independent estimates with standard errors).

    ``se_a``, ``se_b`` are estimated from ``n_a``, ``n_b`` seeds, so each bin's
    ``(a - b) / sqrt(se_a^2 + se_b^2)`` follows Welch's t (not a normal): it is
    turned into its two-sided t p-value, then into the normal quantile with the
    same p-value, whose square is chi-square(1) under the null. Their sum over
    the bins is chi-square with one degree of freedom per bin. (A plain sum of
    squared t's has a heavier tail and rejects far too often with 8 seeds.)
    """
    var = se_a ** 2 + se_b ** 2
    m = var > 0
    both_zero = (~m) & (a == b)
    assert np.all(m | both_zero), "a value differs where both estimates have zero variance"
    t = np.abs(a - b)[m] / np.sqrt(var[m])
    va, vb = (se_a ** 2)[m], (se_b ** 2)[m]
    dof = var[m] ** 2 / (va ** 2 / (n_a - 1) + vb ** 2 / (n_b - 1))  # Welch-Satterthwaite
    z = stats.norm.isf(stats.t.sf(t, dof))
    return stats.chi2.sf(float((z ** 2).sum()), int(m.sum())), int(m.sum())


def test_confocal_pixel_equals_array_capture_with_laser_on_that_patch():
    W = H = 3
    fp = 0.05
    hidden = [square((0.04, 0.02, 0.3), 0.08, 0.7)]
    common = dict(width=W, height=H, footprint=fp, hidden=hidden, n_bins=240, bin_width_ps=25.0, t0_ps=9000.0)
    conf = nlos_scene(capture="confocal", include_wall_return=False, **common)
    arr = nlos_scene(capture="array", spots=(W, H), spacing=fp, include_wall_return=False, **common)
    c_runs = np.stack([render(conf, seed=100 + s, spp=64) for s in range(N_SEEDS)])
    diag = []
    for s in range(N_SEEDS):
        per_spot = [render(arr, seed=200 + s, spp=64, spot=k) for k in range(W * H)]
        diag.append(np.stack([per_spot[k][k // W, k % W] for k in range(W * H)]).reshape(H, W, -1))
    a_runs = np.stack(diag)
    assert c_runs.sum() > 0
    mc, sc = seed_stats(_coarse(c_runs, 48))
    ma, sa = seed_stats(_coarse(a_runs, 48))
    p, dof = _chi2_pvalue(mc, sc, ma, sa)
    assert dof >= 20
    assert p > 1e-3, f"confocal vs array diagonal: chi2 p-value {p:.2g} over {dof} coarse bins"
    # and the closed-form wall return is the same number in both modes
    conf_r = nlos_scene(capture="confocal", **common, include_wall_return=True)
    arr_r = nlos_scene(capture="array", spots=(W, H), spacing=fp, **common, include_wall_return=True)
    hc = render(conf_r, seed=1, spp=4) - render(conf, seed=1, spp=4)
    for k in range(W * H):
        ha = render(arr_r, seed=1, spp=4, spot=k) - render(arr, seed=1, spp=4, spot=k)
        y, x = divmod(k, W)
        np.testing.assert_allclose(hc[y, x], ha[y, x], rtol=1e-5, atol=1e-3 * ha[y, x].max())
        ref, _ = wall_return_reference(patch_centers(W, H, fp)[y, x])
        assert hc[y, x].sum() == pytest.approx(ref, rel=1e-4)


def test_mirror_symmetric_scene_gives_mirror_symmetric_capture():
    # symmetric about the plane x = 0: laser, detector and the two targets; spots at x = -0.1 and +0.1
    laser = np.array([0.0, -0.8, 1.0])
    det = np.array([0.0, -0.9, 1.0])
    hidden = [square((-0.12, 0.05, 0.35), 0.06, 0.7, id_="left"), square((0.12, 0.05, 0.35), 0.06, 0.7, id_="right"),
              square((0.0, -0.1, 0.5), 0.1, 0.5, id_="middle")]
    W, H = 6, 4
    sc = nlos_scene(width=W, height=H, footprint=0.05, spots=(2, 1), spacing=0.2, hidden=hidden, laser=laser,
                    detector=det, include_wall_return=False, max_depth=5, n_bins=200, bin_width_ps=30.0,
                    t0_ps=9000.0)
    s0 = np.stack([render(sc, seed=10 + s, spp=64, spot=0) for s in range(N_SEEDS)])
    s1 = np.stack([render(sc, seed=40 + s, spp=64, spot=1) for s in range(N_SEEDS)])
    mirrored = s1[:, :, ::-1, :]  # spot 1 is the mirror image of spot 0; pixel x -> W - 1 - x
    m0, e0 = seed_stats(_coarse(s0, 40))
    m1, e1 = seed_stats(_coarse(mirrored, 40))
    p, dof = _chi2_pvalue(m0, e0, m1, e1)
    assert dof >= 100
    assert p > 1e-3, f"mirror symmetry: chi2 p-value {p:.2g} over {dof} coarse bins"
    # and it is not symmetric without mirroring (the test can fail)
    p_raw, _ = _chi2_pvalue(m0, e0, *seed_stats(_coarse(s1, 40)))
    assert p_raw < 1e-6


def test_sampling_strategies_agree():
    """Hidden-geometry sampling (one-sample MIS) and pure BSDF sampling estimate the same capture."""
    hidden = [square((0.1, 0.05, 0.25), 0.2, 0.7), square((0.1, -0.1, 0.45), 0.15, 0.5, id_="t2")]
    kw = dict(width=3, height=3, footprint=0.08, hidden=hidden, include_wall_return=False, max_depth=6,
              n_bins=100, bin_width_ps=60.0, t0_ps=9000.0)
    mis = nlos_scene(hidden_geometry_prob=0.8, **kw)
    bsdf = nlos_scene(hidden_geometry_prob=0.0, **kw)
    hg_only = nlos_scene(hidden_geometry_prob=1.0, **kw)
    a = np.stack([render(mis, seed=s, spp=128) for s in range(N_SEEDS)])
    b = np.stack([render(bsdf, seed=50 + s, spp=512) for s in range(N_SEEDS)])
    c = np.stack([render(hg_only, seed=90 + s, spp=128) for s in range(N_SEEDS)])
    ma, ea = seed_stats(_coarse(a, 10))
    mb, eb = seed_stats(_coarse(b, 10))
    mc, ec = seed_stats(_coarse(c, 10))
    for (m2, e2, name) in ((mb, eb, "bsdf-only"), (mc, ec, "hidden-only")):
        p, dof = _chi2_pvalue(ma, ea, m2, e2)
        assert dof >= 30
        assert p > 1e-3, f"MIS vs {name}: chi2 p-value {p:.2g}"


def test_higher_bounces_add_light_later():
    hidden = [square((0.0, 0.0, 0.3), 0.3, 0.8)]
    kw = dict(width=2, height=2, footprint=0.1, hidden=hidden, include_wall_return=False, n_bins=120,
              bin_width_ps=50.0, t0_ps=9000.0)
    three = render(nlos_scene(max_depth=4, **kw), seed=1, spp=256)
    more = render(nlos_scene(max_depth=8, **kw), seed=1, spp=256)
    assert more.sum() > three.sum() * 1.01  # wall-object interreflections exist
    first3 = np.nonzero(three.sum((0, 1)))[0].min()
    extra = more.sum((0, 1)) - three.sum((0, 1))
    # extra light (4+ bounces) arrives no earlier than the three-bounce light
    assert np.all(np.abs(extra[:first3]) <= 1e-6 * three.max())


def test_same_seed_same_bytes():
    hidden = [square((0.05, 0.0, 0.4), 0.1, 0.7)]
    sc = nlos_scene(width=4, height=3, capture="confocal", hidden=hidden, n_bins=64, bin_width_ps=100.0,
                    t0_ps=9000.0, max_depth=6)
    a = render(sc, seed=7, spp=32)
    b = render(sc, seed=7, spp=32)
    c = render(sc, seed=8, spp=32)
    assert a.tobytes() == b.tobytes()
    assert a.tobytes() != c.tobytes()


def test_spot_groups_estimate_the_same_as_single_spots():
    """Spots rendered together (sharing detector-side sub-paths) equal spots rendered alone, statistically."""
    hidden = [square((0.05, 0.05, 0.35), 0.12, 0.7)]
    sc = nlos_scene(width=3, height=3, footprint=0.06, spots=(2, 2), spacing=0.15, hidden=hidden,
                    include_wall_return=False, max_depth=6, n_bins=60, bin_width_ps=80.0, t0_ps=9000.0)
    integ, sensor = sc.integrator(), sc.sensors()[0]
    groups = [np.stack([r.histogram for r in integ.render_transient(sc, sensor, seed=300 + s, spp=64,
                                                                    spots=[0, 1, 2, 3])]).astype(np.float64)
              for s in range(N_SEEDS)]
    singles = [np.stack([render(sc, seed=400 + 10 * s + j, spp=64, spot=j) for j in range(4)])
               for s in range(N_SEEDS)]
    mg, eg = seed_stats(_coarse(np.stack(groups), 10))
    ms, es = seed_stats(_coarse(np.stack(singles), 10))
    p, dof = _chi2_pvalue(mg, eg, ms, es)
    assert dof >= 50
    assert p > 1e-3, f"groups vs single spots: chi2 p-value {p:.2g}"
    assert sensor.spot_groups(sc, 64) == [[0, 1, 2, 3]]


def test_laser_is_invisible_to_mitsuba_and_does_not_break_camera_renders():
    """A pulsed_laser alive in the process must not disturb other renders (Dr.Jit traces every emitter)."""
    import mitsuba as mi

    nlos = nlos_scene(width=2, height=2, hidden=[square((0.0, 0.0, 0.4), 0.1, 0.7)], t0_ps=9000.0, bin_width_ps=50.0)
    assert render(nlos, seed=0, spp=4).sum() > 0
    # Mitsuba's own path tracer neither hits nor samples the laser: a black image
    img = mi.render(mi.load_dict({
        "type": "scene", "integrator": {"type": "path"},
        "laser": {"type": "pulsed_laser", "origin": [0, 0, 2], "target": [0, 0, 0]},
        "wall": {"type": "rectangle"},
        "cam": {"type": "perspective", "to_world": mi.ScalarTransform4f().look_at([0, 0, 3], [0, 0, 0], [0, 1, 0]),
                "film": {"type": "hdrfilm", "width": 8, "height": 8}},
    }, optimize=False), spp=4)
    assert float(np.asarray(img).max()) == 0.0
    # a camera render with the transient integrator in the same process
    cam = mi.load_dict({
        "type": "scene", "integrator": {"type": "transient_path", "max_depth": 3},
        "light": {"type": "point", "position": [0, 0, 1], "intensity": {"type": "rgb", "value": [1, 1, 1]}},
        "plane": {"type": "rectangle"},
        "cam": {"type": "perspective", "to_world": mi.ScalarTransform4f().look_at([0, 0, 3], [0, 0, 0], [0, 1, 0]),
                "film": {"type": "transient_film", "width": 4, "height": 4, "n_bins": 50, "bin_width_ps": 1000.0}},
    })
    res = cam.integrator().render_transient(cam, cam.sensors()[0], seed=0, spp=4)
    assert res.histogram.sum() > 0
