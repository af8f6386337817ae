"""``estimator="quadrature"`` beyond three bounces: the quadrature's three-bounce light plus the Monte Carlo
remainder (every other path; ``KernelConstants.skip_three_bounce``).

* the sum agrees with plain Monte Carlo at ``max_depth=6`` on two hidden squares facing each other (their
  inter-reflections are the deeper light), pixel x time-window sums within the t interval of both estimators'
  replicates plus the quadrature's bound;
* the remainder alone has no three-bounce light and no wall return (exactly zero at ``max_depth=4``), and the
  capture is exactly quadrature(max_depth 4) + remainder(max_depth 6) of the same seed;
* the render pipeline stores both errors (``variance/`` and ``error_bound/``) and states both in the manifest;
  ``detect`` adds them; resume re-renders a spot whose error-bound file is missing;
* ``max_depth > 4`` is no longer refused; the other refusals stay.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import transient_mi  # noqa: F401  (LLVM + variant + plug-ins)
from nlos_helpers import nlos_scene
from stats_helpers import t_bound
from transient_mi.props import PluginParameterError

#: Family-wise false-failure rate of the Monte Carlo comparisons below (Bonferroni over their checks).
ALPHA = 1e-3
#: Quadrature settings (coarse: the bound is part of every comparison).
Q = dict(element_size_m=0.02, patch_cells=2)
SPP = 1024
N_WINDOWS = 8


def _tilted(center, side, albedo, angle_deg, id_):
    """A Lambertian square facing the wall (-z), turned by ``angle_deg`` about y."""
    import mitsuba as mi

    T = mi.ScalarTransform4f
    xf = (T().translate([float(c) for c in center]) @ T().rotate([0, 1, 0], angle_deg) @ T().rotate([1, 0, 0], 180)
          @ T().scale([side / 2.0, side / 2.0, 1.0]))
    return {"type": "rectangle", "id": id_, "to_world": xf,
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [albedo] * 3}}}


def _scene(max_depth):
    """2 x 2 pixels, 64 bins of 128 ps: the wall return and two squares turned 40 degrees towards each other
    (each sees the other and the wall)."""
    return nlos_scene(width=2, height=2, footprint=0.1, include_wall_return=True, n_bins=64, bin_width_ps=128.0,
                      t0_ps=9000.0, max_depth=max_depth,
                      hidden=[_tilted((-0.12, 0.0, 0.45), 0.2, 0.9, -40, "a"),
                              _tilted((0.12, 0.0, 0.45), 0.2, 0.85, 40, "b")])


def _render(max_depth, seed, spp, **opts):
    s = _scene(max_depth)
    integ = s.integrator()
    integ.variance_replicates = 8
    integ.nlos_options.update(opts)
    return integ.render_transient(s, s.sensors()[0], seed=seed, spp=spp, spot=0)


def _windows(a):
    a = a.astype(np.float64)
    return a.reshape(-1, N_WINDOWS, a.shape[-1] // N_WINDOWS).sum(-1)


@pytest.fixture(scope="module")
def combined():
    return _render(6, 1, SPP, estimator="quadrature", **Q)


def test_remainder_plus_quadrature_agrees_with_monte_carlo(combined):
    """Quadrature + remainder (seed 1) against plain Monte Carlo (seed 3), both at max_depth=6 with 8 replicates:
    every lit pixel x window sum and the grand total within ``t * sqrt(s_R^2 + s_MC^2) + bound``, t the Student
    quantile of 7 degrees of freedom (conservative: the Welch degrees of freedom of two 8-replicate means are
    at least 7) at a family-wise false-failure rate of 1e-3 (Bonferroni over the windows and the total)."""
    mc = _render(6, 3, SPP)
    d = _windows(combined.histogram) - _windows(mc.histogram)
    se = np.sqrt(_windows(combined.variance) + _windows(mc.variance))
    bound = _windows(combined.error_bound)
    lit = se > 0
    assert lit.sum() >= 16
    tb = t_bound(8, ALPHA, int(lit.sum()) + 1)
    bad = np.abs(d[lit]) > tb * se[lit] + bound[lit]
    assert not bad.any(), (d[lit][bad], se[lit][bad], bound[lit][bad])
    tot_d = float(combined.histogram.astype(np.float64).sum() - mc.histogram.astype(np.float64).sum())
    tot_se = float(np.sqrt(combined.total_variance.astype(np.float64).sum()
                           + mc.total_variance.astype(np.float64).sum()))
    assert abs(tot_d) <= tb * tot_se + float(combined.total_error_bound.astype(np.float64).sum())
    assert combined.replicates == 8 and combined.estimator_info["remainder"] == "monte_carlo"


def test_remainder_has_no_three_bounce_light(combined):
    """The remainder alone (the Monte Carlo kernel with skip_three_bounce) is exactly zero at max_depth=4 (planar
    wall: no depth-1 connection; no three-bounce connection; no wall return). At max_depth=6 it is the deeper
    light, far above its noise, and the capture is exactly quadrature(4) + remainder(6) of the same seed."""
    r4 = _render(4, 1, 64, skip_three_bounce=True)
    assert not np.any(r4.histogram) and not np.any(r4.steady)
    r6 = _render(6, 1, SPP, skip_three_bounce=True)
    q4 = _render(4, 0, 1, estimator="quadrature", **Q)
    tot, se = float(r6.histogram.astype(np.float64).sum()), float(np.sqrt(r6.total_variance.astype(np.float64).sum()))
    assert tot > 10 * se > 0  # light beyond three bounces exists and is resolved
    want = (q4.histogram.astype(np.float64) + r6.histogram.astype(np.float64)).astype(np.float32)
    np.testing.assert_array_equal(combined.histogram, want)
    np.testing.assert_array_equal(combined.variance, r6.variance)
    np.testing.assert_array_equal(combined.error_bound, q4.error_bound)


def test_noise_ratio_adds_the_variance_and_the_squared_bound():
    """detect's render_noise with both parts: V = jittered variance + (linearly jittered bound)^2, bin by bin."""
    from spad_detector import DetectorParams
    from spad_detector.model import build_model
    from spad_detector.render_noise import NoiseRatio

    p = DetectorParams(dark_count_rate_cps=0.0, jitter_ps=25.0).validate()
    model = build_model(p, bin_width_ps=1.0, n_bins=400, t0_ps=0.0)
    rng = np.random.default_rng(0)
    x = np.zeros((2, 400))
    x[:, 150:250] = rng.uniform(1e-4, 2e-3, size=(2, 100))
    var, bnd = 1e-9 * x, 3e-3 * x
    N = 10_000
    only_var, only_bound, both = NoiseRatio(), NoiseRatio(), NoiseRatio()
    only_var.add_spot(model, x, var, N, total_variance=var.sum(1))
    only_bound.add_spot(model, x, bnd, N, total_variance=bnd.sum(1), error_bound=True)
    both.add_spot(model, x, var, N, total_variance=var.sum(1), bound=bnd, total_bound=bnd.sum(1))
    parts = [only_var, only_bound, both]
    both = parts[2]
    assert both.var_sum == pytest.approx(parts[0].var_sum + parts[1].var_sum, rel=1e-12)
    assert both.total_var == pytest.approx(parts[0].total_var + parts[1].total_var, rel=1e-12)
    rep = both.report(spp=64, replicates=8, estimator="quadrature+monte_carlo")
    share = rep["parts"]["quadrature_error_bound"]["share_of_rendering_variance"]
    assert share == pytest.approx(parts[1].var_sum / both.var_sum, rel=1e-12)
    assert "error bound" in rep["definition"] and rep["spp"] == 64


def test_pipeline_states_both_errors_and_resumes(tmp_path):
    """render -D estimator=quadrature -D max_depth=6: variance/ (the remainder's, 8 replicates) and error_bound/
    (the quadrature's) per spot, the manifest's variance and error_bound blocks; detect combines both; a spot
    whose error-bound file is missing is rendered again by --resume, to the same bytes."""
    from spad_detector import detect_stack
    from transient_core import stack
    from transient_mi.render_capture import render

    d = dict(estimator="quadrature", max_depth="6", width="2", height="2", spots_x="2", spots_y="1", n_bins="128",
             bin_width_ps="64", spp="64", element_size_m="0.04", patch_cells="2", include_wall_return="false")
    a = render("scenes/nlos_letter.xml", tmp_path / "a", defines=d, progress=False)
    m = stack.read_manifest(a)
    assert m["render"]["estimator"] == "quadrature"
    v, b = m["variance"], m["error_bound"]
    assert v["directory"] == "variance" and v["replicates"] == 8 and v["part"] == "monte_carlo_remainder"
    assert "kind" not in v and not stack.is_error_bound(m) and stack.has_error_bound(m)
    assert b["kind"] == "error_bound" and b["directory"] == "error_bound" and b["part"] == "quadrature"
    assert v["summary"] is not None and b["summary"] is not None
    for j in range(m["n_files"]):
        var, tvar = stack.read_variance(a, j, m)
        bnd, tbnd = stack.read_error_bound(a, j, m)
        assert var.shape == bnd.shape == (2, 2, 128) and (var >= 0).all() and (bnd >= 0).all()
        assert float(tvar.sum()) > 0 and float(tbnd.sum()) > 0

    out = detect_stack(a, tmp_path / "counts", exposure_s=1e-3, seed=1)
    rn = json.loads((out / "manifest.json").read_text())["detector"]["resolved"]["render_noise"]
    assert rn["available"] and rn["estimator"] == "quadrature+monte_carlo"
    share = rn["parts"]["quadrature_error_bound"]["share_of_rendering_variance"]
    assert 0.0 < share < 1.0 and np.isfinite(rn["ratio"]) and rn["ratio"] > 0
    # the in-memory detection of the studies states the same combined ratio
    from spad_detector import DetectorParams
    from transient_mi.study.detection import Detection, IdealCapture

    mem = Detection(IdealCapture(a), DetectorParams(), exposure_s=1e-3).render_noise()
    assert mem["ratio"] == pytest.approx(rn["ratio"], rel=1e-9)
    assert mem["parts"]["quadrature_error_bound"]["share_of_rendering_variance"] == pytest.approx(share, rel=1e-9)

    # resume: spot 1's error bound lost -> the spot is incomplete and rendered again (same bytes)
    name = stack.spot_filename(1)
    before = {p: (a / p / name).read_bytes() for p in (".", "variance", "error_bound")}
    (a / "error_bound" / name).unlink()
    assert stack.spot_is_complete(a, 1, m) and not stack.variance_is_complete(a, 1, m)
    render("scenes/nlos_letter.xml", tmp_path / "a", defines=d, progress=False, resume=True)
    assert {p: (a / p / name).read_bytes() for p in before} == before
    # both summaries, from the arrays in memory (spot 1) and read back (spot 0), equal those of the files
    from transient_mi.capture_error import variance_summary

    m2 = stack.read_manifest(a)
    assert m2["variance"]["summary"] == variance_summary(a, m2) == v["summary"]
    assert m2["error_bound"]["summary"] == variance_summary(a, stack.error_bound_view(m2)) == b["summary"]


def test_max_depth_beyond_four_is_rendered_and_other_refusals_stay():
    from transient_mi.scene_io import load_scene

    s = load_scene("scenes/nlos_letter.xml", {"estimator": "quadrature", "max_depth": "-1", "width": "2",
                                              "height": "2", "spots_x": "1", "spots_y": "1", "n_bins": "64",
                                              "bin_width_ps": "128", "spp": "16", "element_size_m": "0.05"})
    s.integrator().variance_replicates = 8
    res = s.integrator().render_transient(s, s.sensors()[0], seed=0, spp=16, spot=0)
    assert res.error_bound is not None and res.variance is not None and res.replicates == 8
    s = load_scene("scenes/nlos_point_targets.xml", {"estimator": "quadrature", "max_depth": "6"})  # disks
    with pytest.raises(PluginParameterError, match="estimator=quadrature cannot render this capture: the hidden"):
        s.integrator().render_transient(s, s.sensors()[0], seed=0, spp=1, spot=0)
    s = nlos_scene(width=2, height=2, max_depth=6, laser_extra={"divergence_mrad": 20.0},
                   hidden=[_tilted((0.0, 0.0, 0.45), 0.2, 0.9, 0, "a")])
    s.integrator().nlos_options.update(estimator="quadrature")
    with pytest.raises(PluginParameterError, match="cannot render this capture: the laser beam diverges"):
        s.integrator().render_transient(s, s.sensors()[0], seed=0, spp=1, spot=0)


def test_confocal_remainder_agrees_with_monte_carlo():
    """A confocal capture (2 x 2 spots on the pixels' patches) of the two squares at max_depth=6: quadrature +
    remainder against plain Monte Carlo, pixel x window sums within ``t * sqrt(s_R^2 + s_MC^2) + bound`` (t of 7
    degrees of freedom, family-wise false-failure rate 1e-3, Bonferroni over the windows); the remainder alone is
    resolved (its total above ten standard errors)."""
    def render(seed, **opts):
        s = nlos_scene(width=2, height=2, footprint=0.1, capture="confocal", include_wall_return=True, n_bins=64,
                       bin_width_ps=128.0, t0_ps=9000.0, max_depth=6,
                       hidden=[_tilted((-0.12, 0.0, 0.45), 0.2, 0.9, -40, "a"),
                               _tilted((0.12, 0.0, 0.45), 0.2, 0.85, 40, "b")])
        integ = s.integrator()
        integ.variance_replicates = 8
        integ.nlos_options.update(opts)
        return integ.render_transient(s, s.sensors()[0], seed=seed, spp=SPP)

    q = render(1, estimator="quadrature", **Q)
    mc = render(3)
    d = _windows(q.histogram) - _windows(mc.histogram)
    se = np.sqrt(_windows(q.variance) + _windows(mc.variance))
    bound = _windows(q.error_bound)
    lit = se > 0
    assert lit.sum() >= 8
    tb = t_bound(8, ALPHA, int(lit.sum()))
    bad = np.abs(d[lit]) > tb * se[lit] + bound[lit]
    assert not bad.any(), (d[lit][bad], se[lit][bad], bound[lit][bad])
    assert q.estimator_info["remainder"] == "monte_carlo"
    # the deeper light the remainder adds is there and resolved
    r = render(1, skip_three_bounce=True)
    tot, tse = float(r.histogram.astype(np.float64).sum()), float(np.sqrt(r.total_variance.astype(np.float64).sum()))
    assert tot > 10 * tse > 0
