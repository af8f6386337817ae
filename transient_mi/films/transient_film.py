"""Film ``transient_film``: a time-binned image (one histogram per pixel)."""

from __future__ import annotations

from dataclasses import dataclass

import mitsuba as mi
import numpy as np

from transient_mi._upload import upload_tensor
from transient_mi.props import PluginParameterError, get_choice, get_float, get_int
from transient_mi.time_axis import TimeAxis, gaussian_kernel_taps

PLUGIN = ("film", "transient_film", "TransientFilm")


@dataclass
class TransientResult:
    """What a transient render produced for one laser spot (or a camera view).

    Attributes
    ----------
    histogram : ndarray of float32, shape ``(height, width, n_bins)`` or ``(height, width, n_bins, n_channels)``
        Per-pixel histogram over time. Camera renders: radiance integrated
        over each bin (summing the bins gives the steady-state radiance).
        NLOS captures: expected photons per laser pulse per bin.
    steady : ndarray of float32, shape ``(height, width)`` (``(height, width, n_channels)``)
        Time-integrated value of every contribution, including those
        outside the film's time range.
    dropped_contributions : int
        Number of path contributions whose arrival time fell outside
        ``[t0_ps, t0_ps + n_bins * bin_width_ps)`` (or was undefined, for
        infinitely distant emitters); they are not in ``histogram``.
    dropped_fraction : float
        Their share of the steady-state total (0 when the total is 0).
    samples : int
        Paths traced (pixels x samples per pixel).
    variance : ndarray of float32, shape ``(height, width, n_bins)``, or None
        Estimated variance of every value of ``histogram`` (the Monte Carlo
        error of the render, squared), from ``replicates`` independent
        replicates (:mod:`transient_mi.integrators._replicates`); None when
        the render used a single replicate.
    total_variance : ndarray of float64, shape ``(height, width)``, or None
        Estimated variance of each pixel's in-range total (sum over time).
    replicates : int
        Independent replicates the estimate averages (>= 1).
    invalid_contributions : int
        Contributions whose path length was NaN or ``-inf`` (or whose value
        was NaN): a bug, kept out of every other number and reported.
    error_bound : ndarray of float32, shape ``(height, width, n_bins)``, or None
        Deterministic estimators (``estimator="quadrature"``): a bound on the
        absolute error of every value of ``histogram`` (same unit), in place of
        a variance (see :mod:`transient_mi.integrators._nlos_quadrature`).
    total_error_bound : ndarray of float32, shape ``(height, width)``, or None
        A bound on the error of each pixel's total over time.
    estimator_info : dict or None
        What the deterministic estimator used (elements, refinement levels, pairs).
    negative_fraction : float
        The most negative raw dropped fraction seen (0 when none was below
        ``-1e-5``): more light in the histogram than recorded, a bug.
    error_parts : dict of str to ndarray, or None
        The quadrature's ``error_bound`` by part (``visibility``, ``elements``, ``cells``; float64, each shaped as
        ``error_bound``, summing to it), when the render was asked for them (``render --noise-target``'s
        refinement, :func:`transient_mi.integrators._nlos_quadrature.error_parts`).
    """

    histogram: np.ndarray
    steady: np.ndarray
    dropped_contributions: int
    dropped_fraction: float
    samples: int
    variance: np.ndarray | None = None
    total_variance: np.ndarray | None = None
    replicates: int = 1
    invalid_contributions: int = 0
    negative_fraction: float = 0.0
    error_bound: np.ndarray | None = None
    total_error_bound: np.ndarray | None = None
    estimator_info: dict | None = None
    error_parts: dict | None = None


#: Wavelength range Mitsuba's spectral variants sample (nm)
SPECTRAL_RANGE_NM = (360, 830)


def _read_bands(props, name: str, channels: str) -> list[int] | None:
    """The ``spectral_bands_nm`` edges (whole nm, increasing, in :data:`SPECTRAL_RANGE_NM`), or None."""
    if "spectral_bands_nm" not in props:
        return None
    v = props.get("spectral_bands_nm")
    if isinstance(v, str) and not v.strip():
        return None  # empty: no bands (lets a scene expose the parameter with an empty default)
    allowed = (f"allowed: at least two increasing whole-nanometre edges within {SPECTRAL_RANGE_NM[0]}.."
               f"{SPECTRAL_RANGE_NM[1]}, comma-separated, e.g. \"400, 500, 600, 700\"")
    if not (mi.is_spectral and not mi.is_polarized):
        raise PluginParameterError(f"{name}: spectral_bands_nm={v!r} needs a *_spectral variant (the active one is "
                                   f"{mi.variant()}, which records no wavelengths)")
    if channels == "mono":
        raise PluginParameterError(f"{name}: spectral_bands_nm={v!r} with channels='mono': the bands are channels; "
                                   "leave channels at 'auto'")
    try:
        edges = [float(x) for x in str(v).replace(";", ",").split(",")]
    except ValueError:
        raise PluginParameterError(f"{name}: spectral_bands_nm={v!r}; {allowed}") from None
    ok = len(edges) >= 2 and all(e == int(e) for e in edges) and \
        all(a < b for a, b in zip(edges, edges[1:])) and \
        SPECTRAL_RANGE_NM[0] <= edges[0] and edges[-1] <= SPECTRAL_RANGE_NM[1]
    if not ok:
        raise PluginParameterError(f"{name}: spectral_bands_nm={v!r}; {allowed}")
    return [int(e) for e in edges]


class TransientFilm(mi.Film):
    r"""Transient film (``transient_film``).

    Stores, for every pixel, a histogram of the light arriving over time.
    Works under any sensor: a perspective camera gives a transient video, a
    ``spad_array`` an NLOS capture. Render it with the ``transient_path``
    integrator (cameras) or ``transient_nlos_path`` (``spad_array``).

    .. list-table::
       :header-rows: 1

       * - Parameter
         - Type
         - Description
       * - ``width``, ``height``
         - integer
         - Pixels (default 64 x 64).
       * - ``n_bins``
         - integer
         - Number of time bins, >= 1 (default 1024).
       * - ``bin_width_ps``
         - float
         - Width of one bin in picoseconds, > 0 (default 10).
       * - ``t0_ps``
         - float
         - Start of bin 0, picoseconds after the light left the emitter
           (default 0). Bin ``b`` covers
           ``[t0_ps + b bin_width_ps, t0_ps + (b + 1) bin_width_ps)``; an
           arrival exactly on a boundary goes to the later bin.
       * - ``channels``
         - string
         - ``auto`` (default): what the variant carries, per bin --
           ``R``, ``G``, ``B`` in ``*_rgb`` and ``*_spectral`` variants
           (linear sRGB, as Mitsuba's films), the Stokes vector ``S0``..``S3``
           in the sensor's frame in ``*_polarized`` variants (as Mitsuba's
           ``stokes`` integrator; spectral-polarized: of the luminance);
           ``mono``: one value per bin (luminance Y, or S0). NLOS sensors
           (``spad_array``) record one intensity (the detector's).
       * - ``spectral_bands_nm``
         - string
         - ``*_spectral`` variants only: band edges in whole nanometres,
           increasing, within Mitsuba's sampled range 360..830, e.g.
           ``"400, 500, 600, 700"``. The film then records one channel per
           band instead of R, G, B, named ``400-500nm``, ``500-600nm``, ...:
           the radiance integrated over the band, ``int_lo^hi L(lambda)
           dlambda`` (W m^-2 sr^-1 of the band for a camera). Each sampled
           wavelength's weight (``1 / pdf``) goes to the band it falls in, so
           each band is an unbiased estimate. Default: none (R, G, B; an
           empty string also means none).
       * - ``kernel_sigma_ps``
         - float
         - Standard deviation (ps) of an optional Gaussian temporal kernel
           applied along time, >= 0 (default 0: none). Taps are the
           Gaussian integrated over each bin, renormalised to sum to 1, so
           the kernel conserves energy (it adds ``sigma^2 + bin_width^2/12``
           to the arrival-time variance); contributions up to 5 sigma outside
           the time range still blur into it.

    Reconstruction filter (``rfilter`` child, Mitsuba's default ``gaussian``
    when none is given): under a camera sensor the ``transient_path``
    integrator honours it by filter importance sampling (each sample's
    offset from its pixel centre is drawn from the filter, so a pixel
    converges to the filter-weighted average that Mitsuba's films give, at
    the edges too, with or without ``sample_border``, see
    :mod:`transient_mi.integrators._pixel_filter`); ``box`` is the uniform
    draw in the pixel; filters with negative lobes are refused. Under a
    ``spad_array`` a pixel is a wall patch integrated uniformly: an
    ``rfilter`` other than ``box`` given explicitly is refused, the default
    is ignored (:mod:`transient_mi.integrators._sensor_checks`). Contributions arriving
    outside the time range are dropped and counted
    (:attr:`TransientResult.dropped_contributions`).

    Axis order of the developed data: ``[pixel_y, pixel_x, time]``.
    """

    NAME = "transient_film"

    def __init__(self, props: mi.Properties):
        #: True when the scene gives an ``rfilter`` child (False: Mitsuba's default filter)
        self.rfilter_explicit = any(isinstance(obj, mi.ReconstructionFilter) for _, obj in props.objects())
        super().__init__(props)
        name = self.NAME
        self.n_bins = get_int(props, name, "n_bins", 1024, min_value=1, max_value=1 << 20)
        self.bin_width_ps = get_float(props, name, "bin_width_ps", 10.0, min_value=0.0, min_exclusive=True)
        self.t0_ps = get_float(props, name, "t0_ps", 0.0)
        self.kernel_sigma_ps = get_float(props, name, "kernel_sigma_ps", 0.0, min_value=0.0)
        self.channels = get_choice(props, name, "channels", "auto", ("auto", "mono"))
        self.spectral_bands_nm = _read_bands(props, name, self.channels)
        size = self.size()
        self.width, self.height = int(size[0]), int(size[1])
        if self.width < 1 or self.height < 1:
            raise PluginParameterError(f"{name}: width={self.width}, height={self.height} must be >= 1")
        crop, off = self.crop_size(), self.crop_offset()
        if (int(crop[0]), int(crop[1]), int(off[0]), int(off[1])) != (self.width, self.height, 0, 0):
            raise PluginParameterError(
                f"{name}: crop_offset_x={int(off[0])}, crop_offset_y={int(off[1])}, crop_width={int(crop[0])}, "
                f"crop_height={int(crop[1])}: crop windows are not supported (the film renders every pixel); "
                "allowed: no crop_* parameters (render a smaller width/height instead)")
        self.result: TransientResult | None = None

    # ------------------------------------------------------------------ queries

    def time_axis(self) -> TimeAxis:
        """The film's :class:`~transient_mi.time_axis.TimeAxis`."""
        return TimeAxis(self.t0_ps, self.bin_width_ps, self.n_bins)

    def channel_names(self) -> tuple[str, ...] | None:
        """Channels recorded per time bin: None (one value) for ``channels="mono"`` or a ``*_mono``
        variant, else the variant's (``R, G, B`` or ``S0..S3``, see
        :func:`transient_mi.integrators._lanes.variant_channels`)."""
        from transient_mi.integrators._lanes import variant_channels

        if self.channels == "mono":
            return None
        if self.spectral_bands_nm is not None:
            from transient_core.stack import band_name

            e = self.spectral_bands_nm
            return tuple(band_name(e[i], e[i + 1]) for i in range(len(e) - 1))
        return variant_channels()

    def kernel_taps(self) -> np.ndarray:
        """Taps of the temporal kernel (``[1.0]`` when there is none)."""
        return gaussian_kernel_taps(self.kernel_sigma_ps, self.bin_width_ps)

    def is_transient(self) -> bool:
        """Marker used by the integrators (robust to plug-in reloading)."""
        return True

    # --------------------------------------------------------------- results

    def set_result(self, result: TransientResult | None) -> None:
        """Store the result of the last render (called by the integrator)."""
        self.result = result

    def develop(self, raw: bool = False):
        """The last render's histograms as ``mi.TensorXf [height, width, n_bins]``."""
        if self.result is None:
            raise RuntimeError(f"{self.NAME}: nothing rendered yet (render with the transient_path or transient_nlos_path integrator)")
        return upload_tensor(self.result.histogram)

    # Mitsuba's C++ integrators would call these; they cannot fill a transient film.
    def prepare(self, aovs):
        raise RuntimeError(
            f"{self.NAME} must be rendered with the transient_path integrator (or transient_nlos_path under a "
            "spad_array; Mitsuba's own integrators do not record path lengths)"
        )

    def to_string(self):
        return (f"TransientFilm[size={self.width}x{self.height}, n_bins={self.n_bins}, "
                f"bin_width_ps={self.bin_width_ps:g}, t0_ps={self.t0_ps:g}, "
                f"kernel_sigma_ps={self.kernel_sigma_ps:g}]")
