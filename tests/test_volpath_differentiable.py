"""Differentiable ``transient_volpath`` (camera views through participating media): Mitsuba's AD interfaces.

Reverse-mode gradients of ``sum(w * histogram)`` (``w`` fixed random weights per pixel and time bin) in fog
filling the scene, with respect to the medium's ``sigma_t`` and ``albedo``, a surface reflectance lit
through the medium and the same reflectance in a scene where the surface is lit *only* by light scattered
in the medium (its gradient is all in the replay term: the derivative of the throughput of later
contributions), and a heterogeneous medium's grid values along one direction (the maximum voxel left out so
that the majorant, and with it the delta-tracking sampling, stays fixed) agree with central finite
differences of the same renderer with common random numbers: AD over 8 seeds against finite differences
over 8 seeds, Welch t, false-failure rate 1e-3 for the five comparisons together (Bonferroni, 2e-4 each).
Forward mode equals reverse mode on the same samples (deterministic: float rounding only), in the fog and in
a heterogeneous medium. RGB variants (a subprocess): spectrally varying extinction, forward equals reverse
and two gradients agree with central differences (false-failure rate 1e-3 for the two). Refusals are one
line.
"""

from __future__ import annotations


import numpy as np
import pytest

import transient_mi  # noqa: F401
import drjit as dr
import mitsuba as mi

from ad_helpers import assert_welch, loss_at, reverse_gradient
from transient_mi.props import PluginParameterError

T = mi.ScalarTransform4f
W, H, NB = 8, 8, 100
SIGMA_T, ALBEDO, REFL = "fog.sigma_t.value.value", "fog.albedo.value.value", "plane.bsdf.reflectance.value"


def _scene(fog_only=False, max_depth=6, rgb=False, kernel_sigma_ps=0.0):
    """Fog fills the scene (the sensor's medium); the camera looks at a diffuse plane; a square area light
    faces the plane (``fog_only=False``) or faces away from it (``True``: the plane and the camera get only
    light scattered in the fog). ``rgb`` (RGB variants): extinction and albedo varying per channel (one
    channel sampled per path for the free flights)."""
    facing = [0.8, 0.0, 1.8] if fog_only else [0.8, 0.0, -1.0]
    fog = {"type": "homogeneous", "sigma_t": 0.8, "albedo": 0.8, "phase": {"type": "hg", "g": 0.3}}
    if rgb:
        fog.update({"scale": 1.2, "sigma_t": {"type": "rgb", "value": [0.33, 0.67, 1.0]},
                    "albedo": {"type": "rgb", "value": [0.9, 0.7, 0.5]}})
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "transient_volpath", "max_depth": max_depth},
        "fog": fog,
        "sensor": {"type": "perspective", "fov": 30.0,
                   "to_world": T().look_at(origin=[0.0, 0.0, 2.0], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "transient_film", "width": W, "height": H, "n_bins": NB,
                            "bin_width_ps": 150.0, "t0_ps": 5000.0, "rfilter": {"type": "box"},
                            "kernel_sigma_ps": kernel_sigma_ps},
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
    ad = [reverse_gradient(scene, key, w, seed=10 + s, spp=256) for s in range(8)]
    fd = [(loss_at(scene, key, x0 + h, w, 100 + s, 2048) - loss_at(scene, key, x0 - h, w, 100 + s, 2048)) / (2 * h)
          for s in range(8)]
    assert_welch(ad, fd, N_COMPARISONS, key)


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
    assert_welch([ad(10 + s) for s in range(8)], [(loss(h, 100 + s) - loss(-h, 100 + s)) / (2 * h) for s in range(8)],
           N_COMPARISONS, key)


@pytest.mark.parametrize("kernel_sigma_ps", [0.0, 200.0])
def test_forward_mode_equals_reverse_mode(kernel_sigma_ps):
    """Same seed, same samples: ``<w, dh/dtheta>`` from forward mode equals the reverse-mode gradient for the
    medium's coefficients, its phase function's ``g`` (checked only here), the reflectance and the emitter's
    radiance; with a temporal kernel the adjoint goes through the kernel's taps."""
    scene, w = _scene(kernel_sigma_ps=kernel_sigma_ps), _weights()
    for key in (SIGMA_T, ALBEDO, "fog.phase_function.g", REFL, "light.emitter.radiance.value"):
        rev = reverse_gradient(scene, key, w, seed=3, spp=64)
        params = mi.traverse(scene)
        dr.enable_grad(params[key])
        params.update()
        img = mi.render(scene, params, seed=3, spp=64)
        dr.forward(params[key])
        fwd = float(np.sum(np.asarray(dr.grad(img), dtype=np.float64) * np.asarray(w)))
        dr.disable_grad(params[key])
        params.update()
        assert rev != 0 and fwd == pytest.approx(rev, rel=1e-4), key


def test_forward_mode_equals_reverse_mode_in_a_heterogeneous_medium():
    """Null scattering and ratio tracking: the grid values along a random direction, the albedo and the
    floor's reflectance (a medium inside a ``null``-BSDF cube: transitions on camera paths and shadow rays)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from test_transient_volpath import _cube_scene, _tfilm

    scene = _cube_scene({"type": "transient_volpath", "max_depth": 6}, _tfilm(W, H, NB, 150.0, 5000.0), 64,
                        medium="heterogeneous")
    w = _weights()
    for key in ("smoke.sigma_t.data", "smoke.albedo.value.value", "floor.bsdf.reflectance.value"):
        params = mi.traverse(scene)
        v = np.random.default_rng(1).random(np.asarray(params[key]).shape).astype(np.float32)
        dr.enable_grad(params[key])
        params.update()
        img = mi.render(scene, params, seed=3, spp=64)
        dr.backward(dr.sum(img * w, axis=None))
        rev = float(np.sum(np.asarray(dr.grad(params[key]), dtype=np.float64) * v))
        dr.disable_grad(params[key])
        params.update()
        params = mi.traverse(scene)
        dr.enable_grad(params[key])
        params.update()
        img = mi.render(scene, params, seed=3, spp=64)
        dr.set_grad(params[key], mi.TensorXf(v) if key.endswith(".data") else float(v.ravel()[0]))
        dr.enqueue(dr.ADMode.Forward, params[key])
        dr.traverse(dr.ADMode.Forward)
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


_RGB_SCRIPT = r"""
import json, sys
sys.path.insert(0, {tests!r})
import numpy as np
import transient_mi  # noqa: F401
import drjit as dr
import mitsuba as mi
import test_volpath_differentiable as t
from ad_helpers import color_direction_gradient, color_direction_loss

scene = t._scene(rgb=True)
w = mi.TensorXf(np.random.default_rng(0).random((t.H, t.W, t.NB, 3)).astype(np.float32))
out = {{}}
for key, d in ((t.SIGMA_T, (1.0, 0.0, 0.0)), (t.ALBEDO, (0.0, 1.0, 0.0))):
    params = mi.traverse(scene)
    x0 = mi.Color3f(params[key])
    def grad(seed, mode, spp):  # along one channel of the coefficient
        return color_direction_gradient(scene, params, key, x0, d, w, seed, mode, spp)
    def loss(c, seed):
        return color_direction_loss(scene, params, key, x0, d, c, w, seed, 2048)
    h = 0.02
    out[key] = {{"reverse": grad(3, "reverse", 64), "forward": grad(3, "forward", 64),
                "ad": [grad(10 + s, "reverse", 256) for s in range(8)],
                "fd": [(loss(h, 100 + s) - loss(-h, 100 + s)) / (2 * h) for s in range(8)]}}
from transient_mi.props import PluginParameterError
mono = t._scene(rgb=True)
mono.sensors()[0].film().channels = "mono"  # (as channels="mono" in the scene description)
try:
    mono.integrator().render_backward(mono, None, mi.TensorXf(np.zeros((t.H, t.W, t.NB), np.float32)),
                                      mono.sensors()[0], 1, 4)
except PluginParameterError as e:
    out["refused"] = str(e)
# transient_path (surfaces) too: its replay's BSDF ratios are per colour channel as well
mono = mi.load_dict({{"type": "scene", "integrator": {{"type": "transient_path"}},
                     "sensor": {{"type": "perspective", "film": {{"type": "transient_film", "width": 4, "height": 4,
                                                                "n_bins": 8, "channels": "mono"}}}},
                     "plane": {{"type": "rectangle"}}, "light": {{"type": "constant"}}}})
try:
    mono.integrator().render_backward(mono, None, mi.TensorXf(np.zeros((4, 4, 8), np.float32)), mono.sensors()[0], 1, 4)
except PluginParameterError as e:
    out["refused_path"] = str(e)
print("JSON" + json.dumps(out))
"""


def test_rgb_variant_spectral_extinction_gradients():
    """``llvm_ad_rgb`` (subprocess): extinction and albedo per channel, one channel sampled per path for the
    free flights (the primal's weight is the transmittance over the sampled channel's pdf, per channel): the
    red channel of ``sigma_t`` and the green channel of ``albedo``: forward equals reverse (relative 1e-4)
    and reverse mode agrees with central differences (8 AD and 8 FD seeds with common random numbers, Welch
    t, false-failure rate 1e-3 for the two)."""
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
    res = json.loads([x for x in out.stdout.splitlines() if x.startswith("JSON")][-1][4:])
    refused = res.pop("refused", "")
    assert "\n" not in refused and "needs the film's RGB channels, not channels='mono'" in refused
    refused = res.pop("refused_path", "")
    assert "\n" not in refused and "needs the film's colour channels, not channels='mono'" in refused
    for key, r in res.items():
        assert r["reverse"] != 0 and r["forward"] == pytest.approx(r["reverse"], rel=1e-4), key
        assert_welch(r["ad"], r["fd"], len(res), key)


def test_nlos_captures_are_refused_in_one_line():
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from nlos_helpers import nlos_scene, square

    scene = nlos_scene(hidden=[square((0, 0, 0.5), 0.2, 0.8)], n_bins=64, integrator="transient_volpath")
    with pytest.raises(PluginParameterError) as e:
        scene.integrator().render_backward(scene, None, mi.TensorXf(np.zeros((4, 4, 64), np.float32)),
                                           scene.sensors()[0], 1, 4)
    assert "\n" not in str(e.value) and "differentiable rendering of NLOS captures (spad_array) through media is " \
                                       "not supported" in str(e.value)
