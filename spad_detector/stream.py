"""``detect_stack``: an ideal capture directory -> a counts capture directory, spot by spot.

Everything is validated before any work (parameters, budget, gate, time axis
against the laser period, jitter against the bin width, the output path).
Spots are read, detected and written one at a time (memory bounded by one
spot), into a temporary sibling directory that is renamed into place at the
end, so a failed or interrupted run leaves no counts capture behind. Each
spot uses its own random stream, ``SeedSequence(seed, spawn_key=(spot,))``,
so a spot's counts do not depend on the others.
"""

from __future__ import annotations

import math
import os
import shutil
import sys
from pathlib import Path

import numpy as np

from transient_core.progress import progress_bar
from transient_core.atomic import check_output_location, rename_into_place, temp_dir_beside
from transient_core.lock import output_lock
from transient_core.errors import UserInputError
from transient_core.stack import (MANIFEST_NAME, StackError, has_error_bound, has_variance, is_error_bound,
                                  missing_spots, read_error_bound, new_manifest, read_intensity,
                                  read_manifest, read_variance, spot_filename, write_manifest, write_spot)

from .budget import resolve_budget
from .detect import check_engine, check_ideal, run_spot, to_uint32
from .engines import estimated_events
from .gate import auto_gate
from .model import build_model
from .params import DetectorParams
from .render_noise import DEFAULT_THRESHOLD, NoiseRatio, unavailable, warning_line

#: ``engine="exact"`` refuses (unless forced) a capture whose estimated number of simulated triggering
#: events (:func:`~spad_detector.engines.exact.estimated_events`, summed over spots) exceeds this.
EXACT_MAX_EVENTS = 5e8
#: Version of the detector model recorded in counts manifests.
MODEL_VERSION = 1
_STANDARD_KEYS = {"format", "format_version", "status", "kind", "capture", "quantity", "width", "height",
                  "n_files", "time", "include_first_last", "geometry", "laser", "detector", "render",
                  "source_ideal", "variance", "error_bound", "channels", "intensity"}


def spot_rng(seed: int, spot: int) -> np.random.Generator:
    """The random stream of one spot: ``default_rng(SeedSequence(seed, spawn_key=(spot,)))``."""
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(int(spot),)))


def _check_seed(seed) -> int:
    import numbers

    if isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or seed < 0:
        raise UserInputError(f"seed={seed!r}: must be a whole number >= 0")
    return int(seed)


def _check_output(out: Path, ideal: Path, overwrite: bool) -> None:
    if out.resolve() == ideal.resolve():
        raise UserInputError(f"output {out} is the ideal capture itself: choose another directory")
    if ideal.resolve() in out.resolve().parents:
        raise UserInputError(f"output {out} lies inside the ideal capture {ideal}: choose another directory")
    if out.exists():
        if not out.is_dir():
            raise UserInputError(f"output {out} exists and is not a directory")
        if (out / MANIFEST_NAME).exists() and not overwrite:
            raise UserInputError(f"output {out} already holds a capture: choose another directory "
                                 "(or overwrite it explicitly)")
    check_output_location(out, option="output")


def detect_stack(ideal_dir, out_dir, params: DetectorParams | None = None, *, pulses: int | None = None,
                 exposure_s: float | None = None, seed: int = 0, engine: str = "auto", progress: bool = True,
                 overwrite: bool = False, noise_threshold: float = DEFAULT_THRESHOLD, warn=None,
                 force: bool = False, on_spot=None) -> Path:
    """Detect a whole ideal capture and write the counts capture.

    Parameters
    ----------
    ideal_dir : path
        An ideal capture (``kind="ideal"``, ``quantity="photons_per_pulse"``,
        complete).
    out_dir : path
        Where to write the counts capture. It may exist if it holds no capture
        (e.g. a render output directory containing ``ideal/``); its other
        files are kept.
    params : DetectorParams, optional
        Detector model (default: the paper's).
    pulses, exposure_s : optional
        Photon budget per laser spot (one of them; default 1e6 pulses), see
        :func:`~spad_detector.budget.resolve_budget`.
    seed : int
        Master seed; spot ``j`` uses :func:`spot_rng` ``(seed, j)``.
    engine : {"auto", "analytic", "exact"}
    progress : bool
        Draw a progress bar (when stderr is a terminal, see ``transient_core.progress``).
    overwrite : bool
        Replace an existing counts capture in ``out_dir``.
    noise_threshold : float
        Largest acceptable ratio of rendering variance to photon variance
        (:mod:`.render_noise`); above it a one-line warning is given.
    warn : callable, optional
        ``warn(line)`` receives that warning (default: printed on stderr).
    force : bool
        With ``engine="exact"``, run even when the estimated work exceeds
        :data:`EXACT_MAX_EVENTS` (otherwise refused before any work).
    on_spot : callable, optional
        ``on_spot(j, ideal, counts)`` after spot ``j`` is detected, with its ideal histograms as read (one
        intensity per bin, photons per pulse, float32 ``[height, width, n_bins]``) and its counts (uint32, same
        shape), so a caller can use both without reading the files back (the demo's summed histograms).

    Returns
    -------
    Path
        ``out_dir``.

    The counts manifest has ``kind="counts"``, ``quantity="counts"``, the
    ideal capture's geometry, time axis and render provenance, the laser block
    with any overrides applied, ``source_ideal`` (path relative to ``out_dir``
    when inside it, else absolute), and under ``detector`` every parameter as
    given plus ``pulses``, ``exposure_s``, ``seed``, ``engine`` and
    ``resolved`` (repetition rate, photon scale, gate times, engine used per
    spot, whether every draw was exact) and ``render_noise``: how much of the
    counts' variance is the ideal capture's rendering noise, per class of bins
    and on per-pixel totals (:mod:`.render_noise`; ``available: false`` when
    the ideal capture stores no variance).
    """
    params = (params if params is not None else DetectorParams()).validate()
    check_engine(engine)
    seed = _check_seed(seed)
    ideal = Path(ideal_dir)
    out = Path(out_dir)
    m = read_manifest(ideal)
    if m["kind"] != "ideal":
        raise UserInputError(f"{ideal}: kind={m['kind']!r}; detect needs an ideal capture (kind 'ideal')")
    if m["quantity"] != "photons_per_pulse":
        raise UserInputError(f"{ideal}: quantity={m['quantity']!r}; detect needs expected photons per pulse "
                             "(quantity 'photons_per_pulse', as NLOS captures store)")
    missing = missing_spots(ideal, m)
    if missing or m["status"] != "complete":
        raise StackError(f"{ideal}: the capture is incomplete ({len(missing)} of {m['n_files']} spot files "
                         f"missing, status {m['status']!r}); finish the render first (--resume)")
    budget = resolve_budget(params, m.get("laser"), pulses=pulses, exposure_s=exposure_s)
    run_params, gate_source, spot_gates = resolve_gates(m, params)
    if params.crosstalk_prob > 0 and m["capture"] == "confocal":
        raise UserInputError(f"crosstalk_prob={params.crosstalk_prob!r}: a confocal capture's pixels were "
                             "recorded under different laser spots, so neighbour crosstalk cannot be modelled; "
                             "use crosstalk_prob=0")
    if not (isinstance(noise_threshold, (int, float)) and not isinstance(noise_threshold, bool)
            and math.isfinite(noise_threshold) and noise_threshold > 0):
        raise UserInputError(f"noise_threshold={noise_threshold!r}: must be a finite number > 0")
    t = m["time"]
    H, W, T = m["height"], m["width"], t["n_bins"]
    model = build_model(run_params, bin_width_ps=t["bin_width_ps"], n_bins=T, t0_ps=t["t0_ps"],
                        repetition_rate_hz=budget.repetition_rate_hz)
    _check_output(out, ideal, overwrite)

    src = ideal.resolve()
    dst = out.resolve()
    source_ideal = os.path.relpath(src, dst) if dst in src.parents else str(src)
    detector = {
        "model": "transient-mi SPAD+TCSPC",
        "model_version": MODEL_VERSION,
        **params.to_dict(),
        "pulses": budget.n_pulses,
        "exposure_s": budget.exposure_s,
        "pulses_requested": pulses,
        "exposure_s_requested": exposure_s,
        "seed": seed,
        "engine": engine,
    }
    resolved = {
        "repetition_rate_hz": budget.repetition_rate_hz,
        "period_ps": budget.period_ps,
        "photon_scale": budget.photon_scale,
        "gate": gate_source,
        "gate_open_ps": run_params.gate_open_ps,
        "gate_close_ps": run_params.gate_close_ps,
        "gate_transition_ps": run_params.gate_transition_ps,
        "gate_open_ps_per_spot": None if spot_gates is None else [g[0] for g in spot_gates],
        "gate_close_ps_per_spot": None if spot_gates is None else [g[1] for g in spot_gates],
        "spad_dead_time_ps": model.spad_dead_time_ps,
        "tcspc_dead_time_ps": model.tcspc_dead_time_ps,
    }
    extra = {k: v for k, v in m.items() if k not in _STANDARD_KEYS}
    manifest = new_manifest(
        kind="counts", capture=m["capture"], width=W, height=H, n_files=m["n_files"], t0_ps=t["t0_ps"],
        bin_width_ps=t["bin_width_ps"], n_bins=T, quantity="counts",
        include_first_last=m["include_first_last"], geometry=m.get("geometry"), laser=budget.laser,
        detector=dict(detector, resolved=resolved), render=m.get("render"), source_ideal=source_ideal,
        **({"detected_intensity": m["intensity"]} if m.get("channels") else {}), **extra)

    with output_lock(out, option="output"):
        _check_output(out, ideal, overwrite)  # again under the lock: another run may have written OUT meanwhile
        if engine == "exact":
            _check_exact_work(ideal, m, model, budget, spot_gates, run_params, force, progress)
        return _detect_locked(ideal, out, m, manifest, model, budget, spot_gates, run_params, resolved, seed, on_spot,
                              engine, progress, noise_threshold, warn)


def _detect_locked(ideal, out, m, manifest, model, budget, spot_gates, run_params, resolved, seed, on_spot, engine,
                   progress, noise_threshold, warn) -> Path:
    t = m["time"]
    H, W, T = m["height"], m["width"], t["n_bins"]
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = temp_dir_beside(out)
    except OSError as e:
        raise UserInputError(f"output {out}: cannot create a directory in {out.parent} ({e.strerror})") from None
    try:
        write_manifest(tmp, manifest)
        engines_used, exact, regimes = [], True, {}
        # multi-channel ideal captures store per-channel variances, not the variance of the intensity the
        # detector sees (channel covariances are not recorded): no noise ratio for them
        bound_kind = is_error_bound(m)
        # quadrature + Monte Carlo remainder: the variance is the remainder's, the bound the quadrature's
        two_parts = has_error_bound(m) and not bound_kind
        noise = NoiseRatio(threshold=float(noise_threshold)) if (has_variance(m) or two_parts) \
            and not m.get("channels") else None
        N = budget.n_pulses
        with progress_bar(f"detect {ideal.name}", total=m["n_files"] * N,
                          disable=None if progress else True) as advance:
            for j in range(m["n_files"]):
                data = read_intensity(ideal, j, m)  # one intensity per bin (luminance Y, Stokes S0 or mono)
                arr = check_ideal(data, where=f"{ideal / spot_filename(j)}")
                if budget.photon_scale != 1.0:
                    arr = arr * budget.photon_scale
                spot_model = model if spot_gates is None else spot_model_for(m, run_params, spot_gates, j, budget)
                if noise is not None:
                    if has_variance(m):
                        var, tvar = read_variance(ideal, j, m)
                    else:  # a remainder of a single replicate: its variance is unknown (only the bound counts)
                        var, tvar = np.zeros((H, W, T), np.float32), np.zeros((H, W), np.float32)
                    # a bound scales with the photons, a variance with their square
                    vs = budget.photon_scale if bound_kind else budget.photon_scale ** 2
                    bnd = tbnd = None
                    if two_parts:
                        bnd, tbnd = read_error_bound(ideal, j, m)
                        bnd = bnd.reshape(H * W, T).astype(np.float64) * budget.photon_scale
                        tbnd = tbnd.reshape(-1).astype(np.float64) * budget.photon_scale
                    noise.add_spot(spot_model, arr.reshape(H * W, T),
                                   var.reshape(H * W, T).astype(np.float64) * vs, N,
                                   total_variance=tvar.reshape(-1).astype(np.float64) * vs,
                                   error_bound=bound_kind, bound=bnd, total_bound=tbnd)
                    del var, tvar, bnd, tbnd
                counts, info = run_spot(spot_model, arr.reshape(H * W, T), N, spot_rng(seed, j), engine, (H, W),
                                        advance=advance)
                counts = to_uint32(counts, where=spot_filename(j)).reshape(H, W, T)
                write_spot(tmp, j, counts, manifest)
                if on_spot is not None:
                    on_spot(j, data, counts)
                engines_used.append(info["engine"])
                exact = exact and bool(info["exact"])
                for k, v in info.get("pixels_by_regime", {}).items():
                    regimes[k] = regimes.get(k, 0) + v
        if noise is not None:
            spp_used = m["variance"].get("spp_per_spot") or [(m.get("render") or {}).get("spp")]
            render_noise = noise.report(spp=max(spp_used) if None not in spp_used else None,
                                        replicates=m["variance"].get("replicates"),
                                        estimator="quadrature" if bound_kind else
                                        "quadrature+monte_carlo" if two_parts else None)
        else:
            render_noise = unavailable("the ideal capture stores no variance (rendered with one replicate or by "
                                       "an older version): its rendering noise is unknown")
        resolved.update(engines_used=engines_used, exact=exact, analytic_pixels_by_regime=regimes or None,
                        render_noise=render_noise)
        manifest["detector"]["resolved"] = resolved
        manifest["status"] = "complete"
        write_manifest(tmp, manifest)
        _move_into_place(tmp, out, m["n_files"])
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    line = warning_line(render_noise)
    if line:
        (warn or _stderr)(line)
    return out


def estimate_exact_work(ideal: Path, m: dict, model, budget, spot_gates=None, run_params=None,
                        progress: bool = True) -> dict:
    """Work of the exact engine on a whole capture, estimated before running it (streams the spots).

    Returns ``{"events": expected triggering events (the exact engine's cost driver, summed over spots),
    "pixel_pulses": pixels x pulses x spots}``.
    """
    t = m["time"]
    H, W, T = m["height"], m["width"], t["n_bins"]
    N = budget.n_pulses
    events = 0.0
    with progress_bar(f"estimate exact work {ideal.name}", total=m["n_files"],
                      disable=None if progress else True) as advance:
        for j in range(m["n_files"]):
            arr = check_ideal(read_intensity(ideal, j, m), where=f"{ideal / spot_filename(j)}")
            if budget.photon_scale != 1.0:
                arr = arr * budget.photon_scale
            spot_model = model if spot_gates is None else spot_model_for(m, run_params, spot_gates, j, budget)
            events += estimated_events(spot_model, arr.reshape(H * W, T), N)
            advance(1)
    return {"events": events, "pixel_pulses": float(H * W) * N * m["n_files"]}


def _check_exact_work(ideal, m, model, budget, spot_gates, run_params, force: bool, progress: bool) -> dict:
    work = estimate_exact_work(ideal, m, model, budget, spot_gates, run_params, progress)
    if work["events"] > EXACT_MAX_EVENTS and not force:
        raise UserInputError(
            f"engine=exact: {ideal} needs about {work['events']:.3g} simulated photon events "
            f"({work['pixel_pulses']:.3g} pixel-pulses over {m['n_files']} spot(s)), more than the limit "
            f"{EXACT_MAX_EVENTS:.3g}; gate out the wall return, use fewer pulses or engine auto, "
            "or force it (--force)")
    return work


def _stderr(line: str) -> None:
    sys.stderr.write(line + "\n")
    sys.stderr.flush()


def resolve_gates(m: dict, params: DetectorParams):
    """``(run_params, gate_source, spot_gates)``: ``auto_gate`` resolved against the capture's geometry.

    Array captures get one gate per laser spot (``spot_gates[j] = (open_ps,
    close_ps)``; ``run_params`` then spans all of them), other captures one
    gate; ``gate_source`` is ``auto_per_spot``, ``auto``, ``explicit`` or ``none``.
    """
    run_params = params
    gate_source = "none"
    spot_gates = None  # per-spot (open, close) for array captures with auto_gate
    if params.auto_gate:
        if m["capture"] == "array":
            # One gate per laser position (a gated SPAD array is re-timed for every acquisition): every
            # three-bounce path from spot j is longer than j's own first-bounce path (triangle inequality),
            # so the spot's window passes its hidden-volume light and blocks its wall return.
            spot_gates = [auto_gate(m, params.gate_transition_ps, params.auto_gate_depth_min_m,
                                    params.auto_gate_depth_max_m, spot=j) for j in range(m["n_files"])]
            g_open, g_close = min(g[0] for g in spot_gates), max(g[1] for g in spot_gates)
            gate_source = "auto_per_spot"
        else:
            g_open, g_close = auto_gate(m, params.gate_transition_ps, params.auto_gate_depth_min_m,
                                        params.auto_gate_depth_max_m)
            gate_source = "auto"
        run_params = params.replace(gate_open_ps=g_open, gate_close_ps=g_close, auto_gate=False)
    elif params.gate_open_ps is not None:
        gate_source = "explicit"
    return run_params, gate_source, spot_gates


def spot_model_for(m: dict, run_params: DetectorParams, spot_gates, j: int, budget):
    """The detector model of spot ``j`` (its own gate when ``spot_gates`` is given)."""
    t = m["time"]
    if spot_gates is not None:
        run_params = run_params.replace(gate_open_ps=spot_gates[j][0], gate_close_ps=spot_gates[j][1])
    return build_model(run_params, bin_width_ps=t["bin_width_ps"], n_bins=t["n_bins"], t0_ps=t["t0_ps"],
                       repetition_rate_hz=budget.repetition_rate_hz)


def _move_into_place(tmp: Path, out: Path, n_files: int) -> None:
    """Rename ``tmp`` to ``out``; into an existing ``out``, move spots first and the manifest last."""
    if not out.exists():
        rename_into_place(tmp, out)
        return
    old = out / MANIFEST_NAME
    if old.exists():
        old.unlink()  # from here on, out is not a capture until the new manifest lands
    for f in out.glob("spot_*.exr"):
        f.unlink()
    for j in range(n_files):
        rename_into_place(tmp / spot_filename(j), out / spot_filename(j))
    rename_into_place(tmp / MANIFEST_NAME, out / MANIFEST_NAME)
    shutil.rmtree(tmp, ignore_errors=True)
