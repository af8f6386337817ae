"""Emitter ``pulsed_laser``: a pulsed laser scanned over a grid of spots on the relay wall."""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from transient_core.units import photon_energy_j
from transient_mi.props import PluginParameterError, _has, get_float, get_int, get_vector3
from transient_mi.wall import WallFrame

PLUGIN = ("emitter", "pulsed_laser", "PulsedLaser")

#: Default repetition rate (Hz) and average power (W): a 1550 nm femtosecond
#: fibre laser at 50 MHz with 100 mW average power, i.e. 2 nJ per pulse
#: (about 1.56e10 photons per pulse).
DEFAULT_REPETITION_RATE_HZ = 50e6
DEFAULT_AVERAGE_POWER_W = 0.1
DEFAULT_WAVELENGTH_NM = 1550.0
#: Largest accepted beam divergence (1/e^2 half-angle), mrad: the Gaussian profile is defined in the
#: tangent plane of the beam axis, a small-angle description.
MAX_DIVERGENCE_MRAD = 100.0


class PulsedLaser(mi.Emitter):
    r"""Pulsed laser scanned over the relay wall (``pulsed_laser``).

    A collimated beam from ``origin``: each pulse deposits all its photons at
    one point of the wall, the laser spot ``S`` = the first surface the ray
    from ``origin`` towards a scan-grid point hits. The scan grid has
    ``spots_x`` x ``spots_y`` points ``spot_spacing_m`` apart, centred on
    ``target`` in the wall plane (the frame of :mod:`transient_mi.wall`, with
    normal ``wall_normal``); scan order is row-major (spot
    ``j = iy * spots_x + ix``, spot 0 has the smallest wall coordinates).

    The emitter is a delta in position and direction: Mitsuba's own
    integrators can neither hit nor sample it (it emits nothing for them).
    It is used by the ``spad_array`` sensor's NLOS estimator, which treats
    the lit spot as a point source (see :mod:`transient_mi.integrators.transient_nlos_path`).
    In a ``confocal`` capture the sensor aims the laser at each pixel's
    patch centre instead, and the scan grid is not used.

    ``mi.traverse`` exposes ``pulse_energy_j`` (J, a differentiable
    ``mi.Float``): the NLOS captures are linear in it, and
    :meth:`photons_per_pulse_ad` carries its gradient into differentiable
    NLOS renders (:mod:`transient_mi.integrators._nlos_ad`).
    ``params.update()`` after changing it updates ``pulse_energy_j``,
    ``average_power_w`` and ``photons_per_pulse``; a value <= 0 is refused
    in one line.

    Photons per pulse: ``N = pulse_energy_j / (h c / wavelength)``, with
    ``pulse_energy_j = average_power_w / repetition_rate_hz`` when the
    average power is given instead.

    Beam divergence (``divergence_mrad`` = ``theta_0`` > 0): the photons leave
    ``origin`` in the directions ``normalize(a + x e_1 + y e_2)``, with ``a`` the
    beam axis (towards the scan point), ``e_1, e_2`` orthonormal and
    perpendicular to it, and ``x, y`` independent normal variables of standard
    deviation ``sigma = theta_0 / 2`` (rad): a Gaussian angular profile
    ``I(theta) ~ exp(-2 theta^2 / theta_0^2)`` (small angles), ``theta_0``
    its 1/e^2 half-angle. The spot is then a footprint of 1/e^2 radius about
    ``|S - origin| tan(theta_0)`` (stretched by ``1 / cos`` of the incidence
    angle along the plane of incidence). The NLOS estimator samples a beam
    direction for every spot connection (unbiased) and integrates the
    wall's own return over the footprint with a fixed quadrature (see
    :mod:`transient_mi.integrators.transient_nlos_path`). 0 (default) is
    the collimated beam: every photon at the one spot ``S``.

    .. list-table::
       :header-rows: 1

       * - Parameter
         - Type
         - Description
       * - ``origin``
         - point
         - Laser position, metres (required); must be on the hidden-space
           side of the wall.
       * - ``target``
         - point
         - Centre of the scan grid, on the wall (required).
       * - ``wall_normal``
         - vector
         - Wall normal defining the scan plane (default 0, 0, 1); must agree
           with the ``spad_array``'s.
       * - ``spots_x``, ``spots_y``
         - integer
         - Scan grid size, >= 1 (default 1 x 1).
       * - ``spot_spacing_m``
         - float
         - Distance between neighbouring spots, metres; > 0 when there is
           more than one spot (default 0).
       * - ``scan_extent_m``
         - float
         - Alternative to ``spot_spacing_m``: side of the wall square the
           scan covers; spacing = ``scan_extent_m / max(spots_x, spots_y)``
           (spots at the centres of that many equal cells).
       * - ``pulse_energy_j``
         - float
         - Energy of one pulse, J, > 0. Alternatively give
           ``average_power_w``.
       * - ``average_power_w``
         - float
         - Average optical power, W, > 0 (default 0.1 W when
           ``pulse_energy_j`` is not given).
       * - ``repetition_rate_hz``
         - float
         - Pulse repetition rate, Hz, > 0 (default 50 MHz).
       * - ``wavelength_nm``
         - float
         - Vacuum wavelength, nm, > 0 (default 1550).
       * - ``divergence_mrad``
         - float
         - Beam divergence: 1/e^2 half-angle ``theta_0`` of the Gaussian
           angular profile, mrad, in [0, 100] (default 0: collimated).
    """

    NAME = "pulsed_laser"

    def __init__(self, props: mi.Properties):
        super().__init__(props)
        name = self.NAME
        self.m_flags = mi.EmitterFlags.DeltaPosition | mi.EmitterFlags.DeltaDirection
        self.origin = np.array(get_vector3(props, name, "origin", None))
        self.target = np.array(get_vector3(props, name, "target", None))
        normal = get_vector3(props, name, "wall_normal", (0.0, 0.0, 1.0))
        try:
            self.frame = WallFrame.from_normal(self.target, normal)
        except ValueError as e:
            raise PluginParameterError(f"{name}: {e}") from None
        if np.linalg.norm(self.target - self.origin) == 0:
            raise PluginParameterError(f"{name}: origin and target are the same point {tuple(self.origin)}")
        self.spots_x = get_int(props, name, "spots_x", 1, min_value=1, max_value=4096)
        self.spots_y = get_int(props, name, "spots_y", 1, min_value=1, max_value=4096)
        if "scan_extent_m" in props and "spot_spacing_m" in props:
            raise PluginParameterError(f"{name}: give spot_spacing_m or scan_extent_m, not both")
        if "scan_extent_m" in props:
            extent = get_float(props, name, "scan_extent_m", None, min_value=0.0, min_exclusive=True)
            self.spot_spacing_m = extent / max(self.spots_x, self.spots_y)
        else:
            self.spot_spacing_m = get_float(props, name, "spot_spacing_m", 0.0, min_value=0.0)
        if self.spots_x * self.spots_y > 1 and not self.spot_spacing_m > 0:
            raise PluginParameterError(
                f"{name}: spot_spacing_m={self.spot_spacing_m:g} must be > 0 with "
                f"{self.spots_x} x {self.spots_y} spots")
        self.wavelength_nm = get_float(props, name, "wavelength_nm", DEFAULT_WAVELENGTH_NM, min_value=0.0,
                                       min_exclusive=True)
        self.repetition_rate_hz = get_float(props, name, "repetition_rate_hz", DEFAULT_REPETITION_RATE_HZ,
                                            min_value=0.0, min_exclusive=True)
        has_e, has_p = _has(props, "pulse_energy_j"), _has(props, "average_power_w")
        if has_e and has_p:
            e = get_float(props, name, "pulse_energy_j", None, min_value=0.0, min_exclusive=True)
            p = get_float(props, name, "average_power_w", None, min_value=0.0, min_exclusive=True)
            if not math.isclose(e * self.repetition_rate_hz, p, rel_tol=1e-6):
                raise PluginParameterError(
                    f"{name}: pulse_energy_j={e:g} x repetition_rate_hz={self.repetition_rate_hz:g} = "
                    f"{e * self.repetition_rate_hz:g} W disagrees with average_power_w={p:g}; give only one of them")
            self.pulse_energy_j = e
        elif has_e:
            self.pulse_energy_j = get_float(props, name, "pulse_energy_j", None, min_value=0.0, min_exclusive=True)
        else:
            p = get_float(props, name, "average_power_w", DEFAULT_AVERAGE_POWER_W, min_value=0.0,
                          min_exclusive=True)
            self.pulse_energy_j = p / self.repetition_rate_hz
        self.average_power_w = self.pulse_energy_j * self.repetition_rate_hz
        self.photons_per_pulse = self.pulse_energy_j / photon_energy_j(self.wavelength_nm)
        self.divergence_mrad = get_float(props, name, "divergence_mrad", 0.0, min_value=0.0,
                                         max_value=MAX_DIVERGENCE_MRAD)

    @property
    def beam_sigma_rad(self) -> float:
        """Standard deviation (rad) of each tangent-plane component of the beam direction:
        ``divergence_mrad / 2 * 1e-3``."""
        return 0.5e-3 * self.divergence_mrad

    # ------------------------------------------------------------ queries

    def is_pulsed_laser(self) -> bool:
        """Marker used by the ``spad_array`` sensor (robust to plug-in reloading)."""
        return True

    @property
    def n_spots(self) -> int:
        return self.spots_x * self.spots_y

    def spot_targets(self) -> np.ndarray:
        """Scan-grid points in the wall plane, row-major, shape ``(spots_y * spots_x, 3)``, metres."""
        return self.frame.grid(self.spots_x, self.spots_y, self.spot_spacing_m).reshape(-1, 3)

    def laser_info(self) -> dict:
        """The manifest's ``laser`` entry."""
        return {
            "wavelength_nm": self.wavelength_nm,
            "pulse_energy_j": self.pulse_energy_j,
            "repetition_rate_hz": self.repetition_rate_hz,
            "average_power_w": self.average_power_w,
            "photons_per_pulse": self.photons_per_pulse,
            "origin": self.origin.tolist(),
            "target": self.target.tolist(),
            "spots_x": self.spots_x,
            "spots_y": self.spots_y,
            "spot_spacing_m": self.spot_spacing_m,
            **({"divergence_mrad": self.divergence_mrad} if self.divergence_mrad > 0 else {}),
        }

    # ---------------------------- Mitsuba interface: nothing to hit or sample
    # Dr.Jit traces every registered emitter when a kernel calls emitters indirectly (also for scenes
    # without this laser), so every method returns fully initialised (zero) values.

    def sample_ray(self, time, sample1, sample2, sample3, active=True):
        return dr.zeros(mi.Ray3f), dr.zeros(mi.Spectrum)

    def sample_direction(self, it, sample, active=True):
        ds = dr.zeros(mi.DirectionSample3f)
        ds.delta = mi.Bool(True)
        return ds, dr.zeros(mi.Spectrum)

    def pdf_direction(self, it, ds, active=True):
        return dr.zeros(mi.Float)

    def eval_direction(self, it, ds, active=True):
        return dr.zeros(mi.Spectrum)

    def eval(self, si, active=True):
        return dr.zeros(mi.Spectrum)

    def sample_position(self, time, sample, active=True):
        ps = dr.zeros(mi.PositionSample3f)
        ps.delta = mi.Bool(True)
        return ps, dr.zeros(mi.Float)

    def pdf_position(self, ps, active=True):
        return dr.zeros(mi.Float)

    def sample_wavelengths(self, si, sample, active=True):
        return dr.zeros(type(si.wavelengths)), dr.zeros(mi.Spectrum)

    def bbox(self):
        p = mi.ScalarPoint3f(*[float(c) for c in self.origin])
        return mi.ScalarBoundingBox3f(p, p)

    # -------------------------------- differentiable pulse energy (mi.traverse)

    def _energy_value(self):
        """The pulse energy as a Dr.Jit value (J), created on first use (the traversed parameter)."""
        if getattr(self, "pulse_energy", None) is None:
            self.pulse_energy = mi.Float(self.pulse_energy_j)
        return self.pulse_energy

    def photons_per_pulse_ad(self) -> "mi.Float":
        """Photons per pulse as a Dr.Jit value attached to the traversed ``pulse_energy_j`` (its gradient)."""
        return self._energy_value() * (1.0 / photon_energy_j(self.wavelength_nm))

    def traverse(self, callback):
        callback.put("pulse_energy_j", self._energy_value(), mi.ParamFlags.Differentiable)

    def parameters_changed(self, keys=None):
        v = self._energy_value()
        e = float(dr.detach(v)[0]) if dr.width(v) == 1 else float("nan")
        if not (e > 0 and math.isfinite(e)):
            raise PluginParameterError(f"{self.NAME}: pulse_energy_j={e:g} (width {dr.width(v)}) must be one "
                                       "finite value > 0")
        self.pulse_energy_j = e
        self.average_power_w = e * self.repetition_rate_hz
        self.photons_per_pulse = e / photon_energy_j(self.wavelength_nm)

    def to_string(self):
        return (f"PulsedLaser[origin={tuple(self.origin.tolist())}, target={tuple(self.target.tolist())}, "
                f"spots={self.spots_x}x{self.spots_y}, spot_spacing_m={self.spot_spacing_m:g}, "
                f"pulse_energy_j={self.pulse_energy_j:g}, wavelength_nm={self.wavelength_nm:g}]")
