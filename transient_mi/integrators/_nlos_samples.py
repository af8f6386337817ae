"""The sample numbers of the NLOS kernels (clear, fog, derivative): which pixel and stream each SIMD lane
serves, and the randomised QMC numbers of its samples. One home, so the three kernels draw the same
numbers for the same sample (the derivative kernel replays the primal's samples exactly)."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

#: Dimensions drawn from the randomised low-discrepancy sequence: patch point (2), strategy choice (1),
#: hidden shape (1), point on it (2), BSDF direction (2) at the patch point.
QMC_DIMS = 8


def kronecker_generators(d: int = QMC_DIMS) -> list[int]:
    """Generators of the R_d Kronecker sequence (Roberts 2018) as 32-bit fixed-point fractions.

    ``phi_d`` is the positive root of ``x^(d+1) = x + 1``; dimension ``k``
    advances by ``frac(phi_d^-(k+1))`` per sample.
    """
    phi = 2.0
    for _ in range(100):
        phi = (1.0 + phi) ** (1.0 / (d + 1))
    return [int((phi ** -(k + 1) % 1.0) * 2.0 ** 32) & 0xFFFFFFFF for k in range(d)]


def lane_pixels(c: "transient_mi.integrators._nlos_kernel.KernelConstants", layout) -> list:
    """``[lane, pixel, k, centre]`` per SIMD lane: the lane index, its pixel, its stream ``k`` among the
    pixel's ``layout.streams`` (sample ``k + j K``) and the centre of the pixel's wall patch (m)."""
    K = layout.streams
    lane = dr.arange(mi.UInt32, layout.n_lanes)
    pixel = lane // K
    k = lane - pixel * K
    px = mi.Float(pixel % c.width_px)
    py = mi.Float(pixel // c.width_px)
    return [lane, pixel, k, c.patch_origin + px * c.pitch_x + py * c.pitch_y]


class PixelQMC:
    """The randomised QMC numbers of a pixel's samples: an R_d sequence (:func:`kronecker_generators`)
    shifted at random per pixel and replicate (Cranley-Patterson rotation, seeded by ``c.seed``)."""

    def __init__(self, c: "transient_mi.integrators._nlos_kernel.KernelConstants", pixel):
        self.gen = [dr.opaque(mi.UInt32, g) for g in kronecker_generators()]
        self.shift = []
        for d in range(0, QMC_DIMS, 2):
            a, b = mi.sample_tea_32(pixel, c.seed ^ mi.UInt32(0x9E3779B9 * (d + 1) & 0xFFFFFFFF))
            self.shift += [a, b]

    def numbers(self, c: "transient_mi.integrators._nlos_kernel.KernelConstants", rng, i_sample) -> list:
        """The :data:`QMC_DIMS` numbers of sample ``i_sample``; with ``rqmc=false`` (plain Monte Carlo, for
        comparisons) they are drawn from ``rng`` instead."""
        if c.rqmc:
            return [mi.Float((self.shift[d] + i_sample * self.gen[d]) >> 8) * (1.0 / (1 << 24))
                    for d in range(QMC_DIMS)]
        return [rng.next_float32() for d in range(QMC_DIMS)]
