"""What ``transient_volpath`` and its AD replay (:mod:`._ad_volpath`) share about participating media."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi


def index_spectrum(spec, channel):
    """Component ``channel`` of a spectrum (RGB: the sampled colour channel; mono/spectral: the first)."""
    s = mi.unpolarized_spectrum(spec)
    if mi.is_rgb:
        return dr.select(channel == 0, s[0], dr.select(channel == 1, s[1], s[2]))
    return s[0]
