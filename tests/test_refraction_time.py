"""Light in glass travels at c/n: the optical path of a ray through dielectrics is sum(n_i d_i).

Closed forms (peak time of the centre pixel of a narrow camera, within one bin):

* a glass slab (n = 1.5, d = 10 cm) at normal incidence delays the light behind it by (n - 1) d / c
  (166.8 ps), and at oblique incidence the path is (D - d) / cos(theta) + n d / cos(theta_t);
* a sphere lens seen through its centre: (D - 2R) + 2 n R;
* a right-angle prism that turns the light by total internal reflection: z0 + 2 n a + (X_e - a).

The tests are deterministic geometry checks (a delta chain of refractions has one path per pixel
sample, and every sample of the centre pixel lies within a fraction of a bin of the closed form), so
they have no statistical false-failure rate: a peak a whole bin away is a physics error.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import transient_mi  # noqa: F401  (LLVM + plug-ins first)
import mitsuba as mi

from transient_core.units import C_M_PER_PS

N_GLASS = 1.5
BIN_PS = 5.0
T = mi.ScalarTransform4f


def _scene(shapes, *, theta_deg=0.0, t0_ps=0.0, n_bins=4000, emitter=None):
    th = math.radians(theta_deg)
    d = {
        "type": "scene",
        "integrator": {"type": "transient_path", "max_depth": 10},
        "sensor": {
            "type": "perspective", "fov": 1.0,
            "to_world": T().look_at(origin=[0, 0, 0], target=[math.sin(th), 0, math.cos(th)], up=[0, 1, 0]),
            "film": {"type": "transient_film", "width": 3, "height": 3, "n_bins": n_bins,
                     "bin_width_ps": BIN_PS, "t0_ps": t0_ps, "rfilter": {"type": "box"}},
            "sampler": {"type": "independent", "sample_count": 64},
        },
        "emitter": emitter or {
            "type": "rectangle", "to_world": T().translate([0, 0, 2.0]) @ T().rotate([1, 0, 0], 180) @ T().scale([4.0, 4.0, 1.0]),
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}},
        },
    }
    d.update(shapes)
    return mi.load_dict(d)


def _glass():
    return {"type": "dielectric", "int_ior": N_GLASS, "ext_ior": 1.0}


def _peak_ps(scene, t0_ps):
    res = scene.integrator().render_transient(scene, scene.sensors()[0], seed=1, spp=64)
    h = np.asarray(res.histogram)[1, 1]
    assert h.max() > 0, "the centre pixel recorded no light"
    return t0_ps + (int(np.argmax(h)) + 0.5) * BIN_PS


def _check(peak_ps, opl_m):
    want = opl_m / C_M_PER_PS
    assert abs(peak_ps - want) <= BIN_PS, f"peak at {peak_ps:.1f} ps, closed form {want:.1f} ps"


def _slab(z1, d):
    return {"slab": {"type": "cube", "to_world": T().translate([0, 0, z1 + d / 2]) @ T().scale([3.0, 3.0, d / 2]),
                     "bsdf": _glass()}}


def test_slab_at_normal_incidence_delays_light_by_n_minus_1_d_over_c():
    D, d = 2.0, 0.1
    free = _peak_ps(_scene({}, t0_ps=6000), 6000)
    through = _peak_ps(_scene(_slab(0.8, d), t0_ps=6000), 6000)
    _check(free, D)
    _check(through, D - d + N_GLASS * d)
    assert abs((through - free) - (N_GLASS - 1) * d / C_M_PER_PS) <= BIN_PS  # 166.8 ps, not ~0


@pytest.mark.parametrize("theta_deg", [20.0, 35.0])
def test_slab_at_oblique_incidence_follows_snell(theta_deg):
    D, d = 2.0, 0.1
    th = math.radians(theta_deg)
    th_t = math.asin(math.sin(th) / N_GLASS)
    peak = _peak_ps(_scene(_slab(0.8, d), theta_deg=theta_deg, t0_ps=6000), 6000)
    _check(peak, (D - d) / math.cos(th) + N_GLASS * d / math.cos(th_t))


def test_sphere_lens_through_its_centre():
    D, R = 2.0, 0.2
    lens = {"lens": {"type": "sphere", "center": [0, 0, 1.0], "radius": R, "bsdf": _glass()}}
    _check(_peak_ps(_scene(lens, t0_ps=6000), 6000), (D - 2 * R) + 2 * N_GLASS * R)


def test_total_internal_reflection_in_a_prism(tmp_path):
    """Light enters a right-angle prism normally, is totally reflected at the hypotenuse (45 deg >
    the critical angle 41.8 deg) and leaves through the other leg towards an emitter at x = X_e."""
    import trimesh

    a, z0, h, x_e = 0.1, 0.5, 0.3, 1.0
    tri = [(-a, z0), (a, z0), (a, z0 + 2 * a)]  # (x, z): entry face z = z0, exit face x = a, hypotenuse
    verts = [(x, y, z) for y in (-h, h) for (x, z) in tri]
    faces = [(0, 1, 2), (3, 5, 4), (0, 3, 4), (0, 4, 1), (1, 4, 5), (1, 5, 2), (2, 5, 3), (2, 3, 0)]
    mesh = trimesh.Trimesh(np.array(verts), np.array(faces), process=True)
    mesh.fix_normals()
    assert mesh.is_watertight and mesh.volume > 0
    path = tmp_path / "prism.ply"
    mesh.export(path)
    prism = {"prism": {"type": "ply", "filename": str(path), "face_normals": True, "bsdf": _glass()}}
    emitter = {"type": "rectangle",
               "to_world": T().translate([x_e, 0, z0 + a]) @ T().rotate([0, 1, 0], -90) @ T().scale([1.0, 1.0, 1.0]),
               "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}}}
    peak = _peak_ps(_scene(prism, t0_ps=4000, emitter=emitter), 4000)
    _check(peak, z0 + 2 * N_GLASS * a + (x_e - a))


def test_next_event_estimation_through_a_rough_dielectric_runs_at_c_over_n():
    """A small emitter at the centre of a rough glass sphere is reached mostly by next-event estimation
    through the rough interface: that connection lies inside the glass, so it takes n (R - r) / c."""
    zc, R, r = 1.0, 0.2, 0.0005
    shapes = {"ball": {"type": "sphere", "center": [0, 0, zc], "radius": R,
                       "bsdf": {"type": "roughdielectric", "int_ior": N_GLASS, "ext_ior": 1.0, "alpha": 0.6}}}
    emitter = {"type": "sphere", "center": [0, 0, zc], "radius": r,
               "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}}}
    peak = _peak_ps(_scene(shapes, t0_ps=2000, n_bins=2000, emitter=emitter), 2000)
    _check(peak, (zc - R) + N_GLASS * (R - r))
