"""Derivatives of the deterministic three-bounce estimator (``estimator="quadrature"``,
transient_mi/integrators/_nlos_quadrature_ad.py, docs/quadrature.md, docs/differentiable.md).

Scenes: a 1 m relay wall, a 0.2 m Lambertian square 0.4 m in front of it, partly occluded (as seen from the
wall) by a 0.1 m square, 2 x 2 SPAD pixels, 128 bins of 50 ps with a 100 ps temporal kernel (so the kernel's
adjoint is exercised), coarse elements (4 cm, 2 x 2 cells, one refinement: a few seconds per render).

Tolerance: the quadrature is deterministic, so its central differences have no noise. The capture is
linear in a hidden reflectance and in the pulse energy, and quadratic in the wall's reflectance (it enters at
the patch point and at the laser spot), so a central difference is exact for all three; what is left is the
float32 rounding of the rendered histograms (relative 6e-8 per bin), divided by the relative step 1e-2: a
few 1e-6 of the gradient (measured: at most 5e-6). The tolerance is relative 1e-4.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

import transient_mi  # noqa: F401,E402  (before mitsuba/drjit)
import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

import nlos_helpers as nh  # noqa: E402
from ad_helpers import detach_all  # noqa: E402
from stats_helpers import ALPHA, mean_se, t_bound  # noqa: E402
from transient_core.units import C_M_PER_PS  # noqa: E402
from transient_mi.props import PluginParameterError  # noqa: E402

TARGET = (0.05, 0.02, 0.4)
REL_STEP = 1e-2
REL_TOL = 1e-4
KEYS = ("target.bsdf.reflectance.value", "relay_wall.bsdf.reflectance.value", "laser.pulse_energy_j")


def _scene(capture="array", occluder=True, element_size_m=0.04, integrator="transient_nlos_path"):
    hidden = [nh.square(TARGET, 0.2, 0.6, id_="target")]
    if occluder:
        hidden.append(nh.square((TARGET[0] + 0.08, TARGET[1], 0.3), 0.1, 0.3, id_="occluder"))
    orig = mi.load_dict

    def load(d, **kw):
        d["sensor"]["film"]["kernel_sigma_ps"] = 100.0
        return orig(d, **kw)

    mi.load_dict = load
    try:
        scene = nh.nlos_scene(hidden=hidden, n_bins=128, width=2, height=2, bin_width_ps=50.0, t0_ps=9000.0,
                              capture=capture, max_depth=4, integrator=integrator)
    finally:
        mi.load_dict = orig
    scene.integrator().nlos_options.update(estimator="quadrature", element_size_m=element_size_m, patch_cells=2,
                                           refine_levels=1)
    return scene


def _render(scene) -> np.ndarray:
    return np.asarray(mi.render(scene), dtype=np.float64)


def _weights(scene, shape):
    """Random loss weights ``w``, and ``w`` without the bins of the wall's own return (so the wall
    reflectance's three-bounce derivative is not hidden under the far larger wall return)."""
    w = np.random.default_rng(5).random(shape)
    setup = scene.sensors()[0].nlos_setup(scene)
    axis = scene.sensors()[0].film().time_axis()
    wr = setup.wall_return
    w3 = w.copy()
    spots = range(setup.n_spots) if setup.capture == "confocal" else [0]
    for j in spots:
        pix = int(wr["pixel"][j])
        if pix < 0:
            continue
        b = int(np.floor((float(wr["opl_m"][j]) / C_M_PER_PS - axis.t0_ps) / axis.bin_width_ps))
        w3[pix // setup.width, pix % setup.width, max(0, b - 8):b + 9] = 0.0
    return w.astype(np.float32), w3.astype(np.float32)


def _reverse(scene, params, key, x0, v0, w):
    """Reverse mode: the derivative of ``<w, capture>`` along ``key = x0 (1 + t)``, divided by ``v0``."""
    th = mi.Float(0.0)
    dr.enable_grad(th)
    params[key] = x0 * (1.0 + th)
    params.update()
    img = mi.render(scene, params)
    dr.backward(dr.sum(img * mi.TensorXf(w), axis=None))
    return float(dr.grad(th)[0]) / v0


def _derivatives(scene, params, key, x0, v0, w, w3):
    """Reverse mode (losses ``<w3, capture>`` and ``<w, capture>``) and forward mode (tangent image), along
    ``key = x0 (1 + t)``, divided by ``v0`` (so per unit of the parameter)."""
    rev = (_reverse(scene, params, key, x0, v0, w3), _reverse(scene, params, key, x0, v0, w))
    th = mi.Float(0.0)
    dr.enable_grad(th)
    params[key] = x0 * (1.0 + th)
    params.update()
    img = mi.render(scene, params)
    dr.forward(th)
    tangent = np.asarray(dr.grad(img), dtype=np.float64) / v0
    params[key] = type(x0)(x0)
    params.update()
    return rev, tangent


@pytest.mark.parametrize("capture", ["array", "confocal", "array, general BSDF path"])
def test_gradients_equal_central_differences(capture, monkeypatch):
    """Hidden reflectance, wall reflectance and pulse energy: reverse and forward mode on the loss without
    the wall return's bins and on the full one (which holds the wall return's derivative), against central
    differences of the quadrature's own primal. (Confocal: the two reflectances, whose terms depend on the
    pixel's own spot; the pulse energy scales every term alike, checked on the array capture.) "general BSDF
    path": the per-pair BSDF evaluations that BSDFs other than Lambertian take, forced on these Lambertian
    ones (``is_lambertian`` false), primal and derivatives alike."""
    if capture.endswith("general BSDF path"):
        import transient_mi.integrators._nlos_surfaces as surfaces

        monkeypatch.setattr(surfaces, "is_lambertian", lambda bsdf: False)
        capture = "array"
    scene = _scene(capture)
    params = mi.traverse(scene)
    img = _render(scene)
    w, w3 = _weights(scene, img.shape)
    for key in KEYS if capture == "array" else KEYS[:2]:
        kind = type(params[key])
        x0 = kind(dr.detach(params[key]))
        v0 = float(np.asarray(x0).ravel()[0])
        rev, tangent = _derivatives(scene, params, key, x0, v0, w, w3)
        imgs = []
        for s in (1, -1):
            params[key] = kind(v0 * (1 + s * REL_STEP))
            params.update()
            imgs.append(_render(scene))
        params[key] = x0
        params.update()
        fd = (imgs[0] - imgs[1]) / (2 * REL_STEP * v0)
        fd3, fd_full = float(np.sum(fd * w3)), float(np.sum(fd * w))
        assert fd3 != 0 and rev[0] == pytest.approx(fd3, rel=REL_TOL), (key, "reverse")
        assert rev[1] == pytest.approx(fd_full, rel=REL_TOL), (key, "reverse, wall return")
        assert float(np.sum(tangent * w3)) == pytest.approx(fd3, rel=REL_TOL), (key, "forward")
        assert float(np.sum(tangent * w)) == pytest.approx(fd_full, rel=REL_TOL), (key, "forward, wall return")
    detach_all(params)


def test_transient_path_under_a_spad_array_gives_the_same_gradient():
    """``transient_path`` under a ``spad_array`` dispatches to the same derivative (same bytes)."""
    out = []
    for integrator in ("transient_nlos_path", "transient_path"):
        scene = _scene(occluder=False, integrator=integrator)
        params = mi.traverse(scene)
        key = KEYS[0]
        x0 = type(params[key])(dr.detach(params[key]))
        w = np.random.default_rng(5).random((2, 2, 128)).astype(np.float32)
        out.append(_reverse(scene, params, key, x0, 1.0, w))
        detach_all(params)
    assert out[0] != 0 and out[0] == out[1]


def test_geometry_is_refused_in_one_line():
    """Forward mode differentiates no geometry (hidden shapes' and the relay wall's rigid motions, so no mannequin
    joints): refused, naming the parameter. Reverse mode differentiates hidden meshes' vertices
    (tests/test_nlos_quadrature_geometry.py) but not the relay wall's."""
    scene = _scene()
    w = mi.TensorXf(np.zeros((2, 2, 128), np.float32))
    for key in ("target.to_world", "relay_wall.to_world"):
        params = mi.traverse(scene)
        dr.enable_grad(params[key])
        calls = [(lambda: scene.integrator().render_forward(scene, params, scene.sensors()[0], 0, 1),
                  rf"{key} is being differentiated; estimator=quadrature's forward mode differentiates BSDF "
                  r"values and the laser's pulse_energy_j, not geometry")]
        if key.startswith("relay_wall"):
            calls.append((lambda: scene.integrator().render_backward(scene, params, w, scene.sensors()[0], 0, 1),
                          rf"{key} is being differentiated; estimator=quadrature cannot: the relay wall's geometry"))
        for call, msg in calls:
            with pytest.raises(PluginParameterError, match=msg) as e:
                call()
            assert "\n" not in str(e.value)
        detach_all(params)


def test_hidden_reflectance_gradient_agrees_with_monte_carlo():
    """The quadrature's gradient of the hidden reflectance against the Monte Carlo estimator's AD gradient
    (8 seeds x 128 spp, array capture without the occluder, loss without the wall return's bins). The capture
    is linear in the reflectance, so the gradient is the target's light divided by the reflectance and the
    quadrature's error is that of its capture: the bound is the Student-t quantile (rate ``ALPHA``) times the
    Monte Carlo standard error, plus the quadrature's stored error estimate weighted like the loss (5 % of the
    gradient at these coarse elements). Measured: 367.7 against 367.0 +- 2.9."""
    scene = _scene("array", occluder=False)
    params = mi.traverse(scene)
    key = KEYS[0]
    x0 = type(params[key])(dr.detach(params[key]))
    v0 = float(np.asarray(x0).ravel()[0])
    sensor = scene.sensors()[0]
    res = scene.integrator().render_transient(scene, sensor, seed=0, spp=1, spot=0)
    w, w3 = _weights(scene, np.asarray(res.histogram).shape)
    quad = _reverse(scene, params, key, x0, v0, w3)
    quad_err = float(np.sum(np.abs(w3) * np.asarray(res.error_bound, dtype=np.float64))) / v0
    assert quad_err < 0.1 * abs(quad)  # (measured: 5 %)
    scene.integrator().nlos_options.update(estimator="monte_carlo", hidden_geometry_prob=0.8)
    mc = []
    for seed in range(1, 9):
        th = mi.Float(0.0)
        dr.enable_grad(th)
        params[key] = x0 * (1.0 + th)
        params.update()
        img = mi.render(scene, params, seed=seed, spp=128)
        dr.backward(dr.sum(img * mi.TensorXf(w3), axis=None))
        mc.append(float(dr.grad(th)[0]) / v0)
    params[key] = x0
    params.update()
    m, se, n = mean_se(mc)
    print(f"quadrature {quad:.6g} +- {quad_err:.3g} (estimate), Monte Carlo {m:.6g} +- {se:.3g}")
    assert abs(quad - m) <= t_bound(n, ALPHA) * se + quad_err, (quad, m, se, quad_err)
    detach_all(params)
