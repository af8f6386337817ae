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

About 30 s on 2 cores.

    python bench/camera_geometry_bias.py
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


def main() -> None:
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
