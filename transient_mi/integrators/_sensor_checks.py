"""Which of a sensor's ``<sampler>`` and film ``<rfilter>`` the transient integrators honour.

Both checks are plain functions of the sensor, independent of any integrator class, so that every
transient integrator (``transient_path``, ``transient_nlos_path``) calls them at the top of its render
and refuses what it cannot honour with one :class:`~transient_mi.props.PluginParameterError` line.

Sampler
    The integrators draw their own random numbers: one PCG32 stream per SIMD lane, seeded from the
    render seed (:mod:`transient_mi.integrators._lanes`), which keeps every lane's histogram ownership
    and makes the same seed give the same bytes. Of the scene's ``<sampler>`` only ``sample_count`` is
    read. The ``independent`` sampler *is* this (independent uniform numbers), so it is the one
    accepted; a stratified or low-discrepancy sampler (``stratified``, ``multijitter``, ``ldsampler``,
    ``orthogonal``, any other) would be silently replaced by independent numbers, so it is refused.
    Variance reduction for NLOS captures: the NLOS integrator's ``rqmc`` option.

Reconstruction filter
    Camera sensors: the film's filter is honoured by filter importance sampling
    (:mod:`transient_mi.integrators._pixel_filter`), which needs a non-negative filter: ``box``,
    ``tent``, ``gaussian`` (and any other non-negative filter) are accepted, filters with negative lobes
    (``mitchell``, ``catmullrom``, ``lanczos``) refused. NLOS sensors (``spad_array``): a pixel is a
    physical wall patch integrated uniformly (a box); an ``rfilter`` other than ``box`` given
    explicitly in the scene is refused, the film's default (none given) is accepted and ignored.
"""

from __future__ import annotations

import mitsuba as mi
import numpy as np

from transient_mi._upload import upload
from transient_mi.props import PluginParameterError

#: Mitsuba class name -> plug-in name, for the messages.
SAMPLER_NAMES = {"IndependentSampler": "independent", "StratifiedSampler": "stratified",
                 "MultijitterSampler": "multijitter", "LowDiscrepancySampler": "ldsampler",
                 "OrthogonalSampler": "orthogonal"}
FILTER_NAMES = {"BoxFilter": "box", "TentFilter": "tent", "GaussianFilter": "gaussian",
                "MitchellNetravaliFilter": "mitchell", "CatmullRomFilter": "catmullrom",
                "LanczosSincFilter": "lanczos"}
#: Points (over ``[-radius, radius]``) at which a filter is checked for negative values.
NEGATIVE_CHECK_POINTS = 4097


def sampler_name(sampler) -> str:
    """The plug-in name of a Mitsuba sampler (``independent``, ``stratified``, ...; else its class name)."""
    cls = sampler.class_name()
    return SAMPLER_NAMES.get(cls, cls)


def filter_name(rfilter) -> str:
    """The plug-in name of a Mitsuba reconstruction filter (``box``, ``gaussian``, ...; else its class name)."""
    cls = rfilter.class_name()
    return FILTER_NAMES.get(cls, cls)


def is_nlos_sensor(sensor) -> bool:
    """Whether ``sensor`` records an NLOS capture (a ``spad_array``: it has a scene analysis)."""
    return hasattr(sensor, "nlos_setup")


def check_sampler(sensor, plugin_name: str) -> None:
    """Refuse any sampler but ``independent`` (see the module docstring)."""
    sampler = sensor.sampler()
    if sampler is None:
        return
    name = sampler_name(sampler)
    if name != "independent":
        raise PluginParameterError(
            f"{plugin_name}: sampler={name} is not supported; allowed: independent (the integrator draws "
            "its own per-lane PCG32 streams and reads only sample_count); for variance reduction use the "
            "NLOS integrator's rqmc option")


def negative_lobe(rfilter):
    """``(x, value)`` of the filter's most negative value on a fine grid over ``[-radius, radius]`` (pixels),
    or None if it is non-negative there."""
    r = float(rfilter.radius())
    x = np.linspace(-r, r, NEGATIVE_CHECK_POINTS)
    w = np.asarray(rfilter.eval(upload(mi.Float, x)), dtype=np.float64)
    i = int(np.argmin(w))
    return (float(x[i]), float(w[i])) if w[i] < 0 else None


def check_rfilter(sensor, plugin_name: str) -> None:
    """Refuse a reconstruction filter the integrator cannot honour (see the module docstring)."""
    film = sensor.film()
    rfilter = film.rfilter()
    if rfilter is None:
        return
    name = filter_name(rfilter)
    if is_nlos_sensor(sensor):
        if getattr(film, "rfilter_explicit", False) and name != "box":
            raise PluginParameterError(
                f"{plugin_name}: rfilter={name} given for the film of an NLOS sensor (spad_array); a pixel "
                "is a physical wall patch integrated uniformly: allowed: box, or no rfilter")
        return
    lobe = negative_lobe(rfilter)
    if lobe is not None:
        raise PluginParameterError(
            f"{plugin_name}: rfilter={name} has negative lobes (value {lobe[1]:.3g} at {lobe[0]:.3g} px), "
            "which filter importance sampling cannot represent; allowed: box, tent, gaussian "
            "(any non-negative filter)")
