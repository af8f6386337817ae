"""The parameters and render-call checks the transient path integrators share.

``transient_path`` (cameras; under a ``spad_array`` it delegates to the NLOS estimator) and
``transient_nlos_path`` (the NLOS estimator) read their common parameters here, so the two read the same
names with the same defaults, ranges and error messages, and check a render call the same way. Each
failure is one :class:`~transient_mi.props.PluginParameterError` line naming the plug-in, the parameter, the
value and what is allowed.
"""

from __future__ import annotations

import mitsuba as mi
import numpy as np

from transient_mi._upload import upload_tensor
from transient_mi.props import PluginParameterError, get_bool, get_choice, get_float, get_int
from transient_mi.integrators._sensor_checks import check_rfilter, check_sampler

#: ``hidden_geometry_prob`` unless the scene gives one.
DEFAULT_HIDDEN_GEOMETRY_PROB = 0.8


def read_path_params(props, plugin: str) -> tuple[int, int, int | None]:
    """``(max_depth, rr_depth, variance_replicates)`` from the plug-in's properties.

    ``max_depth``: longest path in Mitsuba's meaning, -1 (unlimited, the default) or >= 1; ``rr_depth``:
    depth at which Russian roulette starts, >= 1 (default 5); ``variance_replicates``: in [1, 1024], None
    when not given (the default of the caller, see ``replicates_for``).
    """
    max_depth = get_int(props, plugin, "max_depth", -1, min_value=-1)
    if max_depth == 0:
        raise PluginParameterError(f"{plugin}: max_depth=0 records nothing; use -1 (unlimited) or >= 1")
    rr_depth = get_int(props, plugin, "rr_depth", 5, min_value=1)
    replicates = (get_int(props, plugin, "variance_replicates", None, min_value=1, max_value=1024)
                  if "variance_replicates" in props else None)
    return max_depth, rr_depth, replicates


def read_nlos_options(props, plugin: str) -> dict:
    """The NLOS estimator's own parameters: ``rqmc``, ``hidden_geometry_prob``, ``estimator`` and the quadrature's
    ``element_size_m``, ``patch_cells``, ``refine_levels``, ``element_slope`` (see
    :mod:`transient_mi.integrators._nlos_quadrature`).

    ``hidden_geometry_prob``: probability of choosing hidden-geometry (area) sampling over BSDF sampling
    for the direction leaving the relay-wall patch point (one-sample MIS with the balance heuristic, see
    :mod:`transient_mi.integrators.transient_nlos_path`); in [0, 1], default 0.8. ``rqmc``: randomised
    quasi-Monte Carlo at the patch point (default true).
    """
    from transient_mi.integrators import _nlos_quadrature as q

    return {
        "rqmc": get_bool(props, plugin, "rqmc", True),
        "hidden_geometry_prob": get_float(props, plugin, "hidden_geometry_prob", DEFAULT_HIDDEN_GEOMETRY_PROB,
                                          min_value=0.0, max_value=1.0),
        "estimator": get_choice(props, plugin, "estimator", "monte_carlo", ("monte_carlo", "quadrature")),
        "element_size_m": get_float(props, plugin, "element_size_m", q.DEFAULT_ELEMENT_SIZE_M, min_value=1e-5,
                                    max_value=10.0),
        "patch_cells": get_int(props, plugin, "patch_cells", q.DEFAULT_PATCH_CELLS, min_value=1, max_value=64),
        "refine_levels": get_int(props, plugin, "refine_levels", q.DEFAULT_REFINE_LEVELS, min_value=0,
                                 max_value=8),
        "element_slope": get_bool(props, plugin, "element_slope", True),
    }


def estimator_suffix(options: dict) -> str:
    """What a plug-in's ``to_string`` adds for the estimator: nothing for Monte Carlo (the default, so its
    configuration digests are unchanged), the quadrature's settings otherwise."""
    if options.get("estimator", "monte_carlo") == "monte_carlo":
        return ""
    return (f", estimator=quadrature, element_size_m={options['element_size_m']:g}, "
            f"patch_cells={options['patch_cells']}, refine_levels={options['refine_levels']}"
            + ("" if options.get("element_slope", True) else ", element_slope=false"))


def check_render_call(plugin: str, sensor, seed: int, spp: int, replicates: int | None):
    """Check a ``render_transient`` call and release the film's previous result; returns ``(film, spp)``.

    ``spp`` 0 takes the sensor's sampler value. Raises :class:`PluginParameterError` for a film that is not
    transient, a non-JIT variant, a seed outside ``[0, 2**32)``, ``spp < 1`` or ``replicates`` that does
    not divide ``spp``, and for a sampler or reconstruction filter the integrators do not honour
    (:mod:`transient_mi.integrators._sensor_checks`).
    """
    film = sensor.film()
    if not hasattr(film, "is_transient"):
        raise PluginParameterError(
            f"{plugin}: the sensor's film is {type(film).__name__}; use a transient_film or spad_film")
    if not mi.variant().startswith(("llvm_", "cuda_")):
        raise PluginParameterError(
            f"{plugin}: rendering needs a JIT variant (llvm_* or cuda_*), not {mi.variant()}; "
            "scalar_* variants load scenes and construct plug-ins for debugging only")
    if not 0 <= seed < 2**32:
        raise PluginParameterError(f"{plugin}: seed={seed} must be in [0, 2**32)")
    check_sampler(sensor, plugin)
    check_rfilter(sensor, plugin)
    film.set_result(None)  # release the previous render's histogram before allocating
    spp = spp or int(sensor.sampler().sample_count())
    if spp < 1:
        raise PluginParameterError(f"{plugin}: spp={spp} must be >= 1")
    if replicates is not None and (replicates < 1 or spp % replicates):
        raise PluginParameterError(f"{plugin}: replicates={replicates} must be >= 1 and divide spp={spp}")
    return film, spp


def replicates_for(variance_replicates: int | None) -> int:
    """Replicates a render is split into: ``variance_replicates`` if given, else 1 (a single estimate, no
    variance: the fastest render, as ``mi.render`` and direct calls get). ``transient-mi render`` and
    everything built on it (demo, studies, datasets) set
    :data:`~transient_mi.integrators._replicates.DEFAULT_REPLICATES` for NLOS captures, so the captures
    they write carry their variance (:func:`transient_mi.render_capture.prepare_render`)."""
    return int(variance_replicates) if variance_replicates is not None else 1


def as_int(x) -> int:
    """A seed or spp given as a Python int or a one-element Dr.Jit array (``mi.render`` passes
    ``mi.UInt32`` seeds for the differential passes)."""
    if isinstance(x, (int, np.integer)):
        return int(x)
    return int(np.asarray(x).ravel()[0])


def render_tensor(integrator, scene, sensor, seed, spp, progress):
    """``Integrator.render`` for both transient integrators: ``render_transient`` on ``sensor`` (an index or a
    sensor), its histograms as ``mi.TensorXf``; the film keeps the full result.

    This is what ``mi.render`` calls, after ``params.update()`` in optimisation loops: an NLOS sensor's cached
    scene analysis (its closed-form wall return, the laser's photons per pulse, the hidden shapes) is rebuilt
    first, as the parameters may have changed."""
    if isinstance(sensor, int):
        sensor = scene.sensors()[sensor]
    if hasattr(sensor, "forget_nlos_setup"):
        sensor.forget_nlos_setup()
    result = integrator.render_transient(scene, sensor, seed=as_int(seed), spp=as_int(spp), progress=progress)
    return upload_tensor(result.histogram)
