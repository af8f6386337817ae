#!/usr/bin/env python3
"""What the camera-view geometry gradient leaves out (docs/differentiable.md, "Geometry in camera views").

On the scene of tests/test_camera_geometry_ad.py (8 x 8 pixels, 320 bins of 20 ps, kernel_sigma_ps 120, point
light, max_depth 3, loss ``sum(w * histogram)``), reverse-mode AD against central differences of the primal with
common random numbers, 20 seeds at 256 spp, mean +- standard error over the seeds:

1. a black square between the light and the plane (out of the camera's view) moved along x: its shadow sweeps
   over the plane; the interior derivative is 0 (a visibility change only);
2. the partly shadowed plane moved along z: AD misses the shadow edge's share;
3. the plane moved along z without the occluder;
4. the same with a loss weighting later bins more (``w`` a ramp over the bins: a mean arrival time), with
   and without the arrival-time term.

About 20 s on 2 cores. ``--cost``: instead, the time of one reverse-mode gradient on the same scene at 32 x 32
pixels and 64 spp (best of 3 warm calls): the primal render, the gradient of the plane's reflectance, and the
gradient of the reflectance and the plane's translation (geometry: the attached replay and the arrival time).

    python bench/camera_geometry_bias.py [--cost]
"""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import numpy as np  # noqa: E402

import test_camera_geometry_ad as t  # noqa: E402
import transient_mi.integrators._ad_geometry as adg  # noqa: E402


def line(what, ads, fds):
    n = len(ads)
    d = ads - fds
    se = lambda x: x.std(ddof=1) / np.sqrt(n)  # noqa: E731
    print(f"{what}: AD {ads.mean():.4g} +- {se(ads):.2g}, central differences {fds.mean():.4g} +- {se(fds):.2g}, "
          f"paired difference {d.mean():.4g} +- {se(d):.2g} ({100 * d.mean() / fds.mean():+.1f} % of the gradient)")


def cost() -> None:
    import time

    import drjit as dr
    import mitsuba as mi

    t.W = t.H = 32
    scene = t._scene()
    params = mi.traverse(scene)
    w = mi.TensorXf(t._weights())
    T0 = mi.Transform4f(params["plane.to_world"])
    refl = "plane.bsdf.reflectance.value"

    def best(f):
        f()
        times = []
        for _ in range(3):
            t0 = time.perf_counter()
            f()
            times.append(time.perf_counter() - t0)
        return min(times)

    def grad(geometry):
        def f():
            dr.enable_grad(params[refl])
            if geometry:
                z = mi.Float(0.0)
                dr.enable_grad(z)
                t._move(params, "plane.to_world", T0, 2, z)
            params.update()
            scene.integrator().render_backward(scene, params, w, scene.sensors()[0], 1, 64)
            dr.eval(dr.grad(params[refl]))
            t._move(params, "plane.to_world", T0, 0, 0.0)
            t._detach_all(params)
        return f

    primal = best(lambda: t._render(scene, 1, 64))
    for name, f in (("reflectance", grad(False)), ("reflectance and translation", grad(True))):
        g = best(f)
        print(f"32 x 32, 320 bins, 64 spp: primal {primal:.3f} s, gradient ({name}) {g:.3f} s (ratio {g / primal:.2f})")


def main() -> None:
    if "--cost" in sys.argv:
        return cost()
    t.SEEDS = range(100, 120)
    line("occluder along x (m^-1)", *t._paired(t._scene(occluder=True), "occluder.to_world", 0))
    line("shadowed plane along z (m^-1)", *t._paired(t._scene(occluder=True), "plane.to_world", 2))
    line("plane along z, no occluder (m^-1)", *t._paired(t._scene(), "plane.to_world", 2))
    line("plane along z, ramp loss (m^-1)", *t._paired(t._scene(), "plane.to_world", 2, w=t._ramp()))
    adg.ARRIVAL_TIME = False
    line("plane along z, ramp loss, arrival-time term off (m^-1)",
         *t._paired(t._scene(), "plane.to_world", 2, w=t._ramp()))


if __name__ == "__main__":
    main()
