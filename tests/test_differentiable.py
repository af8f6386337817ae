"""Differentiable transient rendering with Mitsuba's AD interfaces (``mi.render(scene, params)``,
``dr.backward``, ``dr.forward``) for camera views.

Reverse-mode gradients of a scalar loss ``sum(w * histogram)`` (``w`` a fixed random weight per pixel
and time bin) with respect to a directly seen reflectance, an indirectly seen one and a light's
intensity agree with central finite differences of the same renderer's expected value: AD over 8
seeds against finite differences with common random numbers over 4 seeds, Welch t, false-failure rate
1e-3 for the three parameters together (Bonferroni). Forward mode equals reverse mode on the same
samples to float precision (deterministic: no statistical false-failure rate).
"""

from __future__ import annotations


import numpy as np
import pytest

import transient_mi  # noqa: F401
import drjit as dr
import mitsuba as mi

from ad_helpers import assert_welch, loss_at, reverse_gradient

T = mi.ScalarTransform4f
PARAMS = ("plane.bsdf.reflectance.value", "wall.bsdf.reflectance.value", "light.intensity.value")


def _scene(kernel_sigma_ps=0.0, spectral_rgb=False):
    """``spectral_rgb``: the reflectances as sRGB colours (upsampled to spectra in spectral variants)."""
    refl = (lambda v, rgb: {"type": "rgb", "value": rgb}) if spectral_rgb else \
        (lambda v, rgb: {"type": "spectrum", "value": v})
    return mi.load_dict({
        "type": "scene",
        "integrator": {"type": "transient_path", "max_depth": 4},
        "sensor": {"type": "perspective", "fov": 30.0,
                   "to_world": T().look_at(origin=[0.25, 0.15, 2.0], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "transient_film", "width": 8, "height": 8, "n_bins": 200,
                            "bin_width_ps": 50.0, "t0_ps": 5000.0, "rfilter": {"type": "box"},
                            "kernel_sigma_ps": kernel_sigma_ps},
                   "sampler": {"type": "independent", "sample_count": 64}},
        # a spot light lights only the wall; the plane the camera looks at gets the wall's light, so its
        # reflectance's gradient is all in the throughput of a later contribution (PRB's replay term)
        "light": {"type": "spot", "cutoff_angle": 15.0, "beam_width": 10.0,
                  "to_world": T().look_at(origin=[0.0, 0.0, 0.5], target=[1.0, 0.0, 0.5], up=[0, 0, 1]),
                  "intensity": {"type": "spectrum", "value": 50.0}},
        "plane": {"type": "rectangle", "to_world": T().scale(3.0),
                  "bsdf": {"type": "diffuse", "reflectance": refl(0.6, [0.2, 0.5, 0.8])}},
        "wall": {"type": "rectangle",
                 "to_world": T().translate([1.0, 0, 0.5]) @ T().rotate([0, 1, 0], -90) @ T().scale(0.5),
                 "bsdf": {"type": "diffuse", "reflectance": refl(0.5, [0.7, 0.4, 0.2])}},
    })


def _weights():
    return mi.TensorXf(np.random.default_rng(0).random((8, 8, 200)).astype(np.float32))


def test_reverse_mode_gradients_agree_with_finite_differences():
    scene, w = _scene(), _weights()
    for key in PARAMS:
        x0 = float(np.asarray(mi.traverse(scene)[key]).ravel()[0])
        h = 0.02 * x0
        ad = [reverse_gradient(scene, key, w, seed=10 + s, spp=256) for s in range(8)]
        fd = [(loss_at(scene, key, x0 + h, w, 100 + s, 2048) - loss_at(scene, key, x0 - h, w, 100 + s, 2048))
              / (2 * h) for s in range(4)]
        assert_welch(ad, fd, len(PARAMS), key)


@pytest.mark.parametrize("kernel_sigma_ps", [0.0, 60.0])
def test_forward_mode_equals_reverse_mode(kernel_sigma_ps):
    """The same samples (same seed): <w, dh/dtheta> from forward mode equals the reverse-mode gradient; with a
    temporal kernel the adjoint goes through the kernel's taps."""
    scene, w = _scene(kernel_sigma_ps), _weights()
    key = PARAMS[1]
    rev = reverse_gradient(scene, key, w, seed=3, spp=256)
    params = mi.traverse(scene)
    dr.enable_grad(params[key])
    params.update()
    img = mi.render(scene, params, seed=3, spp=256)
    dr.forward(params[key])
    fwd = float(np.sum(np.asarray(dr.grad(img), dtype=np.float64) * np.asarray(w)))
    assert rev != 0 and fwd == pytest.approx(rev, rel=2e-4)


def test_nlos_captures_with_unlimited_depth_refuse_ad_with_one_line():
    """Differentiable NLOS captures (tests/test_nlos_differentiable.py) need a finite max_depth."""
    import sys

    sys.path.insert(0, str(__import__("pathlib").Path(__file__).parent))
    from nlos_helpers import nlos_scene, square

    from transient_mi.props import PluginParameterError

    for integrator in ("transient_nlos_path", "transient_path"):
        scene = nlos_scene(hidden=[square((0, 0, 0.5), 0.2, 0.8)], n_bins=64, integrator=integrator, max_depth=-1)
        with pytest.raises(PluginParameterError, match="max_depth=-1; differentiable NLOS captures need a finite max_depth"):
            scene.integrator().render_backward(scene, None, mi.TensorXf(np.zeros((4, 4, 64), np.float32)),
                                               scene.sensors()[0], 1, 4)


_SPECTRAL_SCRIPT = r"""
import json, sys
sys.path.insert(0, {tests!r})
import numpy as np
import transient_mi  # noqa: F401
import drjit as dr
import mitsuba as mi
import test_differentiable as t
from ad_helpers import color_direction_gradient, color_direction_loss

scene = t._scene(spectral_rgb=True)
w = mi.TensorXf(np.random.default_rng(0).random((8, 8, 200, 3)).astype(np.float32))
out = {{}}
for key in ("plane.bsdf.reflectance.value", "wall.bsdf.reflectance.value"):
    params = mi.traverse(scene)
    x0 = mi.Color3f(params[key])
    d = (0.0, 0.0, 1.0)  # the constant term of the sRGB model's polynomial
    def grad(seed, mode):
        return color_direction_gradient(scene, params, key, x0, d, w, seed, mode, 256)
    def loss(c, seed):
        return color_direction_loss(scene, params, key, x0, d, c, w, seed, 2048)
    h = 0.02
    out[key] = {{"reverse": grad(3, "reverse"), "forward": grad(3, "forward"),
                "ad": [grad(10 + s, "reverse") for s in range(8)],
                "fd": [(loss(h, 100 + s) - loss(-h, 100 + s)) / (2 * h) for s in range(4)]}}
print("JSON" + json.dumps(out))
"""


def test_spectral_variant_gradients():
    """``llvm_ad_spectral`` (subprocess, ``TRANSIENT_MI_VARIANT``): the adjoint sums and log-throughput
    derivatives of the replay are kept per wavelength. sRGB-upsampled reflectances (a different BSDF ratio at
    each of a path's wavelengths), along the constant term of the sRGB model's polynomial: forward equals
    reverse (relative 1e-4), and reverse mode agrees with central differences (8 AD seeds, 4 FD seeds with
    common random numbers, Welch t, false-failure rate 1e-3 for the two). With the first wavelength's BSDF
    ratio used for all four (the replay before per-wavelength sums) the plane's comparison fails (t of
    about 6)."""
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    tests = str(Path(__file__).resolve().parent)
    env = dict(os.environ, TRANSIENT_MI_VARIANT="llvm_ad_spectral")
    out = subprocess.run([sys.executable, "-c", _SPECTRAL_SCRIPT.format(tests=tests)], env=env, capture_output=True,
                         text=True, timeout=600, check=False)
    assert out.returncode == 0, out.stderr[-2000:]
    res = json.loads([x for x in out.stdout.splitlines() if x.startswith("JSON")][-1][4:])
    for key, r in res.items():
        assert r["reverse"] != 0 and r["forward"] == pytest.approx(r["reverse"], rel=1e-4), key
        assert_welch(r["ad"], r["fd"], len(res), key)


def test_geometry_in_a_spectral_variant_is_refused_in_one_line():
    """(subprocess) Geometry derivatives support *_mono and *_rgb variants."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    script = (f"import sys; sys.path.insert(0, {str(Path(__file__).resolve().parent)!r})\n"
              "import numpy as np, transient_mi, drjit as dr, mitsuba as mi, test_differentiable as t\n"
              "from transient_mi.props import PluginParameterError\n"
              "scene = t._scene(60.0, spectral_rgb=True); params = mi.traverse(scene)\n"
              "dr.enable_grad(params['plane.to_world'])\n"
              "try:\n"
              "    scene.integrator().render_backward(scene, params, mi.TensorXf(np.zeros((8, 8, 200, 3), np.float32)),"
              " scene.sensors()[0], 1, 4)\n"
              "except PluginParameterError as e:\n"
              "    print('REFUSED', str(e))\n")
    env = dict(os.environ, TRANSIENT_MI_VARIANT="llvm_ad_spectral")
    out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    line = [x for x in out.stdout.splitlines() if x.startswith("REFUSED")]
    assert line and "plane.to_world is differentiated; derivatives with respect to geometry support *_mono and " \
                    "*_rgb variants, not llvm_ad_spectral" in line[0]
