"""Geometry derivatives of camera views (transient_mi/integrators/_ad_geometry.py, docs/differentiable.md).

Scene: a perspective camera (8 x 8 pixels, 320 bins of 20 ps from 9.8 ns: all of the direct light and 99.9 %
of the indirect light; Gaussian temporal kernel of 120 ps) looks at a tilted 4 m Lambertian rectangle that
fills its view (no silhouette in the image), lit by a point light (or a small area light) and by the light a
second rectangle (the "wall", outside the view) reflects onto it; ``max_depth`` 3 (direct light and one
indirect bounce). The loss is ``sum(w * histogram)`` with fixed random
weights ``w`` per pixel and bin.

Statistics: each geometry check compares, per seed, the reverse-mode gradient with central differences of the
primal at the same seed (common random numbers) and tests the mean of the paired differences over 10 seeds
with a two-sided t-test (9 degrees of freedom); the 9 comparisons share a total false-failure rate of 1e-3
(Bonferroni: 1.11e-4 each, quantile 6.50). Each also asserts that the gradient is resolved (its mean at
least 5 standard errors of the differences from 0), so that agreement is not vacuous. Without the
arrival-time term the view-axis comparison must fail (|t| > 6.50; measured t about 170: the power of the
test); the occluder check asserts that central differences see a change (|t| > 6.50, measured about 100)
that AD does not (zero to float rounding). Forward against reverse mode, same bytes and the refusal are
deterministic (no false-failure rate).
"""

from __future__ import annotations

import importlib
import math

import numpy as np
import pytest

import transient_mi  # noqa: F401  (before mitsuba/drjit)
import drjit as dr
import mitsuba as mi

from ad_helpers import detach_all
from scipy import stats

from transient_mi.props import PluginParameterError

T = mi.ScalarTransform4f
W = H = 8
N_BINS = 320
SPP = 256
SEEDS = range(10)
N_COMPARISONS = 9
ALPHA_TOTAL = 1e-3
T_Q = float(stats.t.isf(ALPHA_TOTAL / N_COMPARISONS / 2, len(SEEDS) - 1))
PLANE = T().rotate([1, 0, 0], -20) @ T().rotate([0, 1, 0], 25) @ T().scale(2.0)


def _scene(light="point", sigma_ps=120.0, occluder=False, mesh=None):
    d = {"type": "scene",
         "integrator": {"type": "transient_path", "max_depth": 3},
         "sensor": {"type": "perspective", "fov": 30.0,
                    "to_world": T().look_at(origin=[0.0, 0.0, 2.0], target=[0, 0, 0], up=[0, 1, 0]),
                    "film": {"type": "transient_film", "width": W, "height": H, "n_bins": N_BINS,
                             "bin_width_ps": 20.0, "t0_ps": 9800.0, "rfilter": {"type": "box"},
                             "kernel_sigma_ps": sigma_ps},
                    "sampler": {"type": "independent", "sample_count": SPP}},
         "plane": {"type": "rectangle", "to_world": PLANE,
                   "bsdf": {"type": "diffuse", "reflectance": {"type": "spectrum", "value": 0.6}}},
         # out of the camera's view, above the plane, facing +x (towards the light)
         "wall": {"type": "rectangle",
                  "to_world": T().translate([-0.6, 0, 1.0]) @ T().rotate([0, 1, 0], 90) @ T().scale(0.5),
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "spectrum", "value": 0.8}}}}
    if mesh is not None:  # the same plane as a PLY mesh
        d["plane"] = {"type": "ply", "filename": str(mesh),
                      "bsdf": {"type": "diffuse", "reflectance": {"type": "spectrum", "value": 0.6}}}
    if light == "point":
        d["light"] = {"type": "point", "position": [0.5, 0.4, 1.0], "intensity": {"type": "spectrum", "value": 5.0}}
    else:  # a 0.2 m square facing down
        d["light"] = {"type": "rectangle",
                      "to_world": T().translate([0.5, 0.4, 1.0]) @ T().rotate([1, 0, 0], 180) @ T().scale(0.1),
                      "emitter": {"type": "area", "radiance": {"type": "spectrum", "value": 40.0}}}
    if occluder:  # a black 0.2 x 0.3 m rectangle under the light (out of view): its shadow covers the right half
        d["occluder"] = {"type": "rectangle",
                         "to_world": T().translate([0.5, 0.35, 0.8]) @ T().scale([0.1, 0.15, 1.0]),
                         "bsdf": {"type": "diffuse", "reflectance": {"type": "spectrum", "value": 0.0}}}
    return mi.load_dict(d)


def _shape():
    """The histogram's shape: ``[H, W, bins]``, and ``[H, W, bins, 3]`` in rgb variants (R, G, B channels)."""
    return (H, W, N_BINS) + ((3,) if mi.is_rgb else ())


def _weights():
    return np.random.default_rng(7).random(_shape()).astype(np.float32)


def _ramp():
    """Weights growing with time (the loss: a mean arrival time times the light): its gradient is mostly the
    arrival time's."""
    ramp = np.linspace(0.0, 1.0, N_BINS, dtype=np.float32)
    return np.broadcast_to(ramp.reshape((1, 1, N_BINS) + (1,) * (len(_shape()) - 3)), _shape()).copy()


def _render(scene, seed, spp=SPP):
    return np.asarray(scene.integrator().render(scene, scene.sensors()[0], seed=seed, spp=spp), dtype=np.float64)


def _move(params, key, T0, kind, t):
    """``key`` (a to_world) set to ``T0`` translated along axis ``kind`` (0, 1, 2) by ``t`` metres, or rotated
    about the y axis through the origin (the plane's centre) by ``t`` degrees (``kind`` 3)."""
    if kind < 3:
        v = [0.0, 0.0, 0.0]
        v[kind] = t
        params[key] = mi.Transform4f().translate(mi.Vector3f(*v)) @ T0
    else:
        params[key] = mi.Transform4f().rotate(mi.Vector3f(0, 1, 0), t) @ T0
    params.update()


def _paired(scene, key, kind, spp=SPP, w=None):
    """``(ad, fd)`` per seed: the reverse-mode gradient of ``sum(w * hist)`` along the motion ``kind`` of
    ``key`` and central differences of the primal with the same seed."""
    params = mi.traverse(scene)
    T0 = mi.Transform4f(params[key])
    w = _weights() if w is None else w
    eps = 0.004 if kind < 3 else 0.4
    ads, fds = [], []
    try:
        for seed in SEEDS:
            th = mi.Float(0.0)
            dr.enable_grad(th)
            _move(params, key, T0, kind, th)
            scene.integrator().render_backward(scene, params, mi.TensorXf(w), scene.sensors()[0], seed, spp)
            ads.append(float(dr.grad(th)[0]))
            detach_all(params)
            vals = []
            for s in (1, -1):
                _move(params, key, T0, kind, s * eps)
                vals.append(float(np.sum(_render(scene, seed, spp) * w)))
            fds.append((vals[0] - vals[1]) / (2 * eps))
    finally:
        _move(params, key, T0, 0, 0.0)
        detach_all(params)
    return np.asarray(ads), np.asarray(fds)


def _t(ads, fds):
    d = ads - fds
    se = d.std(ddof=1) / math.sqrt(len(d))
    return d.mean() / se, ads.mean() / se


CASES = [("point", "plane.to_world", 0), ("point", "plane.to_world", 1), ("point", "plane.to_world", 2),
         ("point", "plane.to_world", 3), ("area", "plane.to_world", 2), ("area", "plane.to_world", 3),
         ("point", "wall.to_world", 0)]


@pytest.mark.parametrize("light,key,kind", CASES,
                         ids=["x", "y", "z", "rotation", "area-z", "area-rotation", "wall-x"])
def test_geometry_gradient_equals_central_differences(light, key, kind):
    """Translation along x, y, z (m) and rotation about y (degrees) of the plane the camera sees (its camera
    vertex slides along the camera ray), and the wall moved along x (a deeper vertex, following its shape):
    no visibility changes, so the interior derivative is the whole derivative."""
    spp = 1024 if key.startswith("wall") else SPP
    ads, fds = _paired(_scene(light), key, kind, spp)
    t, resolved = _t(ads, fds)
    assert abs(resolved) > 5, f"not resolved: AD {ads.mean():.4g}, differences' se {ads.mean() / resolved:.3g}"
    assert abs(t) <= T_Q, f"AD {ads.mean():.5g} vs central differences {fds.mean():.5g}: paired t = {t:+.2f}"


def _plane_ply(path):
    """The test plane (the rectangle's four corners under ``PLANE``) as a two-triangle PLY mesh."""
    m = mi.Mesh("plane", 4, 2)
    v = [PLANE @ mi.ScalarPoint3f(x, y, 0.0) for x, y in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    p = mi.traverse(m)
    p["vertex_positions"] = mi.Float(np.asarray([list(q) for q in v], np.float32).ravel())
    p["faces"] = mi.UInt32(np.array([0, 1, 2, 0, 2, 3], np.uint32))
    p.update()
    m.write_ply(str(path))
    return path


def test_mesh_vertex_positions_gradient_equals_central_differences(tmp_path):
    """The plane as a mesh moved along z through its vertex_positions (the 9th comparison): the same interior
    derivative as through a rectangle's to_world."""
    scene = _scene(mesh=_plane_ply(tmp_path / "plane.ply"))
    params = mi.traverse(scene)
    key = "plane.vertex_positions"
    V0 = dr.unravel(mi.Point3f, mi.Float(params[key]))
    w = _weights()
    eps = 0.004
    ads, fds = [], []
    try:
        for seed in SEEDS:
            th = mi.Float(0.0)
            dr.enable_grad(th)
            params[key] = dr.ravel(V0 + mi.Vector3f(0, 0, th))
            params.update()
            scene.integrator().render_backward(scene, params, mi.TensorXf(w), scene.sensors()[0], seed, SPP)
            ads.append(float(dr.grad(th)[0]))
            detach_all(params)
            vals = []
            for s in (1, -1):
                params[key] = dr.ravel(V0 + mi.Vector3f(0, 0, s * eps))
                params.update()
                vals.append(float(np.sum(_render(scene, seed) * w)))
            fds.append((vals[0] - vals[1]) / (2 * eps))
    finally:
        detach_all(params)
    t, resolved = _t(np.asarray(ads), np.asarray(fds))
    assert abs(resolved) > 5 and abs(t) <= T_Q, f"AD {np.mean(ads):.5g} vs {np.mean(fds):.5g}: paired t = {t:+.2f}"


def test_the_arrival_time_term_is_needed(monkeypatch):
    """A loss weighting later bins more (a mean arrival time): along the view axis its gradient agrees with
    central differences (the 8th comparison of the family), and without the arrival time's derivative (the
    Gaussian kernel's) AD disagrees (it has the wrong sign: t of about 170)."""
    ads, fds = _paired(_scene(), "plane.to_world", 2, w=_ramp())
    t, resolved = _t(ads, fds)
    assert abs(resolved) > 5 and abs(t) <= T_Q, f"AD {ads.mean():.5g} vs {fds.mean():.5g}: paired t = {t:+.2f}"
    # the module the plug-ins use now (a variant switch earlier in the session re-imports the plug-in modules)
    monkeypatch.setattr(importlib.import_module("transient_mi.integrators._ad_geometry"), "ARRIVAL_TIME", False)
    ads, fds = _paired(_scene(), "plane.to_world", 2, w=_ramp())
    t, _ = _t(ads, fds)
    assert abs(t) > T_Q, f"without the arrival-time term: paired t = {t:+.2f}"


def test_a_moving_shadow_edge_is_not_differentiated():
    """The documented bias: moving the occluder (out of view) moves its shadow over the plane, which changes
    the histogram (central differences see it), but the interior derivative of the occluder's motion is 0."""
    ads, fds = _paired(_scene(occluder=True), "occluder.to_world", 0)
    assert np.all(np.abs(ads) <= 1e-6 * abs(fds.mean())), ads  # (float rounding: paths that end on it)
    se = fds.std(ddof=1) / math.sqrt(len(fds))
    assert abs(fds.mean()) > T_Q * se, (fds.mean(), se)


def test_forward_mode_equals_reverse_mode():
    """One tangent moving the plane along z, its reflectance and the wall along x at once, through mi.render:
    forward mode equals reverse mode on the same samples."""
    scene = _scene()
    params = mi.traverse(scene)
    P0, W0 = mi.Transform4f(params["plane.to_world"]), mi.Transform4f(params["wall.to_world"])
    r0 = type(params["plane.bsdf.reflectance.value"])(dr.detach(params["plane.bsdf.reflectance.value"]))
    w = _weights()
    out = []
    try:
        for mode in ("reverse", "forward"):
            th = mi.Float(0.0)
            dr.enable_grad(th)
            params["plane.bsdf.reflectance.value"] = r0 + 0.5 * th
            _move(params, "wall.to_world", W0, 0, 0.3 * th)
            _move(params, "plane.to_world", P0, 2, th)
            img = mi.render(scene, params, seed=1, seed_grad=7, spp=64, spp_grad=64)
            if mode == "reverse":
                dr.backward(dr.sum(img * mi.TensorXf(w), axis=None))
                out.append(float(dr.grad(th)[0]))
            else:
                dr.forward(th)
                out.append(float(np.sum(np.asarray(dr.grad(img), dtype=np.float64) * w)))
            detach_all(params)
    finally:
        detach_all(params)
    assert out[0] != 0 and out[1] == pytest.approx(out[0], rel=1e-4)


def test_same_seed_same_bytes():
    """Forward mode records tangents in per-lane histograms: same seed, same bytes. (Reverse mode accumulates
    the parameters' gradients with Dr.Jit's atomic adds across threads: equal to float rounding, not to the
    byte, as for the existing emitter gradients.)"""
    scene = _scene()
    params = mi.traverse(scene)
    T0 = mi.Transform4f(params["plane.to_world"])
    tangents = []
    try:
        for _ in range(2):
            th = mi.Float(0.0)
            dr.enable_grad(th)
            _move(params, "plane.to_world", T0, 2, th)
            img = mi.render(scene, params, seed=5, spp=64)
            dr.forward(th)
            tangents.append(np.asarray(dr.grad(img)).tobytes())
            detach_all(params)
    finally:
        detach_all(params)
    assert tangents[0] == tangents[1] and np.any(np.frombuffer(tangents[0], np.float32) != 0)


def test_geometry_without_a_temporal_kernel_is_refused_in_one_line():
    scene = _scene(sigma_ps=0.0)
    params = mi.traverse(scene)
    dr.enable_grad(params["plane.to_world"])
    w = mi.TensorXf(np.zeros(_shape(), np.float32))
    try:
        for call in (lambda: scene.integrator().render_backward(scene, params, w, scene.sensors()[0], 1, 4),
                     lambda: scene.integrator().render_forward(scene, params, scene.sensors()[0], 1, 4)):
            with pytest.raises(PluginParameterError, match=r"plane.to_world is differentiated but the film's "
                                                           r"kernel_sigma_ps=0") as e:
                call()
            assert "\n" not in str(e.value)
    finally:
        detach_all(params)
