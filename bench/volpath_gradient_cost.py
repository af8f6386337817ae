#!/usr/bin/env python3
"""Cost of one gradient of ``transient_volpath`` against its primal render (issue 14, media).

Scene: ``scenes/fog_camera.xml`` (a camera in homogeneous fog, sigma_t 0.3 / m, albedo 0.8, hg g = 0.5; a
floor, a wall and a spherical lamp), 64 x 64 pixels, 1000 bins of 40 ps from 5 ns, max_depth 8, 128 spp. The
loss is ``sum(w * histogram)`` (fixed random weights); reverse mode (``render_backward``) with respect to the
fog's ``sigma_t`` and ``albedo``, the floor's reflectance and the lamp's radiance together, and forward mode
(``render_forward``) along ``sigma_t``. Each call: one untimed call (JIT compilation), then the best of three;
same seed and spp as the primal (``render_transient``). About 20 s on 2 cores.

    python bench/volpath_gradient_cost.py
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

import transient_mi  # noqa: F401  (first: LLVM + plug-ins)
import drjit as dr
import mitsuba as mi

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "fog_camera.xml"
KEYS = ("fog.sigma_t.value.value", "fog.albedo.value.value", "floor.bsdf.reflectance.value",
        "lamp.emitter.radiance.value")
W = H = 64
NB, SPP = 1000, 128


def best(f, rounds: int = 3) -> float:
    f()
    times = []
    for _ in range(rounds):
        t0 = time.perf_counter()
        f()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    scene = mi.load_file(str(SCENE), width=str(W), height=str(H), n_bins=str(NB), spp=str(SPP))
    sensor, integrator = scene.sensors()[0], scene.integrator()
    params = mi.traverse(scene)
    w = mi.TensorXf(np.random.default_rng(0).random((H, W, NB)).astype(np.float32))

    def primal():
        integrator.render_transient(scene, sensor, seed=1, spp=SPP)

    def reverse():
        for k in KEYS:
            dr.enable_grad(params[k])
        params.update()
        integrator.render_backward(scene, params, w, sensor, 1, SPP)
        dr.eval([dr.grad(params[k]) for k in KEYS])
        for k in KEYS:
            dr.disable_grad(params[k])
        params.update()

    def forward():
        k = KEYS[0]
        dr.enable_grad(params[k])
        params.update()
        dr.set_grad(params[k], 1.0)
        out = integrator.render_forward(scene, params, sensor, 1, SPP)
        dr.eval(out)
        dr.disable_grad(params[k])
        params.update()

    tp = best(primal)
    tr = best(reverse)
    tf = best(forward)
    print(f"{W} x {H}, {NB} bins, {SPP} spp, fog_camera.xml: primal {tp:.3f} s, reverse ({len(KEYS)} parameters) "
          f"{tr:.3f} s (ratio {tr / tp:.2f}), forward (sigma_t) {tf:.3f} s (ratio {tf / tp:.2f})")


if __name__ == "__main__":
    main()
