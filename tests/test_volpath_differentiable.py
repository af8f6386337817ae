"""Differentiable ``transient_volpath`` (camera views through a homogeneous medium): Mitsuba's AD interfaces.

Reverse-mode gradients of ``sum(w * histogram)`` (``w`` fixed random weights per pixel and time bin) with
respect to the medium's ``sigma_t`` and ``albedo``, a surface reflectance lit through the medium and the
same reflectance in a scene where the surface is lit *only* by light scattered in the medium (its gradient
is all in the replay term: the derivative of the throughput of later contributions) agree with central
finite differences of the same renderer with common random numbers: AD over 8 seeds against finite
differences over 8 seeds, Welch t, false-failure rate 1e-3 for the four comparisons together (Bonferroni,
1e-3 / 4 each). Forward mode equals reverse mode on the same samples (deterministic: float rounding only).
Refusals are one line.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import transient_mi  # noqa: F401
import drjit as dr
import mitsuba as mi

from stats_helpers import ALPHA, t_bound, welch_df
from transient_mi.props import PluginParameterError

T = mi.ScalarTransform4f
W, H, NB = 8, 8, 100
SIGMA_T, ALBEDO, REFL = "fog.sigma_t.value.value", "fog.albedo.value.value", "plane.bsdf.reflectance.value"


def _scene(fog_only=False, max_depth=6):
    """Fog fills the scene (the sensor's medium); the camera looks at a diffuse plane; a square area light
    faces the plane (``fog_only=False``) or faces away from it (``True``: the plane and the camera get only
    light scattered in the fog)."""
    facing = [0.8, 0.0, 1.8] if fog_only else [0.8, 0.0, -1.0]
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "transient_volpath", "max_depth": max_depth},
        "fog": {"type": "homogeneous", "sigma_t": 0.8, "albedo": 0.8, "phase": {"type": "hg", "g": 0.3}},
        "sensor": {"type": "perspective", "fov": 30.0,
                   "to_world": T().look_at(origin=[0.0, 0.0, 2.0], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "transient_film", "width": W, "height": H, "n_bins": NB,
                            "bin_width_ps": 150.0, "t0_ps": 5000.0, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": 64},
                   "medium": {"type": "ref", "id": "fog"}},
        "light": {"type": "rectangle",
                  "to_world": T().look_at(origin=[0.8, 0.0, 0.8], target=facing, up=[0, 1, 0]) @ T().scale(0.25),
                  "emitter": {"type": "area", "radiance": {"type": "spectrum", "value": 20.0}}},
        "plane": {"type": "rectangle", "to_world": T().scale(3.0),
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "spectrum", "value": 0.6}}},
    })


def _weights():
    return mi.TensorXf(np.random.default_rng(0).random((H, W, NB)).astype(np.float32))


def _ad_gradient(scene, key, w, seed, spp):
    params = mi.traverse(scene)
    dr.enable_grad(params[key])
    params.update()
    img = mi.render(scene, params, seed=seed, spp=spp)
    dr.backward(dr.sum(img * w, axis=None))
    g = float(np.asarray(dr.grad(params[key])).ravel()[0])
    dr.disable_grad(params[key])
    params.update()
    return g


def _loss(scene, key, value, w, seed, spp):
    params = mi.traverse(scene)
    base = float(np.asarray(params[key]).ravel()[0])
    params[key] = value
    params.update()
    out = float(np.sum(np.asarray(mi.render(scene, seed=seed, spp=spp), dtype=np.float64) * np.asarray(w)))
    params[key] = base
    params.update()
    return out


def _welch(ad, fd, n_tests, what):
    """Welch t of the AD mean against the FD mean, at family-wise rate ``ALPHA`` over ``n_tests`` comparisons."""
    ad, fd = np.asarray(ad), np.asarray(fd)
    va, vb = ad.var(ddof=1), fd.var(ddof=1)
    se = math.sqrt(va / len(ad) + vb / len(fd))
    bound = t_bound(min(len(ad), len(fd)), ALPHA, n_tests, df=welch_df(va, len(ad), vb, len(fd)))
    assert abs(ad.mean()) > 10 * se, f"{what}: the gradient is not resolved ({ad.mean():.4g} +- {se:.3g})"
    assert abs(ad.mean() - fd.mean()) < bound * se, \
        f"{what}: AD {ad.mean():.4g} vs FD {fd.mean():.4g} +- {se:.3g} (bound {bound:.2f} se)"


N_COMPARISONS = 5  # four here, one in the heterogeneous test


@pytest.mark.parametrize("fog_only,key", [(False, SIGMA_T), (False, ALBEDO), (False, REFL), (True, REFL)],
                         ids=["sigma_t", "albedo", "reflectance", "reflectance_lit_only_through_the_fog"])
def test_reverse_mode_gradients_agree_with_finite_differences(fog_only, key):
    """``sigma_t``: its derivative is mostly in the transmittance of the shadow rays (without their replay the
    gradient is -2.30 instead of -5.57 here: the test fails); ``fog_only``: the plane's reflectance reaches
    the loss only through the throughput of contributions made later on the path (fog vertices' next-event
    estimation), the replay term."""
    scene, w = _scene(fog_only), _weights()
    x0 = float(np.asarray(mi.traverse(scene)[key]).ravel()[0])
    h = 0.02 * x0
    ad = [_ad_gradient(scene, key, w, seed=10 + s, spp=256) for s in range(8)]
    fd = [(_loss(scene, key, x0 + h, w, 100 + s, 2048) - _loss(scene, key, x0 - h, w, 100 + s, 2048)) / (2 * h)
          for s in range(8)]
    _welch(ad, fd, N_COMPARISONS, key)


def test_heterogeneous_grid_values_agree_with_finite_differences():
    """Null scattering and ratio tracking: the gradient with respect to the density grid, projected on the
    grid's own values (maximum voxel left out: the majorant stays fixed, so finite differences keep common
    random numbers), against central differences along that direction."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from test_transient_volpath import _cube_scene, _tfilm

    scene = _cube_scene({"type": "transient_volpath", "max_depth": 6}, _tfilm(W, H, NB, 150.0, 5000.0), 64,
                        medium="heterogeneous")
    w, key = _weights(), "smoke.sigma_t.data"
    g0 = np.asarray(mi.traverse(scene)[key]).copy()
    v = g0.copy().ravel()
    v[np.argmax(v)] = 0
    v = v.reshape(g0.shape)

    def ad(seed):
        params = mi.traverse(scene)
        dr.enable_grad(params[key])
        params.update()
        img = mi.render(scene, params, seed=seed, spp=256)
        dr.backward(dr.sum(img * w, axis=None))
        g = np.asarray(dr.grad(params[key]), dtype=np.float64)
        dr.disable_grad(params[key])
        params.update()
        return float(np.sum(g * v))

    def loss(eps, seed):
        params = mi.traverse(scene)
        params[key] = mi.TensorXf((g0 + eps * v).astype(np.float32))
        params.update()
        out = float(np.sum(np.asarray(mi.render(scene, seed=seed, spp=2048), dtype=np.float64) * np.asarray(w)))
        params[key] = mi.TensorXf(g0.astype(np.float32))
        params.update()
        return out

    h = 0.05
    _welch([ad(10 + s) for s in range(8)], [(loss(h, 100 + s) - loss(-h, 100 + s)) / (2 * h) for s in range(8)],
           N_COMPARISONS, key)


def test_forward_mode_equals_reverse_mode():
    """Same seed, same samples: ``<w, dh/dtheta>`` from forward mode equals the reverse-mode gradient for the
    medium's coefficients, its phase function's ``g``, the reflectance and the emitter's radiance."""
    scene, w = _scene(), _weights()
    for key in (SIGMA_T, ALBEDO, "fog.phase_function.g", REFL, "light.emitter.radiance.value"):
        rev = _ad_gradient(scene, key, w, seed=3, spp=64)
        params = mi.traverse(scene)
        dr.enable_grad(params[key])
        params.update()
        img = mi.render(scene, params, seed=3, spp=64)
        dr.forward(params[key])
        fwd = float(np.sum(np.asarray(dr.grad(img), dtype=np.float64) * np.asarray(w)))
        dr.disable_grad(params[key])
        params.update()
        assert rev != 0 and fwd == pytest.approx(rev, rel=1e-4), key


def test_geometry_is_refused_in_one_line():
    scene = _scene()
    params = mi.traverse(scene)
    dr.enable_grad(params["plane.to_world"])
    with pytest.raises(PluginParameterError) as e:
        scene.integrator().render_backward(scene, params, mi.TensorXf(np.zeros((H, W, NB), np.float32)),
                                           scene.sensors()[0], 1, 4)
    msg = str(e.value)
    assert "\n" not in msg and "plane.to_world is differentiated; derivatives with respect to geometry are not " \
                              "supported in media" in msg
    with pytest.raises(PluginParameterError, match="plane.to_world is differentiated"):
        scene.integrator().render_forward(scene, params, scene.sensors()[0], 1, 4)
