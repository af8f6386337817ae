"""The film's reconstruction filter, honoured by filter importance sampling (camera sensors).

Mitsuba's films splat every sample into the pixels around it with the filter's weights and divide by
the summed weights: a pixel converges to the filter-weighted average of the image over the film,

    I(i) = int_film k(x - c_i) L(x) dx / int_film k(x - c_i) dx,      k(x, y) = f(x) f(y),

``c_i`` the pixel centre, ``f`` the 1-D filter (``rfilter.eval``, pixel units, support
``[-radius, radius]``). Here every sample is drawn from that normalised weight instead: its offset
from the pixel centre, in x and in y independently, has density proportional to ``f`` restricted
to the film (``[-(i + 1/2), W - (i + 1/2)]`` for column ``i``: Mitsuba samples only inside the film,
so an edge pixel averages over a truncated filter; with the film's ``sample_border`` Mitsuba also
samples the border the filter reaches, and the whole ``[-radius, radius]`` is used), and it is
recorded in its own pixel's histogram.
The expectation is ``I(i)`` exactly; each lane keeps its pixel's histogram (determinism, see
:mod:`transient_mi.integrators._lanes`). Filter importance sampling needs ``f >= 0``
(:func:`transient_mi.integrators._sensor_checks.check_rfilter`).

The box filter (radius 1/2) is the uniform draw in the pixel, kept as ``pixel + u`` (the same bytes
as before filters were honoured). Any other filter: ``f`` tabulated at ``TABLE_INTERVALS + 1`` points
over ``[-radius, radius]``, sampled by the inverse of its piecewise-linear CDF
(``mi.ContinuousDistribution``; exact for the tent, whose kinks lie on the grid; relative CDF error
~1e-6 for the Gaussian).
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from transient_mi._upload import upload

#: Intervals of the tabulated filter.
TABLE_INTERVALS = 4096


class PixelFilter:
    """Sample image-plane positions (pixel units) from a film's reconstruction filter."""

    def __init__(self, rfilter, sample_border: bool = False):
        #: sample outside the film too (the film's ``sample_border``): the whole filter at edge pixels
        self.sample_border = bool(sample_border)
        self.is_box = rfilter is None or (rfilter.class_name() == "BoxFilter"
                                          and float(rfilter.radius()) == 0.5)
        self.dist = None
        if not self.is_box:
            r = float(rfilter.radius())
            x = np.linspace(-r, r, TABLE_INTERVALS + 1)
            w = np.maximum(np.asarray(rfilter.eval(upload(mi.Float, x)), dtype=np.float64), 0.0)
            self.radius = r
            self.dist = mi.ContinuousDistribution(mi.ScalarVector2f(-r, r), upload(mi.Float, w))

    def bounds(self, p, n: int):
        """Per-lane constants for pixels ``p`` (mi.Float, column or row index) of a film ``n`` pixels wide:
        ``(lo, hi, cdf_lo, cdf_span)`` of the offset from the pixel centre. None for the box filter."""
        if self.is_box:
            return None
        r = self.radius
        if self.sample_border:
            lo, hi = dr.full(mi.Float, -r, dr.width(p)), dr.full(mi.Float, r, dr.width(p))
        else:
            lo = dr.maximum(-r, -(p + 0.5))
            hi = dr.minimum(r, n - (p + 0.5))
        c_lo = self.dist.eval_cdf_normalized(lo)
        c_hi = self.dist.eval_cdf_normalized(hi)
        return lo, hi, c_lo, c_hi - c_lo

    def sample(self, p, u, bounds):
        """Position (pixel units, film coordinates) of a sample of pixel ``p`` from the uniform number ``u``."""
        if bounds is None:
            return p + u
        lo, hi, c_lo, span = bounds
        off = dr.clip(self.dist.sample(dr.fma(u, span, c_lo)), lo, hi)
        return p + 0.5 + off
