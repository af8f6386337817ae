"""Which emitters carry time zero: light leaves a point, spot or projector emitter at its position and an
area emitter at the sampled point on its surface, at t = 0; so every pixel of a camera looking at a
plane peaks at (|L - x| + |x - C|) / c (closed form, within one bin; a deterministic geometry check).
Infinitely distant emitters (directional, environment) have no time of flight: their light is dropped
and counted (tests/test_transient_path.py)."""

from __future__ import annotations

import numpy as np
import pytest

import transient_mi  # noqa: F401
import mitsuba as mi

from transient_mi.time_axis import TimeAxis

T = mi.ScalarTransform4f
CAM = [0.25, 0.15, 2.0]
LIGHT = [-0.5, 0.6, 1.0]
W = H = 24
AXIS = TimeAxis(4000.0, 40.0, 300)


def _emitter(kind):
    to = T().look_at(origin=LIGHT, target=[0, 0, 0], up=[0, 1, 0])
    if kind == "point":
        return {"type": "point", "position": LIGHT, "intensity": {"type": "spectrum", "value": 5.0}}
    if kind == "spot":
        return {"type": "spot", "to_world": to, "cutoff_angle": 60.0, "intensity": {"type": "spectrum", "value": 5.0}}
    if kind == "projector":
        return {"type": "projector", "to_world": to, "fov": 90.0,
                "irradiance": {"type": "bitmap", "data": mi.TensorXf(np.ones((8, 8, 3), dtype=np.float32)), "raw": True}}
    if kind == "area":  # a small sphere: its sampled surface point is within 1 mm of LIGHT
        return {"type": "sphere", "center": LIGHT, "radius": 1e-3,
                "emitter": {"type": "area", "radiance": {"type": "spectrum", "value": 1e6}}}
    raise ValueError(kind)


@pytest.mark.parametrize("kind", ["point", "spot", "projector", "area"])
def test_light_leaves_the_emitter_at_time_zero(kind):
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "transient_path", "max_depth": 2},
        "sensor": {"type": "perspective", "fov": 10.0,
                   "to_world": T().look_at(origin=CAM, target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "transient_film", "width": W, "height": H, "n_bins": AXIS.n_bins,
                            "bin_width_ps": AXIS.bin_width_ps, "t0_ps": AXIS.t0_ps, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": 16}},
        "light": _emitter(kind),
        "plane": {"type": "rectangle", "to_world": T().scale(3.0),
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "spectrum", "value": 0.8}}},
    })
    res = scene.integrator().render_transient(scene, scene.sensors()[0], seed=2, spp=16)
    sensor = scene.sensors()[0]
    j, i = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    ray, _ = sensor.sample_ray(mi.Float(0), mi.Float(0), mi.Point2f((i.ravel() + 0.5) / W, (j.ravel() + 0.5) / H),
                               mi.Point2f(0.5))
    si = scene.ray_intersect(ray)
    x = np.stack([np.asarray(si.p.x), np.asarray(si.p.y), np.asarray(si.p.z)], -1).reshape(H, W, 3)
    opl = np.linalg.norm(x - np.array(LIGHT), axis=-1) + np.linalg.norm(x - np.array(CAM), axis=-1)
    lit = res.histogram.sum(-1) > 0
    assert lit.sum() > W * H // 2
    peak = np.argmax(res.histogram, axis=-1)
    assert np.max(np.abs(peak - AXIS.bin_index(opl))[lit]) <= 1
