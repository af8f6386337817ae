"""Film ``spad_film``: a ``transient_film`` whose output is photon counts (SPAD + TCSPC model)."""

from __future__ import annotations

from transient_mi.films.transient_film import TransientFilm
from transient_mi.props import PluginParameterError, get_bool, get_choice, get_float, get_int

from transient_core.errors import UserInputError

PLUGIN = ("film", "spad_film", "SpadFilm")

# (property name, kind, default) for every detector parameter; names = `transient-mi detect` options.
_FLOATS = ("pde", "dark_count_rate_cps", "ambient_rate_cps", "jitter_ps", "irf_tail_fraction", "irf_tail_ps",
           "gate_transition_ps", "auto_gate_depth_min_m", "auto_gate_depth_max_m", "dead_time_ns",
           "afterpulse_prob", "afterpulse_delay_ns", "crosstalk_prob")
_OPTIONAL_FLOATS = ("gate_open_ps", "gate_close_ps", "repetition_rate_hz", "laser_power_w", "wavelength_nm")


class SpadFilm(TransientFilm):
    r"""SPAD film (``spad_film``).

    A :class:`~transient_mi.films.transient_film.TransientFilm` (same
    ``width``, ``height``, ``n_bins``, ``bin_width_ps``, ``t0_ps``,
    ``kernel_sigma_ps``) that also describes the detector, so that a scene
    file alone defines a photon-counting capture. ``transient-mi render``
    renders the ideal capture (expected photons per pulse) into
    ``OUT/ideal/`` and runs the detector model
    (:func:`spad_detector.detect_stack`) to write the counts capture
    into ``OUT/``; ``transient-mi detect OUT/ideal -o ...`` reruns detection
    with other settings without re-rendering.

    The properties have the names of ``transient-mi detect``'s options (dashes
    become underscores); units are in the names; defaults are the reference
    paper's (see ``docs/detector.md``).

    .. list-table::
       :header-rows: 1

       * - Parameter
         - Type
         - Description
       * - ``pulses``
         - integer
         - Laser pulses per spot (default 1e6); or ``exposure_s`` (float,
           seconds; pulses = exposure x repetition rate). Not both.
       * - ``pde``
         - float
         - Photon detection efficiency in [0, 1] (default 0.7).
       * - ``dark_count_rate_cps``, ``ambient_rate_cps``
         - float
         - Dark counts (default 25) and detected ambient counts (default 0) per second.
       * - ``jitter_ps``
         - float
         - Timing resolution, FWHM of the Gaussian jitter (default 25 ps).
       * - ``irf_tail_fraction``, ``irf_tail_ps``, ``irf_file``
         - float, float, string
         - Exponential IRF tail (weight, time constant) or a measured IRF file.
       * - ``gate_open_ps``, ``gate_close_ps``, ``gate_transition_ps``
         - float
         - Gate 50 % points and 10-90 % transition (default 120 ps); no
           gate when the times are absent.
       * - ``auto_gate``
         - boolean
         - Gate on the hidden volume's three-bounce arrivals
           (``auto_gate_depth_min_m``/``auto_gate_depth_max_m``, default 0.1/1.5 m).
       * - ``dead_time_ns``, ``dead_time_model``
         - float, string
         - SPAD dead time (default 10 ns), ``nonparalyzable`` or ``paralyzable``.
       * - ``tcspc_max_count_rate_hz``
         - float
         - TCSPC maximum count rate (default 20e6; 0 = unlimited).
       * - ``afterpulse_prob``, ``afterpulse_delay_ns``
         - float
         - Afterpulsing probability (default 0) and mean delay after re-arming (default 10 ns).
       * - ``crosstalk_prob``
         - float
         - Crosstalk probability per 4-neighbour per avalanche (default 0).
       * - ``repetition_rate_hz``, ``laser_power_w``, ``wavelength_nm``
         - float
         - Laser overrides (default: the emitter's).
       * - ``seed``
         - integer
         - Seed of the detection noise (default: derived from the render's
           ``--seed``, so one seed fixes the whole capture).
       * - ``engine``
         - string
         - ``auto`` (default), ``analytic`` or ``exact``.

    Every parameter is validated here, when the scene loads.
    """

    NAME = "spad_film"

    def __init__(self, props):
        super().__init__(props)
        from spad_detector.budget import resolve_budget
        from spad_detector.params import DEAD_TIME_MODELS, ENGINES, DetectorParams

        name = self.NAME
        kw = {}
        for key in _FLOATS:
            if key in props:
                kw[key] = get_float(props, name, key, None)
        for key in _OPTIONAL_FLOATS:
            if key in props:
                kw[key] = get_float(props, name, key, None)
        if "tcspc_max_count_rate_hz" in props:
            r = get_float(props, name, "tcspc_max_count_rate_hz", None, min_value=0.0)
            kw["tcspc_max_count_rate_hz"] = None if r == 0 else r
        if "irf_file" in props:
            v = props.get("irf_file")
            if not isinstance(v, str) or not v:
                raise PluginParameterError(f"{name}: irf_file={v!r} must be a file name (<string .../>)")
            kw["irf_file"] = v
        kw["auto_gate"] = get_bool(props, name, "auto_gate", False)
        kw["dead_time_model"] = get_choice(props, name, "dead_time_model", "nonparalyzable", DEAD_TIME_MODELS)
        self.pulses = self._whole(props, "pulses")
        self.exposure_s = get_float(props, name, "exposure_s", None, min_value=0.0, min_exclusive=True) \
            if "exposure_s" in props else None
        # None: derived from the render's --seed by the pipeline (see detect_kwargs)
        self.seed = get_int(props, name, "seed", -1, min_value=0, max_value=2**63 - 1) if "seed" in props else None
        self.engine = get_choice(props, name, "engine", "auto", ENGINES)
        try:
            self.params = DetectorParams(**kw).validate()
            # pulses / exposure_s checks (the laser is only known at render time)
            resolve_budget(self.params.replace(laser_power_w=None, wavelength_nm=None), None,
                           pulses=self.pulses, exposure_s=self.exposure_s)
        except UserInputError as e:
            raise PluginParameterError(f"{name}: {e}") from None

    def _whole(self, props, key):
        if key not in props:
            return None
        v = props.get(key)
        if isinstance(v, float) and v.is_integer():
            v = int(v)
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise PluginParameterError(f"{self.NAME}: {key}={v!r} must be a whole number >= 1")
        return v

    # ------------------------------------------------------------------ queries

    def detector_params(self):
        """The film's :class:`~spad_detector.DetectorParams` (validated)."""
        return self.params

    def detector_pulses(self):
        """``(pulses, exposure_s)`` as given (None when absent; default 1e6 pulses)."""
        return self.pulses, self.exposure_s

    def detector_seed(self, render_seed: int = 0) -> int:
        """The detector's seed: the ``seed`` property, else derived from the render seed."""
        if self.seed is not None:
            return self.seed
        import numpy as np

        return int(np.random.SeedSequence([int(render_seed), 0x5BAD]).generate_state(1, dtype=np.uint32)[0])

    def detect_kwargs(self, render_seed: int = 0) -> dict:
        """Keyword arguments of :func:`spad_detector.detect_stack` for this film.

        ``render_seed``: the render's seed, from which the detection seed is
        derived when the film has no ``seed`` property.
        """
        return {"params": self.params, "pulses": self.pulses, "exposure_s": self.exposure_s,
                "seed": self.detector_seed(render_seed), "engine": self.engine}

    def to_string(self):
        # The render configuration digest includes str(film); detector settings are deliberately left
        # out, so that changing them does not invalidate the (detector-independent) ideal capture on
        # --resume. They are recorded in full under "detector" in the counts manifest.
        return super().to_string().replace("TransientFilm[", "SpadFilm[", 1)
