"""Physical constants and unit conversions shared by rendering and recon.

Time is in picoseconds (``*_ps``), distance and optical path length (OPL) in
metres (``*_m``). The speed of light is exact by definition.
"""

from __future__ import annotations

#: Speed of light in vacuum, m/s (exact, SI definition).
SPEED_OF_LIGHT_M_PER_S = 299_792_458.0
#: Metres of optical path per picosecond (1 ps = 0.299792458 mm).
C_M_PER_PS = SPEED_OF_LIGHT_M_PER_S * 1e-12
#: Planck constant, J s (exact, SI definition).
PLANCK_J_S = 6.626_070_15e-34


def ps_to_m(t_ps):
    """Optical path length (m) travelled in ``t_ps`` picoseconds."""
    return t_ps * C_M_PER_PS


def m_to_ps(d_m):
    """Time (ps) light needs for ``d_m`` metres of optical path."""
    return d_m / C_M_PER_PS


def photon_energy_j(wavelength_nm: float) -> float:
    """Energy of one photon, J, at vacuum wavelength ``wavelength_nm``."""
    if not wavelength_nm > 0:
        raise ValueError(f"wavelength_nm={wavelength_nm!r} must be > 0")
    return PLANCK_J_S * SPEED_OF_LIGHT_M_PER_S / (wavelength_nm * 1e-9)


def photons_per_pulse(pulse_energy_j: float, wavelength_nm: float) -> float:
    """Number of photons in a pulse of ``pulse_energy_j`` joules."""
    return pulse_energy_j / photon_energy_j(wavelength_nm)
