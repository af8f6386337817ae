"""Photon budget: how many laser pulses, and how many photons each carries.

* Pulses: ``pulses`` directly, or ``exposure_s x repetition_rate_hz`` (rounded
  to the nearest integer), or :data:`~spad_detector.params.DEFAULT_PULSES`.
* Repetition rate: ``params.repetition_rate_hz``, else the capture's
  ``laser.repetition_rate_hz``, else 50 MHz.
* Laser overrides: the ideal capture stores expected photons per pulse for
  the laser in its manifest (``laser.photons_per_pulse``). Overriding the
  average power, the wavelength or the repetition rate rescales the ideal data
  by ``photons_per_pulse_new / photons_per_pulse_manifest`` with
  ``photons_per_pulse = (average_power_w / repetition_rate_hz) / (h c / wavelength)``.
  The average power is held fixed when only the repetition rate changes
  (a laser is specified by its average power; its pulse energy follows).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field

from transient_core.errors import UserInputError
from transient_core.units import photons_per_pulse

from .params import DEFAULT_PULSES, DEFAULT_REPETITION_RATE_HZ, DetectorParams


@dataclass(frozen=True)
class Budget:
    """Resolved photon budget.

    Attributes
    ----------
    n_pulses : int
        Laser pulses (TCSPC cycles) integrated into each histogram.
    repetition_rate_hz : float
        Laser repetition rate; the cycle period is ``1e12 / repetition_rate_hz`` ps.
    exposure_s : float
        ``n_pulses / repetition_rate_hz``: acquisition time per laser spot.
    photon_scale : float
        Factor applied to the ideal data (1 unless the laser is overridden).
    laser : dict or None
        The laser block for the counts manifest (overrides applied).
    """

    n_pulses: int
    repetition_rate_hz: float
    exposure_s: float
    photon_scale: float = 1.0
    laser: dict | None = field(default=None)

    @property
    def period_ps(self) -> float:
        """Laser period (one TCSPC cycle), ps."""
        return 1e12 / self.repetition_rate_hz


def _pos(v, name=None):
    try:
        x = float(v)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) and x > 0 else None


def resolve_budget(params: DetectorParams, laser: dict | None = None, *, pulses=None,
                   exposure_s=None) -> Budget:
    """Resolve pulses, repetition rate and photon scale.

    Parameters
    ----------
    params : DetectorParams
        Supplies the optional overrides ``repetition_rate_hz``,
        ``laser_power_w`` and ``wavelength_nm``.
    laser : dict, optional
        The ideal capture's ``laser`` manifest block.
    pulses : int, optional
        Number of pulses (mutually exclusive with ``exposure_s``).
    exposure_s : float, optional
        Exposure time per laser spot, seconds.

    Raises
    ------
    UserInputError
        Both or invalid ``pulses``/``exposure_s``, or an override that the
        manifest cannot support (no ``photons_per_pulse`` to rescale).
    """
    laser = dict(laser) if isinstance(laser, dict) else None
    if pulses is not None and exposure_s is not None:
        raise UserInputError(f"pulses={pulses!r} and exposure_s={exposure_s!r}: give one of them, not both")
    man_rate = _pos((laser or {}).get("repetition_rate_hz"), "repetition_rate_hz")
    rate = params.repetition_rate_hz or man_rate or DEFAULT_REPETITION_RATE_HZ
    if pulses is not None:
        if isinstance(pulses, bool) or not isinstance(pulses, numbers.Integral) and not (
                isinstance(pulses, float) and pulses.is_integer()):
            raise UserInputError(f"pulses={pulses!r}: must be a whole number >= 1")
        n = int(pulses)
        if n < 1:
            raise UserInputError(f"pulses={pulses!r}: must be >= 1")
    elif exposure_s is not None:
        if isinstance(exposure_s, bool) or not isinstance(exposure_s, numbers.Real) or \
                not math.isfinite(exposure_s) or exposure_s <= 0:
            raise UserInputError(f"exposure_s={exposure_s!r}: must be a finite number > 0 (seconds)")
        n = int(round(exposure_s * rate))
        if n < 1:
            raise UserInputError(
                f"exposure_s={exposure_s!r} at repetition_rate_hz={rate:g} is {exposure_s * rate:.3g} pulses: "
                "need at least 1")
    else:
        n = DEFAULT_PULSES
    if n > 2**62:
        raise UserInputError(f"pulses={n}: at most 2**62 pulses are supported")

    scale = 1.0
    overrides = {k: getattr(params, k) for k in ("laser_power_w", "wavelength_nm") if getattr(params, k) is not None}
    rate_changed = params.repetition_rate_hz is not None and man_rate is not None and \
        not math.isclose(params.repetition_rate_hz, man_rate, rel_tol=1e-12)
    out_laser = dict(laser) if laser is not None else None
    if overrides or rate_changed:
        what = ", ".join(f"{k}={v!r}" for k, v in {**overrides, **(
            {"repetition_rate_hz": params.repetition_rate_hz} if rate_changed else {})}.items())
        if laser is None:
            raise UserInputError(f"{what}: the ideal capture has no laser block in its manifest, "
                                 "so its photons per pulse cannot be rescaled")
        n0 = _pos(laser.get("photons_per_pulse"), "photons_per_pulse")
        if n0 is None:
            raise UserInputError(f"{what}: the capture's laser.photons_per_pulse="
                                 f"{laser.get('photons_per_pulse')!r} is not a positive number; cannot rescale")
        wl = params.wavelength_nm or _pos(laser.get("wavelength_nm"), "wavelength_nm")
        if wl is None:
            raise UserInputError(f"{what}: the capture's laser.wavelength_nm={laser.get('wavelength_nm')!r} "
                                 "is not usable; give wavelength_nm")
        power = params.laser_power_w or _pos(laser.get("average_power_w"), "average_power_w")
        if power is None:
            e0 = _pos(laser.get("pulse_energy_j"), "pulse_energy_j")
            power = e0 * (man_rate or rate) if e0 is not None else None
        if power is None:
            raise UserInputError(f"{what}: the capture's laser has neither average_power_w nor "
                                 "pulse_energy_j; give laser_power_w")
        energy = power / rate
        n1 = photons_per_pulse(energy, wl)
        scale = n1 / n0
        out_laser.update(wavelength_nm=wl, average_power_w=power, repetition_rate_hz=rate,
                         pulse_energy_j=energy, photons_per_pulse=n1)
    elif out_laser is not None and man_rate is None:
        out_laser["repetition_rate_hz"] = rate
    return Budget(n_pulses=n, repetition_rate_hz=float(rate), exposure_s=n / rate,
                  photon_scale=float(scale), laser=out_laser)
