"""Optical path length through refracting interfaces: a segment inside a medium of index n takes n d / c.

The integrators track ``eta``, the product of the relative indices ``bs.eta`` of every transmission
sampled so far (as Mitsuba's ``path`` does for Russian roulette): it is the refractive index of the
medium the path is in, relative to the medium the sensor (or, for NLOS captures, the relay wall) sits
in, which counts as index 1 (vacuum: c = 299 792 458 m/s; the default exterior of Mitsuba's dielectrics
is air, n = 1.000277, so an interior index is taken relative to it). A BSDF-sampled segment adds
``eta * length`` to the optical path; reflections (``bs.eta = 1``) keep the index. Thin dielectric sheets
(``thindielectric``) have no thickness and add no delay. A next-event connection that transmits through
a rough dielectric (``roughdielectric``; smooth ``dielectric`` is a delta BSDF and is never connected)
lies on the far side of the interface: :func:`segment_index` gives its index.

Mitsuba's participating media carry no refractive index; light crosses them at the speed of the medium
their bounding dielectric gives (or c when they are bounded by ``null`` interfaces).
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi


def segment_index(bsdf, si, wo_local, eta, active):
    """Relative refractive index of the segment leaving ``si`` in direction ``wo_local`` (local frame).

    ``eta`` is the index the path is in (on the side of ``si.wi``). A direction on the other side of the
    surface (a transmission) enters the medium behind it: index ``eta * eta_b`` when entering the
    interior (``cos theta_i > 0``) and ``eta / eta_b`` when leaving it, with ``eta_b`` the BSDF's
    interior/exterior ratio (its ``eta`` attribute). BSDFs without that attribute (opaque ones, which
    do not transmit) keep ``eta``.
    """
    cos_i = mi.Frame3f.cos_theta(si.wi)
    cos_o = mi.Frame3f.cos_theta(wo_local)
    transmits = active & (cos_i * cos_o < 0)
    eta_b = bsdf.eval_attribute_1("eta", si, transmits)
    ratio = dr.select(cos_i > 0, eta_b, dr.rcp(eta_b))
    return dr.select(transmits & (eta_b > 0), eta * ratio, eta)
