"""Multiple importance sampling weights: the primal integrators' and their AD replays' one definition.

``transient_path`` and ``transient_volpath`` weight emitter sampling against BSDF (or phase-function)
sampling with the power heuristic of Mitsuba's ``path`` and ``volpath``; the replays of the derivative
passes (:mod:`._ad`, :mod:`._ad_geometry`, :mod:`._ad_volpath`) use the same weight, detached (sampling
densities are not differentiated). Below all of them, so none imports another for it.
"""

from __future__ import annotations

import drjit as dr


def mis_weight(pdf_a, pdf_b):
    """Power heuristic (as Mitsuba's ``path``)."""
    a2 = dr.square(pdf_a)
    w = a2 / (a2 + dr.square(pdf_b))
    return dr.select(dr.isfinite(w), w, 0)


def detached_mis_weight(pdf_a, pdf_b):
    """The primal's MIS weight (:func:`mis_weight`), detached: what the AD replays weight with."""
    return dr.detach(mis_weight(pdf_a, pdf_b))
