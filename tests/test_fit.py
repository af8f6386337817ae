"""Inverse NLOS (transient_mi.fit, `transient-mi fit`): the forward model, the size derivative, a fit that
recovers a tilted square, resume and the refusals.

The capture: `scenes/nlos_tilted_plane.xml` (a 40 cm square 50 cm behind the wall, turned 30 degrees about
the vertical), an 8 x 8 array of 1 cm pixels behind a 2 mm aperture (about 2 % detection probability per cycle: low pile-up), 2 x 2 laser spots, the paper's detector for 10 ms per spot.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import transient_mi  # noqa: F401  (before mitsuba/drjit)
from transient_core.errors import UserInputError
from transient_mi.fit import FitSettings, PatchesModel, fit_capture
from transient_mi.fit.capture_model import FIT_QUADRATURE, CaptureModel

ROOT = Path(__file__).resolve().parents[1]
TRUTH = {"x_m": 0.0, "y_m": 0.0, "z_m": 0.5, "yaw_deg": 30.0, "pitch_deg": 0.0}


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    from spad_detector import detect_stack
    from transient_mi.paper import paper_detector
    from transient_mi.render_capture import render
    from transient_mi.scenes import scene_path

    d = tmp_path_factory.mktemp("fitcap")
    ideal = render(scene_path("nlos_tilted_plane"), d / "ideal", spp=256, progress=False,
                   defines={"width": "8", "height": "8", "spots_x": "2", "spots_y": "2", "spot_spacing_m": "0.3",
                            "pixel_footprint_m": "0.01", "aperture_diameter_m": "0.002", "n_bins": "400", "bin_width_ps": "16", "t0_ps": "9000",
                            "estimator": "monte_carlo"})
    return detect_stack(ideal, d / "counts", paper_detector(), exposure_s=0.01, seed=0, progress=False)


def _truth_theta(model: PatchesModel) -> np.ndarray:
    return np.array([TRUTH[n.split("_", 1)[1]] for n in model.names[:-1]] + [0.8])


def test_the_model_at_the_truth_reproduces_the_counts(capture):
    """The square at its true place, through the capture's detector, predicts the detected counts: totals
    within 3 % (the remaining dead-time effect and the 256-spp render's noise; a 5 cm shift changes
    them by more)."""
    model = PatchesModel(1, 0.4)
    cap = CaptureModel(capture, model.faces, model.n_vertices, bin_width_ps=16.0)
    theta = _truth_theta(model)
    cap.set_mesh(model.vertices(theta), model.albedo(theta))
    mu = cap.expected_counts(cap.ideal(5, 256, cap.jitter_sigma_ps))
    assert abs(mu.sum() / cap.counts.sum() - 1.0) < 0.03
    obj_true, _ = cap.objective(mu, cap.jitter_sigma_ps)
    moved = theta.copy()
    moved[2] += 0.05
    cap.set_mesh(model.vertices(moved), model.albedo(moved))
    obj_moved, _ = cap.objective(cap.expected_counts(cap.ideal(5, 256, cap.jitter_sigma_ps)), cap.jitter_sigma_ps)
    assert obj_moved > 2 * obj_true


def test_size_derivative_includes_the_hidden_area(capture):
    """d(sum w . capture)/d(height) of the mannequin: the renderer's vertex derivative plus the area term
    (2 rho / s) dL/drho equals central differences with common random numbers (same seed: a sample keeps its
    triangle and barycentric coordinates under a uniform scale); without the area term it does not.
    Deterministic at fixed samples up to float rounding and the box bins' finite-difference error: 2 %."""
    from transient_mi.fit import MannequinModel

    model = MannequinModel(detail=8)
    cap = CaptureModel(capture, model.faces, model.n_vertices, bin_width_ps=16.0)
    theta = model.initial((0.05, 0.0, 0.45), height_m=0.4, width_m=0.34)  # small: it hides no wall patch
    rng = np.random.default_rng(1)
    w = rng.uniform(0.5, 1.5, size=(cap.n_spots, cap.width * cap.height, cap.n_bins))
    sigma = 80.0
    seed, spp = 3, 64

    def loss(th):
        cap.set_mesh(model.vertices(th), model.albedo(th))
        return float(np.sum(w * cap.ideal(seed, spp, sigma)))

    cap.set_mesh(model.vertices(theta), model.albedo(theta))
    cap.ideal(seed, spp, sigma)  # the primal first: it builds the sensor's scene analysis the adjoint reads
    # the gradient of <w, ideal>: pass w through the detector layer's adjoint as the identity
    from transient_mi.integrators._nlos_ad import nlos_backward
    import drjit as dr

    v, r = cap.params[cap.vkey], cap.params[cap.rkey]
    dr.enable_grad(v)
    dr.enable_grad(r)
    cap.params.update()
    nlos_backward(cap.integrator, cap.scene, cap.params, w.reshape(cap.n_spots, cap.height, cap.width, -1)
                  .astype(np.float32), cap.sensor, seed, spp, spots=cap.spots)
    gv = np.asarray(dr.grad(cap.params[cap.vkey]), dtype=np.float64).reshape(-1, 3)
    ga = float(np.sum(np.asarray(dr.grad(cap.params[cap.rkey]))))
    dr.disable_grad(cap.params[cap.vkey])
    dr.disable_grad(cap.params[cap.rkey])
    cap.params[cap.vkey] = dr.detach(cap.params[cap.vkey])
    cap.params[cap.rkey] = dr.detach(cap.params[cap.rkey])
    cap.params.update()
    g = model.gradient(theta, gv, ga)
    k = model.names.index("height_m")
    h = 0.005
    tp, tm = theta.copy(), theta.copy()
    tp[k] += h
    tm[k] -= h
    fd = (loss(tp) - loss(tm)) / (2 * h)
    area_term = 2.0 * theta[-1] / theta[k] * ga
    assert abs(g[k] - fd) < 0.02 * abs(fd), (g[k], fd)
    assert abs(g[k] - area_term - fd) > 0.1 * abs(fd)  # the vertex motion alone misses the area


def test_fit_recovers_the_tilted_square(capture, tmp_path):
    """`--model patches --estimator monte_carlo` (Adam) with one 40 cm patch, started from the backprojection facing the wall, finds the
    square's turn within 5 degrees and its centre within 2.5 cm in 150 iterations (8 x 8 pixels: the
    centre's position along the square's own plane is the least determined)."""
    res = fit_capture(capture, tmp_path / "fit", model="patches", n_patches=1, patch_side_m=0.4,
                      bin_width_ps=16.0, settings=FitSettings(iterations=150, spp=16, sigma_start_ps=150.0,
                                                              estimator="monte_carlo"), progress=False,
                      log=lambda *a: None)
    assert res["optimizer"]["used"] == "adam" and res["estimator"]["used"] == "monte_carlo"
    fit = res["parameters"]["fit"]
    start = res["parameters"]["start"]
    err = math.dist([fit["patch0_x_m"], fit["patch0_y_m"], fit["patch0_z_m"]], [0.0, 0.0, 0.5])
    assert err < 0.025, fit
    assert abs(fit["patch0_yaw_deg"] - 30.0) < 5.0 and abs(fit["patch0_pitch_deg"]) < 5.0, fit
    assert abs(start["patch0_yaw_deg"]) < 1e-9  # it started facing the wall: the turn was found
    assert res["poisson_nll"]["fit"] < res["poisson_nll"]["start"]
    out = tmp_path / "fit"
    for name in ("fit.json", "fitted.ply", "loss.png", "fit.png", "checkpoint.json"):
        assert (out / name).is_file(), name
    assert json.loads((out / "fit.json").read_text())["status"] == "complete"
    m = res["metrics"]
    assert m["fit"]["chamfer_mesh_m"] < 0.01  # the fitted square lies on the true one


def test_resume_continues_from_the_checkpoint(capture, tmp_path):
    out = tmp_path / "fit"
    kw = dict(model="patches", n_patches=1, patch_side_m=0.4, bin_width_ps=16.0, progress=False,
              log=lambda *a: None)
    fit_capture(capture, out, settings=FitSettings(iterations=4, checkpoint_every=2), **kw)
    state = json.loads((out / "checkpoint.json").read_text())
    assert state["iteration"] == 4 and len(state["history"]) == 4
    res = fit_capture(capture, out, settings=FitSettings(iterations=4, checkpoint_every=2), resume=True, **kw)
    assert len(res["history"]["objective"]) == 4  # nothing left to do: the checkpoint was complete
    with pytest.raises(UserInputError, match="other settings"):
        fit_capture(capture, out, settings=FitSettings(iterations=6, checkpoint_every=2), resume=True, **kw)


@pytest.mark.parametrize("args,words", [
    (["--model", "robot"], ["--model", "robot", "mannequin, patches"]),
    (["--bin-width-ps", "20"], ["bin_width_ps=20", "whole multiple", "16"]),
    (["--patches", "0", "--model", "patches"], ["n_patches=0", "1 to 16"]),
])
def test_cli_bad_input_is_one_line_and_writes_nothing(capture, tmp_path, args, words):
    out = tmp_path / "fit"
    r = subprocess.run([sys.executable, "-m", "transient_mi", "fit", str(capture), "-o", str(out), *args],
                       capture_output=True, text=True, cwd=ROOT)
    assert r.returncode != 0
    lines = [ln for ln in r.stderr.strip().splitlines() if ln]
    assert len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert all(w in lines[0] for w in words), lines[0]
    assert not out.exists() or not any(out.iterdir())


def test_an_ideal_capture_is_refused(capture, tmp_path):
    with pytest.raises(UserInputError, match="counts capture"):
        fit_capture(Path(capture).parent / "ideal", tmp_path / "fit", progress=False)


def test_a_full_output_directory_is_refused(capture, tmp_path):
    out = tmp_path / "fit"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    with pytest.raises(UserInputError, match="not empty"):
        fit_capture(capture, out, model="patches", n_patches=1, progress=False)
    with pytest.raises(UserInputError, match="earlier fit only"):
        fit_capture(capture, out, model="patches", n_patches=1, overwrite=True, progress=False)
    assert (out / "notes.txt").read_text() == "mine"


def test_quadrature_forward_model_gradient_equals_central_differences(capture):
    """``estimator="quadrature"`` with the models' fits' settings (one cell per patch, the fine level only): the
    deterministic forward model's gradient of ``<w, ideal>`` (all four spots in one backward pass) with respect to the patch's depth and turn, chained through the model (no area term: the
    quadrature's vertex gradient holds the area's change), against central differences of its own renders;
    the same inputs give the same bytes. Deterministic: tolerance relative 1e-3 (float32 histograms over steps
    of 1 mm and 0.2 degrees; measured below 1e-4)."""
    import drjit as dr

    from transient_mi.integrators._nlos_quadrature_ad import quadrature_backward

    model = PatchesModel(1, 0.4)
    cap = CaptureModel(capture, model.faces, model.n_vertices, bin_width_ps=16.0, estimator="quadrature",
                       element_size_m=0.1, **FIT_QUADRATURE)
    assert cap.estimator == "quadrature" and cap.estimator_reason is None
    theta = _truth_theta(model)
    w = np.random.default_rng(1).uniform(0.5, 1.5, size=(cap.n_spots, cap.width * cap.height, cap.n_bins))

    def loss(th):
        cap.set_mesh(model.vertices(th), model.albedo(th))
        return float(np.sum(w * cap.ideal(0, 0, 80.0)))

    cap.set_mesh(model.vertices(theta), model.albedo(theta))
    first = cap.ideal(0, 0, 80.0)
    assert np.array_equal(first, cap.ideal(0, 0, 80.0))
    v = cap.params[cap.vkey]
    dr.enable_grad(v)
    cap.params.update()
    quadrature_backward(cap.integrator, cap.scene, cap.params, w.reshape(cap.n_spots, cap.height, cap.width, -1),
                        cap.sensor, spots=cap.spots)
    gv = np.asarray(dr.grad(cap.params[cap.vkey]), dtype=np.float64).reshape(-1, 3)
    dr.disable_grad(cap.params[cap.vkey])
    cap.params[cap.vkey] = dr.detach(cap.params[cap.vkey])
    cap.params.update()
    g = model.gradient(theta, gv, 0.0, area_term=False)
    for name, h in (("patch0_z_m", 1e-3), ("patch0_yaw_deg", 0.2)):
        k = model.names.index(name)
        tp, tm = theta.copy(), theta.copy()
        tp[k] += h
        tm[k] -= h
        fd = (loss(tp) - loss(tm)) / (2 * h)
        assert fd != 0 and abs(g[k] - fd) < 1e-3 * abs(fd), (name, g[k], fd)


def test_quadrature_fit_is_reproducible(capture):
    """Two runs of the optimiser on the quadrature's forward model give the same parameters and objectives, bit
    for bit (``auto`` picks the quadrature for this scene: meshes, a planar wall)."""
    from transient_mi.fit.optimize import FitState, run_adam

    model = PatchesModel(1, 0.4)
    cap = CaptureModel(capture, model.faces, model.n_vertices, bin_width_ps=16.0, estimator="auto",
                       element_size_m=0.1, **FIT_QUADRATURE)
    assert cap.estimator == "quadrature"
    theta = _truth_theta(model) + np.array([0.02, -0.01, 0.03, -5.0, 3.0, 0.0])
    runs = []
    for _ in range(2):
        state = run_adam(model, cap, FitState(theta=theta.tolist()),
                         FitSettings(iterations=2, estimator="quadrature", element_size_m=0.1, sigma_start_ps=150.0))
        runs.append((state.theta, [h[0] for h in state.history], [h[3] for h in state.history]))
    assert runs[0] == runs[1] and runs[0][0] != theta.tolist()


def test_monte_carlo_forward_model_of_a_quadrature_capture_samples(capture, tmp_path):
    """``estimator="monte_carlo"`` renders by Monte Carlo even when the capture's own scene was rendered by the
    quadrature (the paper scene's default, so the demo's captures): two seeds give different renders (a quadrature
    render would repeat its bytes), and the quadrature's per-call options are not set."""
    import shutil

    d = tmp_path / "counts"
    shutil.copytree(capture, d)
    m = json.loads((d / "manifest.json").read_text())
    m["render"]["defines"]["estimator"] = "quadrature"
    (d / "manifest.json").write_text(json.dumps(m))
    model = PatchesModel(1, 0.4)
    cap = CaptureModel(d, model.faces, model.n_vertices, bin_width_ps=16.0, estimator="monte_carlo")
    assert cap.estimator == "monte_carlo" and cap.integrator.nlos_options["estimator"] == "monte_carlo"
    theta = _truth_theta(model)
    cap.set_mesh(model.vertices(theta), model.albedo(theta))
    a, b = cap.ideal(1, 4, 80.0), cap.ideal(2, 4, 80.0)
    assert a.sum() > 0 and not np.array_equal(a, b)


def test_gauss_newton_fit_recovers_the_tilted_square(capture, tmp_path):
    """The defaults (the quadrature and Gauss-Newton, 16 iterations) with one 40 cm patch started facing the wall:
    the same tolerances as Adam's 150 Monte Carlo iterations above; each iteration's objective is no higher than the
    last at the same blur (a step is taken only when it lowers the objective)."""
    res = fit_capture(capture, tmp_path / "fit", model="patches", n_patches=1, patch_side_m=0.4, bin_width_ps=16.0,
                      settings=FitSettings(sigma_start_ps=150.0), progress=False, log=lambda *a: None)
    assert res["optimizer"] == {"requested": "auto", "used": "gauss_newton", "iterations": 16, "detail": None,
                                "pixel_step": 1, "pixels_used": [8, 8]}
    assert res["estimator"]["used"] == "quadrature"
    fit = res["parameters"]["fit"]
    err = math.dist([fit["patch0_x_m"], fit["patch0_y_m"], fit["patch0_z_m"]], [0.0, 0.0, 0.5])
    assert err < 0.025, fit
    assert abs(fit["patch0_yaw_deg"] - 30.0) < 5.0 and abs(fit["patch0_pitch_deg"]) < 5.0, fit
    assert res["poisson_nll"]["fit"] < res["poisson_nll"]["start"]
    assert res["metrics"]["fit"]["chamfer_mesh_m"] < 0.01
    h = res["history"]
    for a, b, sa, sb in zip(h["objective"], h["objective"][1:], h["sigma_ps"], h["sigma_ps"][1:]):
        assert sa != sb or b <= a


def test_gauss_newton_steps_are_deterministic_and_the_blur_falls(capture):
    """Two Gauss-Newton runs from the same start give the same parameters bit for bit; the stages' blurs fall
    from the start's to the end's."""
    from transient_mi.fit.gauss_newton import run_gauss_newton, stages
    from transient_mi.fit.optimize import FitState

    assert [round(s) for _, s in stages(16, 250.0, 30.0)] == [250, 87, 30]
    assert [i for i, _ in stages(16, 250.0, 30.0)] == [0, 8, 14]
    assert stages(2, 250.0, 30.0) == [(0, 30.0)]
    model = PatchesModel(1, 0.4)
    theta0 = np.array([0.02, -0.02, 0.52, 10.0, 0.0, 0.8])
    out = []
    for _ in range(2):
        cap = CaptureModel(capture, model.faces, model.n_vertices, bin_width_ps=16.0, estimator="quadrature",
                           **FIT_QUADRATURE)
        st = run_gauss_newton(model, cap, FitState(theta=theta0.tolist()), FitSettings(sigma_start_ps=150.0), 3)
        out.append(st.theta)
    assert out[0] == out[1] and out[0] != theta0.tolist()


def test_every_other_pixel_is_the_capture_s_own(capture):
    """``pixel_step=2``: the counts of pixels (1, 3, 5, 7) along each axis exactly, and a render of those pixels
    equal to the full render's at them to the quadrature's discretisation (its elements are split where a rendered
    pixel sees them partly hidden, so a pixel set can change another pixel's elements: 0.5 % of a pixel's light
    allowed; the scene here has no occluder and agrees far closer)."""
    model = PatchesModel(1, 0.4)
    theta = np.array([0.0, 0.0, 0.5, 30.0, 0.0, 0.8])
    caps = [CaptureModel(capture, model.faces, model.n_vertices, bin_width_ps=16.0, estimator="quadrature",
                         pixel_step=s, **FIT_QUADRATURE) for s in (1, 2)]
    full, half = caps
    assert (half.width, half.height, half.pixel_offset) == (4, 4, 0)
    G, T = full.n_spots, full.n_bins
    keep = full.counts.reshape(G, 8, 8, T)[:, 0::2, 0::2].reshape(G, 16, T)
    np.testing.assert_array_equal(half.counts, keep)
    renders = []
    for c in caps:
        c.set_mesh(model.vertices(theta), 0.8)
        renders.append(c.ideal(0, 1, c.jitter_sigma_ps))
    sub = renders[0].reshape(G, 8, 8, T)[:, 0::2, 0::2].reshape(G, 16, T)
    assert sub.sum() > 0
    rel = np.abs(renders[1] - sub).sum(axis=-1) / sub.sum(axis=-1)
    assert rel.max() < 5e-3, rel.max()
    with pytest.raises(ValueError, match="pixel_step=3"):
        CaptureModel(capture, model.faces, model.n_vertices, bin_width_ps=16.0, estimator="quadrature",
                     pixel_step=3, **FIT_QUADRATURE)


def test_gauss_newton_needs_the_deterministic_forward_model(capture, tmp_path):
    with pytest.raises(UserInputError, match="optimizer=gauss_newton needs the deterministic"):
        fit_capture(capture, tmp_path / "fit", model="patches", n_patches=1, progress=False,
                    settings=FitSettings(optimizer="gauss_newton", estimator="monte_carlo"))
    with pytest.raises(UserInputError, match="optimizer='newton'"):
        fit_capture(capture, tmp_path / "fit", model="patches", n_patches=1, progress=False,
                    settings=FitSettings(optimizer="newton"))
    assert not (tmp_path / "fit").exists() or not any((tmp_path / "fit").iterdir())


def test_every_other_pixel_of_a_confocal_capture_keeps_its_own_laser_spots(tmp_path):
    """Confocal: the laser is aimed at each pixel's own patch, so the pixels kept by ``pixel_step=2`` keep their
    spots; the render of those pixels equals the full confocal render at them (0.5 % of a pixel's light, as above)."""
    from spad_detector import detect_stack
    from transient_mi.paper import paper_detector
    from transient_mi.render_capture import render
    from transient_mi.scenes import scene_path

    ideal = render(scene_path("nlos_tilted_plane"), tmp_path / "ideal", spp=64, progress=False,
                   defines={"width": "8", "height": "8", "capture": "confocal", "pixel_footprint_m": "0.01",
                            "aperture_diameter_m": "0.002", "n_bins": "400", "bin_width_ps": "16", "t0_ps": "9000",
                            "estimator": "monte_carlo"})
    counts = detect_stack(ideal, tmp_path / "counts", paper_detector(), exposure_s=0.01, seed=0, progress=False)
    model = PatchesModel(1, 0.4)
    theta = np.array([0.0, 0.0, 0.5, 30.0, 0.0, 0.8])
    caps = [CaptureModel(counts, model.faces, model.n_vertices, bin_width_ps=16.0, estimator="quadrature",
                         pixel_step=s, **FIT_QUADRATURE) for s in (1, 2)]
    renders = []
    for c in caps:
        c.set_mesh(model.vertices(theta), 0.8)
        renders.append(c.ideal(0, 1, c.jitter_sigma_ps))
    T = caps[0].n_bins
    sub = renders[0].reshape(1, 8, 8, T)[:, 0::2, 0::2].reshape(1, 16, T)
    np.testing.assert_array_equal(caps[1].counts, caps[0].counts.reshape(1, 8, 8, T)[:, 0::2, 0::2].reshape(1, 16, T))
    assert sub.sum() > 0 and renders[1].shape == (1, 16, T)
    rel = np.abs(renders[1] - sub).sum(axis=-1) / sub.sum(axis=-1)
    assert rel.max() < 5e-3, rel.max()
