"""What a capture states about its own error: the manifest's ``variance`` block and its summary.

A Monte Carlo capture stores the variance of every bin from independent replicates (``variance/``); a
quadrature capture (``estimator="quadrature"``) stores its error estimate the same way (``kind:
"error_bound"``, ``error_bound/``), read by the same reader (:mod:`transient_core.stack`). Used by the render
pipeline (:mod:`transient_mi.render_capture`).

A quadrature capture with ``max_depth`` above 4 (or -1) has two parts: the quadrature's three-bounce light
(and the wall return) and the Monte Carlo remainder (every other path). Its manifest states both:

* ``variance`` is the Monte Carlo block of the remainder (``directory: "variance"``, replicates, degrees of
  freedom, ``part: "monte_carlo_remainder"``), as in a Monte Carlo capture;
* ``error_bound`` (top level, beside it) is the quadrature's block, the same layout as a pure quadrature
  capture's ``variance`` block (``kind: "error_bound"``, ``directory: "error_bound"``, ``part: "quadrature"``);
  :func:`transient_core.stack.read_error_bound` reads it.

A reader that knows only ``variance`` sees the remainder's variance (an understatement of the error);
``detect`` combines both (:mod:`spad_detector.render_noise`: variance per bin = remainder's variance + the
square of the bound carried linearly through gate, PDE and jitter).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from transient_core import stack


def _replicates(integrator, nlos: bool) -> int:
    from transient_mi.integrators._replicates import DEFAULT_REPLICATES

    f = getattr(integrator, "replicates_for", None)
    return f(nlos) if f is not None else DEFAULT_REPLICATES


def estimator_of(integrator) -> str:
    """``"quadrature"`` (the deterministic three-bounce estimator) or ``"monte_carlo"``."""
    return (getattr(integrator, "nlos_options", None) or {}).get("estimator", "monte_carlo")


def has_remainder(integrator) -> bool:
    """True for ``estimator="quadrature"`` with ``max_depth`` above 4 or -1 (quadrature + Monte Carlo remainder)."""
    from transient_mi.integrators._nlos_quadrature import needs_remainder

    return estimator_of(integrator) == "quadrature" and \
        needs_remainder({"max_depth": getattr(integrator, "max_depth_param", 4)})


def error_bound_block(integrator, quantity: str) -> dict:
    """The quadrature's error block: a pure quadrature capture's ``variance``, a two-part capture's ``error_bound``."""
    o = integrator.nlos_options
    return {
        "directory": stack.ERROR_BOUND_DIR,
        "kind": stack.ERROR_BOUND_KIND,
        "replicates": 1,
        "degrees_of_freedom": None,
        "estimator": ("deterministic three-bounce quadrature (transient_mi.integrators._nlos_quadrature): the "
                      "files bound the absolute error of every bin (mixed visibility, path-length "
                      "linearisation, midpoint rule)"),
        "settings": {"element_size_m": o["element_size_m"], "patch_cells": o["patch_cells"],
                     "refine_levels": o["refine_levels"]},
        "quantity": quantity,
        "summary": None,
    }


def variance_block(integrator, spp: int, quantity: str) -> dict:
    """The manifest's ``variance`` entry for a render of ``spp`` samples (summary filled in at the end).

    A quadrature capture (``estimator="quadrature"``) stores its deterministic error bound the same way
    (``kind: "error_bound"``, directory ``error_bound/``, read by the same reader).
    """
    from transient_mi.integrators._replicates import effective_replicates

    if quantity == "photons_per_pulse" and estimator_of(integrator) == "quadrature" and not has_remainder(integrator):
        return error_bound_block(integrator, quantity)

    R = effective_replicates(spp, _replicates(integrator, nlos=quantity == "photons_per_pulse"))
    block = {
        "directory": stack.VARIANCE_DIR if R >= 2 else None,
        "replicates": R,
        "degrees_of_freedom": R - 1,
        "estimator": "sample variance of the mean over independent replicates (unbiased; randomised QMC "
                     "replicates have independent random shifts)",
        "quantity": f"({quantity})^2",
        "summary": None,
    }
    if quantity == "photons_per_pulse" and has_remainder(integrator):
        block["part"] = "monte_carlo_remainder"
        block["estimator"] += ("; of the Monte Carlo remainder beyond three bounces only (the quadrature's error is "
                               "the manifest's error_bound block)")
    if R < 2:
        block["reason"] = (f"spp={spp} and {_replicates(integrator, nlos=quantity == 'photons_per_pulse')} replicates "
                           "(integrator parameter variance_replicates; default 8 for NLOS captures, 1 for cameras) "
                           "give a single replicate: no variance is recorded")
    return block


def error_blocks(integrator, spp: int, quantity: str) -> dict:
    """The manifest's error blocks: ``{"variance": ...}``, plus ``"error_bound"`` for a two-part capture."""
    out = {"variance": variance_block(integrator, spp, quantity)}
    if quantity == "photons_per_pulse" and has_remainder(integrator):
        out["error_bound"] = dict(error_bound_block(integrator, quantity), part="quadrature")
    return out


def spot_error_summary(x: np.ndarray, var: np.ndarray, tvar: np.ndarray, bound: bool
                       ) -> tuple[list[float], float, float]:
    """One spot's part of :func:`variance_summary`: ``(sqrt(Var(total)) / total of its lit pixels, sum of
    sqrt(Var(x_b)), sum of x_b)``, from the values as the capture stores them (cast to float32, as the writers do,
    so the part is the same from the arrays in memory as from the files read back). ``x`` ``[H, W, T[, C]]``,
    ``var`` its variance (or error, ``bound``: not squared), ``tvar`` ``[H, W[, C]]`` the totals'."""
    x = np.asarray(x, dtype=np.float32).astype(np.float64)
    var = np.asarray(var, dtype=np.float32).astype(np.float64)
    tvar = np.asarray(tvar, dtype=np.float32).astype(np.float64)
    if bound:  # a bound is already an error (not squared)
        var, tvar = np.square(var), np.square(tvar)
    tot = x.sum(axis=2)  # over time: [H, W] (or [H, W, C] per channel)
    ok = tot > 1e-6 * max(float(tot.max()), 1e-300)
    return (np.sqrt(tvar[ok]) / tot[ok]).tolist(), float(np.sqrt(var).sum()), float(x.sum())


def variance_summary(directory: Path, manifest: dict, parts: dict | None = None) -> dict | None:
    """Relative Monte Carlo error of a complete capture (read back spot by spot).

    ``pixel_total_rel_std``: median, 90th percentile and maximum over
    (spot, pixel) of ``sqrt(Var(total)) / total`` for pixels whose total is
    above 1e-6 of the largest; ``bin_rel_std_weighted``: the value-weighted
    mean of ``sqrt(Var(x_b)) / x_b`` over all bins, i.e.
    ``sum sqrt(Var(x_b)) / sum x_b``. ``parts``, optional: :func:`spot_error_summary` of spots rendered in this
    run, by spot index (the others are read back: a resumed capture's summary is the same).
    """
    if not stack.has_variance(manifest):
        return None
    rel, sd_sum, x_sum = [], 0.0, 0.0
    bound = stack.is_error_bound(manifest)
    for j in range(manifest["n_files"]):
        part = (parts or {}).get(j)
        if part is None:
            part = spot_error_summary(stack.read_spot(directory, j, manifest), *stack.read_variance(directory, j,
                                                                                                    manifest), bound)
        rel.extend(part[0])
        sd_sum += part[1]
        x_sum += part[2]
    if not rel:
        return {"pixel_total_rel_std": None, "bin_rel_std_weighted": None}
    r = np.asarray(rel)
    return {"pixel_total_rel_std": {"median": float(np.median(r)), "p90": float(np.percentile(r, 90)),
                                    "max": float(r.max())},
            "bin_rel_std_weighted": sd_sum / x_sum if x_sum > 0 else None}


def quadrature_settings_per_spot(manifest: dict) -> list[dict]:
    """The quadrature's settings (``element_size_m``, ``patch_cells``, ``refine_levels``) of each spot of a capture's
    manifest: ``variance.settings_per_spot`` (refined per spot by a noise target), else the capture's
    ``variance.settings`` once; ``[{}]`` for a capture without them (Monte Carlo)."""
    var = manifest.get("variance") or {}
    return var.get("settings_per_spot") or [var.get("settings") or {}]
