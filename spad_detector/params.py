"""Detector parameters: one dataclass holding every knob of the SPAD + TCSPC model.

Defaults follow the reference experiment (``shared/PAPER.md``: a time-gated
SPAD array with one TCSPC channel per pixel, 1550 nm laser at 50 MHz):

==========================  ============  =====================================================
parameter                   default       meaning (units in the name)
==========================  ============  =====================================================
``pde``                     0.70          photon detection efficiency, probability in [0, 1]
``dark_count_rate_cps``     25.0          dark counts per second while the SPAD is armed
``ambient_rate_cps``        0.0           ambient background, *detected* counts per second
                                          (PDE already applied) while armed
``jitter_ps``               25.0          timing resolution = FWHM of the Gaussian jitter
                                          (sigma = FWHM / 2.3548)
``irf_tail_fraction``       0.0           fraction of detections with an extra exponential delay
``irf_tail_ps``             0.0           time constant of that exponential tail (ps)
``irf_file``                None          measured instrument response (replaces the two above
                                          and ``jitter_ps``): two columns ``time_ps, weight``
``gate_open_ps``            None          50 % point of the gate's rising edge (capture time axis)
``gate_close_ps``           None          50 % point of the falling edge; None/None = no gate
``gate_transition_ps``      120.0         10-90 % time of each gate edge
``auto_gate``               False         open the gate between the earliest and latest
                                          three-bounce arrivals (needs the capture geometry)
``auto_gate_depth_min_m``   0.1           hidden volume for ``auto_gate``: depth range in front
``auto_gate_depth_max_m``   1.5           of the relay wall, metres
``dead_time_ns``            10.0          SPAD hold-off after an avalanche (the paper gives none;
                                          10 ns is typical of SPAD array pixels)
``dead_time_model``         nonparalyzable  or ``paralyzable`` (a photon during the dead time
                                          restarts it)
``tcspc_max_count_rate_hz`` 20e6          TCSPC saturation: conversion dead time 1/rate
                                          (50 ns); None = unlimited
``afterpulse_prob``         0.0           probability that an avalanche is followed by an
                                          afterpulse once the SPAD re-arms
``afterpulse_delay_ns``     10.0          mean delay (exponential) of an afterpulse after re-arm
``crosstalk_prob``          0.0           probability that an avalanche triggers each of its 4
                                          nearest neighbours (same time)
``repetition_rate_hz``      None          laser repetition rate; None = from the capture
                                          manifest, else 50 MHz
``laser_power_w``           None          average laser power override (rescales the ideal data)
``wavelength_nm``           None          wavelength override (rescales photons per joule)
==========================  ============  =====================================================

The number of pulses, the seed and the engine are arguments of
:func:`~spad_detector.detect` / :func:`~spad_detector.detect_stack`,
not detector properties.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from transient_core.errors import UserInputError

#: Repetition rate used when neither the parameters nor the manifest give one (the paper's).
DEFAULT_REPETITION_RATE_HZ = 50e6
#: Number of laser pulses when neither ``pulses`` nor ``exposure_s`` is given.
DEFAULT_PULSES = 1_000_000
#: FWHM / sigma of a Gaussian: 2 sqrt(2 ln 2).
FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))
DEAD_TIME_MODELS = ("nonparalyzable", "paralyzable")
ENGINES = ("auto", "analytic", "exact")


@dataclass(frozen=True)
class DetectorParams:
    """Every parameter of the SPAD + TCSPC model (see the module docstring for the table).

    Call :meth:`validate` (done by every public entry point) to get a
    :class:`~transient_core.errors.UserInputError` naming a bad parameter, its value
    and the allowed range.
    """

    pde: float = 0.70
    dark_count_rate_cps: float = 25.0
    ambient_rate_cps: float = 0.0
    jitter_ps: float = 25.0
    irf_tail_fraction: float = 0.0
    irf_tail_ps: float = 0.0
    irf_file: str | None = None
    gate_open_ps: float | None = None
    gate_close_ps: float | None = None
    gate_transition_ps: float = 120.0
    auto_gate: bool = False
    auto_gate_depth_min_m: float = 0.1
    auto_gate_depth_max_m: float = 1.5
    dead_time_ns: float = 10.0
    dead_time_model: str = "nonparalyzable"
    tcspc_max_count_rate_hz: float | None = 20e6
    afterpulse_prob: float = 0.0
    afterpulse_delay_ns: float = 10.0
    crosstalk_prob: float = 0.0
    repetition_rate_hz: float | None = None
    laser_power_w: float | None = None
    wavelength_nm: float | None = None

    # ------------------------------------------------------------------ derived

    @property
    def jitter_sigma_ps(self) -> float:
        """Standard deviation of the Gaussian jitter, ps (``jitter_ps`` is its FWHM)."""
        return self.jitter_ps / FWHM_PER_SIGMA

    @property
    def tcspc_dead_time_ns(self) -> float:
        """Conversion dead time of the TCSPC, ns (``1e9 / tcspc_max_count_rate_hz``; 0 if unlimited)."""
        r = self.tcspc_max_count_rate_hz
        return 0.0 if r is None else 1e9 / r

    @property
    def has_gate(self) -> bool:
        return self.gate_open_ps is not None or self.gate_close_ps is not None or self.auto_gate

    # --------------------------------------------------------------- validation

    def validate(self) -> "DetectorParams":
        """Check every parameter; return ``self``.

        Raises
        ------
        UserInputError
            Naming the parameter, its value and what is allowed.
        """
        def num(name: str, lo: float | None = None, hi: float | None = None, *,
                lo_open: bool = False, hi_open: bool = False, optional: bool = False) -> None:
            v = getattr(self, name)
            if v is None and optional:
                return
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise UserInputError(f"{name}={v!r}: must be a finite number{_range(lo, hi, lo_open, hi_open)}")
            bad = (lo is not None and (v < lo or (lo_open and v == lo))) or \
                  (hi is not None and (v > hi or (hi_open and v == hi)))
            if bad:
                raise UserInputError(f"{name}={v!r}: allowed{_range(lo, hi, lo_open, hi_open)}")

        num("pde", 0.0, 1.0)
        num("dark_count_rate_cps", 0.0)
        num("ambient_rate_cps", 0.0)
        num("jitter_ps", 0.0)
        num("irf_tail_fraction", 0.0, 1.0)
        num("irf_tail_ps", 0.0)
        if self.irf_tail_fraction > 0 and self.irf_tail_ps <= 0:
            raise UserInputError(f"irf_tail_ps={self.irf_tail_ps!r}: must be > 0 when "
                                 f"irf_tail_fraction={self.irf_tail_fraction!r} > 0")
        if self.irf_file is not None:
            p = Path(self.irf_file)
            if not p.is_file():
                raise UserInputError(f"irf_file={str(self.irf_file)!r}: no such file")
        num("gate_open_ps", optional=True)
        num("gate_close_ps", optional=True)
        num("gate_transition_ps", 0.0)
        if not isinstance(self.auto_gate, bool):
            raise UserInputError(f"auto_gate={self.auto_gate!r}: must be true or false")
        if self.auto_gate and (self.gate_open_ps is not None or self.gate_close_ps is not None):
            raise UserInputError(
                f"auto_gate=True together with gate_open_ps={self.gate_open_ps!r}, "
                f"gate_close_ps={self.gate_close_ps!r}: give either explicit gate times or auto_gate, not both")
        if (self.gate_open_ps is None) != (self.gate_close_ps is None):
            raise UserInputError(
                f"gate_open_ps={self.gate_open_ps!r}, gate_close_ps={self.gate_close_ps!r}: "
                "give both gate times (or neither, for an ungated SPAD)")
        if self.gate_open_ps is not None and not self.gate_close_ps > self.gate_open_ps:
            raise UserInputError(
                f"gate_close_ps={self.gate_close_ps!r} <= gate_open_ps={self.gate_open_ps!r}: "
                "the gate must close after it opens")
        num("auto_gate_depth_min_m", 0.0, lo_open=True)
        num("auto_gate_depth_max_m", 0.0, lo_open=True)
        if not self.auto_gate_depth_max_m > self.auto_gate_depth_min_m:
            raise UserInputError(
                f"auto_gate_depth_max_m={self.auto_gate_depth_max_m!r} must be > "
                f"auto_gate_depth_min_m={self.auto_gate_depth_min_m!r}")
        num("dead_time_ns", 0.0)
        if self.dead_time_model not in DEAD_TIME_MODELS:
            raise UserInputError(f"dead_time_model={self.dead_time_model!r}: allowed {', '.join(DEAD_TIME_MODELS)}")
        num("tcspc_max_count_rate_hz", 0.0, lo_open=True, optional=True)
        num("afterpulse_prob", 0.0, 1.0, hi_open=True)
        num("afterpulse_delay_ns", 0.0, lo_open=True)
        num("crosstalk_prob", 0.0, 1.0)
        num("repetition_rate_hz", 0.0, lo_open=True, optional=True)
        num("laser_power_w", 0.0, lo_open=True, optional=True)
        num("wavelength_nm", 0.0, lo_open=True, optional=True)
        return self

    # ------------------------------------------------------------ conversions

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-serialisable dictionary of every parameter (for manifests)."""
        d = dataclasses.asdict(self)
        d["jitter_convention"] = "FWHM"
        d["jitter_sigma_ps"] = self.jitter_sigma_ps
        d["tcspc_dead_time_ns"] = self.tcspc_dead_time_ns
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "DetectorParams":
        """Build from a mapping, ignoring derived keys written by :meth:`to_dict`.

        Unknown keys raise :class:`UserInputError` (listing the known ones).
        """
        names = {f.name for f in dataclasses.fields(cls)}
        derived = {"jitter_convention", "jitter_sigma_ps", "tcspc_dead_time_ns"}
        unknown = sorted(set(d) - names - derived)
        if unknown:
            raise UserInputError(f"unknown detector parameter(s) {', '.join(unknown)}; "
                                 f"known: {', '.join(sorted(names))}")
        return cls(**{k: v for k, v in d.items() if k in names})

    def replace(self, **changes: Any) -> "DetectorParams":
        """A copy with some parameters changed (not validated)."""
        return dataclasses.replace(self, **changes)


def param_names() -> list[str]:
    """Names of all :class:`DetectorParams` fields, in declaration order."""
    return [f.name for f in dataclasses.fields(DetectorParams)]


def _range(lo, hi, lo_open, hi_open) -> str:
    if lo is None and hi is None:
        return ""
    if hi is None:
        return f" {'>' if lo_open else '>='} {lo:g}"
    if lo is None:
        return f" {'<' if hi_open else '<='} {hi:g}"
    return f" in {'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
