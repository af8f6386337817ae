#!/usr/bin/env python3
"""The sub-bin mismatch of the NLOS geometry gradient (docs/differentiable.md, "Arrival time and the temporal kernel").

AD (arrival-time derivative through the continuous Gaussian kernel) against central differences of the primal
(box bin, then the discrete taps), on the scene of tests/test_nlos_differentiable.py (confocal, 50 ps bins),
hidden square translated along z (the translation with the largest arrival-time term), common random numbers,
paired over 24 seeds at 256 spp, for kernel_sigma_ps = 25, 50, 150 ps. Prints one line per sigma
(mean difference and its standard error, relative to the gradient). About 2 minutes on 2 cores.

    python bench/kernel_mismatch.py
"""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import numpy as np  # noqa: E402

import test_nlos_differentiable as t  # noqa: E402
import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

BIN_PS = 50.0


def main() -> None:
    t.SPP = 256
    for sigma in (25.0, 50.0, 150.0):
        scene = t._scene("confocal", sigma_ps=sigma)
        params = mi.traverse(scene)
        key = "target.to_world"
        T0 = mi.Transform4f(params[key])
        w = t._weights(t._render(scene, 3).shape)
        eps = 0.002
        d, ads = [], []
        try:
            for seed in range(100, 124):
                th = mi.Float(0.0)
                dr.enable_grad(th)
                t._move(params, key, T0, 2, th)
                t._reverse(scene, params, w, seed)
                ad = float(dr.grad(th)[0])
                v = []
                for s in (1, -1):
                    t._move(params, key, T0, 2, mi.Float(s * eps))
                    v.append(float(np.sum(t._render(scene, seed) * w)))
                d.append(ad - (v[0] - v[1]) / (2 * eps))
                ads.append(ad)
        finally:
            t._detach_all(params)
        d = np.array(d)
        m = float(np.mean(ads))
        se = d.std(ddof=1) / np.sqrt(len(d))
        print(f"sigma {sigma:.0f} ps ({sigma / BIN_PS:.1f} bins): AD {m:.1f}, AD - FD {d.mean():.2f} +- {se:.2f} "
              f"({100 * d.mean() / m:.3f} % +- {100 * se / abs(m):.3f} %); "
              f"bin_width^2 / (12 sigma^2) = {BIN_PS ** 2 / 12 / sigma ** 2:.3f}", flush=True)


if __name__ == "__main__":
    main()
