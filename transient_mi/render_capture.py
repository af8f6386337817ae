"""Render a scene into an EXR histogram stack, one laser spot at a time.

This is what ``transient-mi render`` runs. Everything that can be checked
before rendering (scene, parameters, output location) is checked first, so bad
input leaves no output directory behind. The capture directory then receives
``manifest.json`` (status ``incomplete``), one ``spot_NNNNN.exr`` per laser
spot as soon as it is rendered (atomic writes: a file with its final name is
complete), and finally ``preview.png`` and the manifest with status
``complete``. Peak memory is that of one spot, whatever the number of spots.

``resume=True`` continues an interrupted capture: spots already written with
the same configuration are kept, the others are rendered. Spots are rendered
in fixed groups (one spot each, except NLOS array captures, whose sensor's
``spot_groups`` lets a group share sub-paths); the group starting at spot
``j`` uses its own seed derived from ``(seed, j)``, and a group with any
spot missing is rendered again as a whole, so a resumed capture is
byte-identical to an uninterrupted one.

With a ``spad_film`` the ideal capture is rendered into ``OUT/ideal/`` and the
detector model turns it into a counts capture in ``OUT/``.
"""

from __future__ import annotations

import os
import platform
import shutil
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from transient_core.atomic import check_output_location
from transient_core.lock import output_lock
from transient_core.progress import progress_bar
from transient_core.errors import UserInputError
from transient_core import stack

from . import __version__
from .integrators._work_arrays import reuse_work_arrays
from .capture_error import _replicates, error_blocks, estimator_of, spot_error_summary, variance_summary
from .noise_target import PARTIAL_DIR  # per-spot facts and noise-target checkpoints, removed at the end
from .render_resume import read_spot_facts, remove_stale_temporaries, write_spot_facts
from .scene_io import file_sha256, load_scene


def spot_seed(seed: int, spot: int) -> int:
    """Seed of laser spot ``spot``: a hash of ``(seed, spot)`` (spot 0 of a camera render uses ``seed``)."""
    return int(np.random.SeedSequence([int(seed), int(spot)]).generate_state(1, dtype=np.uint32)[0])


@dataclass
class RenderJob:
    """A validated render request (see :func:`prepare_render`)."""

    scene_file: Path
    out_dir: Path
    defines: dict[str, str]
    spp: int
    seed: int
    variant: str
    resume: bool
    scene: object = None
    sensor: object = None
    integrator: object = None
    layout: dict = field(default_factory=dict)
    manifest: dict = field(default_factory=dict)
    detect_kwargs: dict | None = None
    noise_target: object = None  # transient_mi.noise_target.NoiseTargetSpec

    @property
    def ideal_dir(self) -> Path:
        return self.out_dir / "ideal" if self.detect_kwargs is not None else self.out_dir


def _check_output(out_dir: Path, resume: bool) -> None:
    if out_dir.exists() and not out_dir.is_dir():
        raise UserInputError(f"-o {out_dir}: exists and is not a directory")
    check_output_location(out_dir)
    if out_dir.exists() and not resume and any(out_dir.iterdir()):
        raise UserInputError(f"-o {out_dir}: directory exists and is not empty (use --resume to continue it, "
                             "or choose another output)")
    if out_dir.exists() and not os.access(out_dir, os.W_OK | os.X_OK):
        raise UserInputError(f"-o {out_dir}: directory is not writable")


def _camera_layout(sensor) -> dict:
    return {
        "capture": "camera",
        "n_files": 1,
        "quantity": "radiance",
        "include_first_last": True,
        "geometry": None,
        "laser": None,
    }


def _versions() -> dict:
    import drjit as dr
    import mitsuba as mi

    return {"transient_mi": __version__, "mitsuba": mi.__version__, "drjit": dr.__version__,
            "numpy": np.__version__, "python": platform.python_version()}


def prepare_render(scene_file, out_dir, *, defines=None, spp: int = 0, seed: int = 0,
                   variant: str | None = None, resume: bool = False, noise_target=None) -> RenderJob:
    """Validate everything and load the scene; creates nothing on disk.

    ``noise_target``: a :class:`transient_mi.noise_target.NoiseTargetSpec`
    (render each spot until its rendering noise is at most that share of the
    photon noise; its ``params`` may be None to use the scene's ``spad_film``
    or else the default detector).

    Raises
    ------
    UserInputError
        For a missing or malformed scene, bad parameters, a bad variant or
        an output location that cannot be used.
    """
    import transient_mi as tm

    if variant:
        tm.set_variant(variant)
    if not tm.variant().startswith(("llvm_", "cuda_")):
        raise UserInputError(f"variant {tm.variant()!r} cannot render: use an llvm_* or cuda_* variant "
                             "(scalar_* variants only load scenes, for debugging)")
    if spp < 0:
        raise UserInputError(f"--spp {spp}: must be >= 1 (or 0 for the scene's value)")
    if not 0 <= seed < 2**32:
        raise UserInputError(f"--seed {seed}: must be in [0, 2**32)")
    scene_file = Path(scene_file)
    out_dir = Path(out_dir)
    _check_output(out_dir, resume)
    scene = load_scene(scene_file, defines)
    sensors = scene.sensors()
    if len(sensors) != 1:
        raise UserInputError(f"{scene_file}: has {len(sensors)} sensors; transient-mi renders scenes with exactly one")
    sensor = sensors[0]
    integrator = scene.integrator()
    if not hasattr(integrator, "render_transient"):
        raise UserInputError(f"{scene_file}: integrator is {type(integrator).__name__}; "
                             "use <integrator type=\"transient_path\"> (cameras) or \"transient_nlos_path\" "
                             "(spad_array) for transient renders")
    film = sensor.film()
    if not hasattr(film, "is_transient"):
        raise UserInputError(f"{scene_file}: the sensor's film must be a transient_film or spad_film")
    if not spp:
        spp = int(sensor.sampler().sample_count())
        if spp < 1:
            raise UserInputError(f"{scene_file}: the sampler's sample_count is {spp} (e.g. from -D spp={spp}); "
                                 "need >= 1 samples per pixel")
    layout = sensor.capture_layout(scene) if hasattr(sensor, "capture_layout") else _camera_layout(sensor)
    if getattr(integrator, "variance_replicates", 0) is None and layout["quantity"] == "photons_per_pulse":
        # captures written to disk carry their variance (docs/noise.md); direct renders default to one replicate
        from transient_mi.integrators._replicates import DEFAULT_REPLICATES

        integrator.variance_replicates = DEFAULT_REPLICATES
    detect_kwargs = film.detect_kwargs(render_seed=seed) if hasattr(film, "detect_kwargs") else None
    if detect_kwargs is not None and layout["quantity"] != "photons_per_pulse":
        raise UserInputError(f"{scene_file}: a spad_film needs an NLOS sensor (spad_array) that records "
                             "photons per laser pulse; under a camera use transient_film")

    quadrature = layout["quantity"] == "photons_per_pulse" and estimator_of(integrator) == "quadrature"
    if noise_target is not None and quadrature and _has_remainder(integrator):
        raise UserInputError(f"--noise-target: {scene_file} renders with estimator=quadrature and max_depth="
                             f"{integrator.max_depth_param} (a Monte Carlo remainder beside the quadrature); a noise "
                             "target refines pure quadrature captures (max_depth <= 4) only")
    if noise_target is not None:
        noise_target = _resolve_noise_target(noise_target, integrator, spp, layout, detect_kwargs, scene_file,
                                             quadrature)
    axis = film.time_axis()
    config = {
        "scene_sha256": file_sha256(scene_file),
        "defines": dict(sorted((defines or {}).items())),
        "spp": spp,
        "seed": seed,
        "variant": tm.variant(),
        "film": str(film),
        "integrator": str(integrator),
        "sensor": layout.get("geometry"),
        "laser": layout.get("laser"),
    }
    if noise_target is not None:
        config["noise_target"] = noise_target.to_dict()
    render_info = {
        "scene_file": str(scene_file.resolve()),
        "scene_sha256": config["scene_sha256"],
        "defines": config["defines"],
        "spp": spp,
        "seed": seed,
        "variant": tm.variant(),
        "integrator": str(integrator),
        "film": str(film),
        "kernel_sigma_ps": float(getattr(film, "kernel_sigma_ps", 0.0)),
        "versions": _versions(),
        "config_sha256": stack.config_digest(config),
        "command": " ".join(sys.argv) if sys.argv else "",
    }
    manifest = stack.new_manifest(
        kind="ideal",
        capture=layout["capture"],
        width=film.width,
        height=film.height,
        n_files=layout["n_files"],
        t0_ps=axis.t0_ps,
        bin_width_ps=axis.bin_width_ps,
        n_bins=axis.n_bins,
        quantity=layout["quantity"],
        include_first_last=layout["include_first_last"],
        geometry=layout.get("geometry"),
        laser=layout.get("laser"),
        detector=None,
        render=render_info,
        dropped={"contributions": 0, "fraction": 0.0, "invalid_path_lengths": 0, "negative_fraction": 0.0},
        # colour or Stokes vectors per bin (camera renders in rgb, spectral, polarized variants); NLOS: one intensity
        channels=film.channel_names() if layout["capture"] == "camera" and hasattr(film, "channel_names") else None,
    )
    manifest.update(error_blocks(integrator, spp, layout["quantity"]))
    manifest["render"]["estimator"] = (estimator_of(integrator) if layout["quantity"] == "photons_per_pulse"
                                       else "monte_carlo")
    if noise_target is not None:
        manifest["render"]["noise_target"] = dict(noise_target.to_dict(), spots=[None] * layout["n_files"])
    job = RenderJob(scene_file, out_dir, dict(defines or {}), spp, seed, tm.variant(), resume,
                    scene, sensor, integrator, layout, manifest, detect_kwargs, noise_target)
    if resume and job.ideal_dir.exists() and stack.manifest_path(job.ideal_dir).exists():
        old = stack.read_manifest(job.ideal_dir)
        _check_resumable(old, manifest, job.ideal_dir)
    return job


def _has_remainder(integrator) -> bool:
    """A quadrature render with a Monte Carlo remainder (light beyond three bounces)."""
    d = getattr(integrator, "max_depth_param", 4)
    return d == -1 or d > 4


def _resolve_noise_target(spec, integrator, spp: int, layout: dict, detect_kwargs, scene_file,
                          quadrature: bool = False):
    """Validate a noise-target request; fill in the detector and budget from the scene's spad_film if unset.

    ``quadrature``: the target is met by refining the quadrature (no replicates needed)."""
    from spad_detector import DetectorParams
    from transient_mi.integrators._replicates import effective_replicates

    if layout["quantity"] != "photons_per_pulse":
        raise UserInputError(f"--noise-target: {scene_file} renders {layout['quantity']} (a camera view), which "
                             "has no photon budget; noise targets apply to NLOS captures (spad_array sensor)")
    if spec.params is None:
        if detect_kwargs is not None:
            spec.params = detect_kwargs["params"]
            if spec.pulses is None and spec.exposure_s is None:
                spec.pulses, spec.exposure_s = detect_kwargs.get("pulses"), detect_kwargs.get("exposure_s")
        else:
            spec.params = DetectorParams(auto_gate=True)
    spec.params = spec.params.validate()
    if quadrature and spec.quadrature_target is not None:
        spec.target = spec.quadrature_target
    R = 2 if quadrature else effective_replicates(spp, _replicates(integrator, nlos=True))
    return spec.validate(spp, R)


def _check_resumable(old: dict, new: dict, where: Path) -> None:
    o, n = old.get("render") or {}, new["render"]
    if o.get("config_sha256") == n["config_sha256"]:
        return
    diffs = []
    for key in ("scene_sha256", "defines", "spp", "seed", "variant", "film", "integrator"):
        if o.get(key) != n.get(key):
            diffs.append(f"{key}: {o.get(key)!r} then, {n.get(key)!r} now")
    if not diffs:
        diffs.append("sensor/laser geometry differs")
    raise UserInputError(f"--resume {where}: the existing capture was rendered with other settings ("
                         + "; ".join(diffs) + "); use a new output directory")


def run_render(job: RenderJob, progress: bool | None = None, on_spot=None, log=None) -> Path:
    """Render every (missing) spot of ``job`` and write the capture.

    Parameters
    ----------
    job : RenderJob
        From :func:`prepare_render`.
    progress : bool, optional
        Force the progress bar on/off (default: on for terminals).
    on_spot : callable, optional
        ``on_spot(j)`` after spot ``j`` is written (used by tests to
        interrupt a render).
    log : callable, optional
        ``log(line)`` for the noise-target steps (default: stderr).

    Returns
    -------
    Path
        The capture directory (for a ``spad_film``, the counts capture).
    """
    with output_lock(job.out_dir):
        # re-checked under the lock: another run may have written OUT since prepare_render looked
        _check_output(job.out_dir, job.resume)
        return _run_render_locked(job, progress, on_spot, log)


#: Threads that write the spots of a group (each spot's files in order on one of them).
WRITE_THREADS = 2


def _write_spot_files(d: Path, j: int, res, m: dict):
    """Write spot ``j``'s error files, then its spot file (a complete spot file implies complete error files: resume
    checks both), and summarise its error from the arrays in memory (the files are not read back): ``(summary,
    bound_summary)`` of :func:`~transient_mi.capture_error.spot_error_summary`, ``None`` where the capture has no
    such part."""
    bounded = stack.is_error_bound(m)  # the quadrature's error estimate stands where Monte Carlo's variance does
    remainder = stack.has_error_bound(m) and not bounded  # quadrature + Monte Carlo remainder: both files
    if remainder:
        stack.write_error_bound(d, j, res.error_bound, res.total_error_bound, m)
    v, tv = (res.error_bound, res.total_error_bound) if bounded else (res.variance, res.total_variance)
    if stack.has_variance(m):
        stack.write_variance(d, j, v, tv, m)
    stack.write_spot(d, j, res.histogram, m)
    summary = spot_error_summary(res.histogram, v, tv, bounded) if stack.has_variance(m) else None
    bound_summary = (spot_error_summary(res.histogram, res.error_bound, res.total_error_bound, True) if remainder
                     else None)
    return summary, bound_summary


def _run_render_locked(job: RenderJob, progress: bool | None, on_spot, log) -> Path:
    d = job.ideal_dir
    d.mkdir(parents=True, exist_ok=True)
    if log is None:
        def log(line: str) -> None:
            sys.stderr.write(line + "\n")
            sys.stderr.flush()
    if job.resume:
        remove_stale_temporaries(d)
    m = dict(job.manifest)
    n_files = m["n_files"]
    # A spot is done when its spot file, its variance file and its facts (dropped light, noise-target result:
    # OUT/.partial/spot_NNNNN.json) are all written; they are written in the order facts, variance, spot, so a
    # complete spot file implies the other two. The capture's figures are summed from the facts of every spot,
    # so a resumed capture states the same as an uninterrupted one.
    done = {j: read_spot_facts(d, j, m["render"]["config_sha256"]) for j in range(n_files)} if job.resume else {}
    todo = [j for j in range(n_files) if not (job.resume and done[j] is not None and stack.spot_is_complete(d, j, m)
                                              and stack.variance_is_complete(d, j, m))]
    facts: list[dict | None] = [None if j in todo else done[j] for j in range(n_files)]
    if job.resume and stack.manifest_path(d).exists():
        old = stack.read_manifest(d)
        m["render"]["render_time_s"] = (old.get("render") or {}).get("render_time_s", 0.0)
    stack.write_manifest(d, dict(m, status="incomplete"))
    W, H = m["width"], m["height"]
    paths_per_spot = W * H * job.spp
    t_start = time.perf_counter()
    preview_data = None
    summary_parts, bound_parts = {}, {}  # spot -> capture_error.spot_error_summary of the spots rendered here
    # Spots are rendered in fixed groups (NLOS array captures share sub-paths within a group); a group
    # with any spot missing is rendered again as a whole, so resumed captures keep the same bytes.
    if hasattr(job.sensor, "spot_groups"):
        groups = job.sensor.spot_groups(job.scene, job.spp)
    else:
        groups = [[j] for j in range(n_files)]
    todo_set = set(todo)
    groups = [g for g in groups if todo_set.intersection(g)]
    target_run = None
    if job.noise_target is not None:
        from .noise_target import TargetRun

        target_run = TargetRun(job.noise_target, m)
    # (the quadrature's capture-sized work arrays are kept from one group to the next: integrators._work_arrays)
    with progress_bar(f"render {job.scene_file.name}", total=sum(len(g) for g in groups) * paths_per_spot,
                      disable=None if progress is None else not progress) as advance, reuse_work_arrays():
        for group in groups:
            done_before = [0]

            def cb(done, total, _d=done_before):
                advance(done - _d[0])
                _d[0] = done

            seed_g = job.seed if n_files == 1 else spot_seed(job.seed, group[0])
            ckpt = None
            info = [None] * len(group)
            if job.noise_target is not None and stack.is_error_bound(m):  # refine the quadrature
                from .noise_target_quadrature import render_group_quadrature

                results, info = render_group_quadrature(job, target_run, group, log=log)
                advance(len(group) * paths_per_spot)
            elif job.noise_target is not None:
                from .noise_target import render_group

                results, info, ckpt = render_group(job, target_run, group, seed_g, m["render"]["config_sha256"],
                                                   log=log, progress=None)
                advance(len(group) * paths_per_spot)
            elif len(group) == 1:
                results = [job.integrator.render_transient(
                    job.scene, job.sensor, seed=seed_g, spp=job.spp,
                    spot=None if m["capture"] == "camera" else group[0], progress=cb)]
            else:
                results = job.integrator.render_transient(job.scene, job.sensor, seed=seed_g, spp=job.spp,
                                                          spots=group, progress=cb)
            written = [(j, res, inf) for j, res, inf in zip(group, results, info) if j in todo_set]
            for j, res, inf in written:  # (a spot not to do is complete from an earlier run, and identical)
                facts[j] = {"dropped_contributions": int(res.dropped_contributions),
                            "dropped_fraction": float(res.dropped_fraction),
                            "invalid_path_lengths": int(res.invalid_contributions),
                            "negative_fraction": float(res.negative_fraction), "noise_target": inf}
                write_spot_facts(d, j, m["render"]["config_sha256"], facts[j])
            # each spot's files on a thread of their own (compression and fsync release the GIL: the paper scene's
            # 32 x 32 capture at 1 ps bins spent 2.9 s writing its four spots one after another)
            with ThreadPoolExecutor(max_workers=max(1, min(len(written), WRITE_THREADS))) as pool:
                pending = [(j, res, pool.submit(_write_spot_files, d, j, res, m)) for j, res, _ in written]
                for j, res, fut in pending:  # in spot order, each once its files are complete
                    summary, bound_summary = fut.result()
                    if summary is not None:
                        summary_parts[j] = summary
                    if bound_summary is not None:
                        bound_parts[j] = bound_summary
                    if j == 0:
                        preview_data = (j, np.array(res.histogram))  # a copy: frees the group buffer
                    if on_spot is not None:
                        on_spot(j)
            del results
            if ckpt is not None:
                ckpt.unlink(missing_ok=True)
    elapsed = time.perf_counter() - t_start
    m["render"]["render_time_s"] = float(m["render"].get("render_time_s", 0.0) or 0.0) + elapsed
    dropped_n = sum(f["dropped_contributions"] for f in facts)
    frac_sum = 0.0
    for f in facts:  # in spot order, as an uninterrupted run adds them
        frac_sum += f["dropped_fraction"]
    invalid_n = sum(f["invalid_path_lengths"] for f in facts)
    negative = min([0.0] + [f["negative_fraction"] for f in facts])
    m["dropped"] = {"contributions": dropped_n, "fraction": frac_sum / n_files,
                    "invalid_path_lengths": invalid_n, "negative_fraction": negative}
    if invalid_n or negative < 0:
        log(f"warning: {invalid_n} contribution(s) had a NaN or -inf path length and were left out"
            + (f"; a spot binned more light than it recorded (dropped fraction {negative:.3g})" if negative < 0
               else "") + ": this is a bug, please report it with the scene (manifest 'dropped')")
    if preview_data is None:
        preview_data = (0, stack.read_spot(d, 0, m))
    from .preview import write_preview

    colour = preview_data[1] if m.get("channels") == ["R", "G", "B"] else None
    write_preview(d / "preview.png", stack.intensity(preview_data[1], m), m, spot=preview_data[0], rgb=colour)
    if stack.has_variance(m):
        m["variance"] = dict(m["variance"], summary=variance_summary(d, m, summary_parts))
    if stack.has_error_bound(m) and not stack.is_error_bound(m):
        m["error_bound"] = dict(m["error_bound"], summary=variance_summary(d, stack.error_bound_view(m), bound_parts))
    if job.noise_target is not None:
        spots_nt = [f["noise_target"] for f in facts]
        m["render"]["noise_target"]["spots"] = spots_nt
        if stack.is_error_bound(m):  # the quadrature's settings per spot
            m["variance"]["settings_per_spot"] = [{"element_size_m": s_["element_size_m"],
                                                  "patch_cells": s_["patch_cells"],
                                                  "refine_levels": s_["refine_levels"]} for s_ in spots_nt]
        else:
            m["variance"]["spp_per_spot"] = [s_["spp"] for s_ in spots_nt]
            m["variance"]["replicates_per_spot"] = [s_["replicates"] for s_ in spots_nt]
        m["render"]["noise_target"]["met"] = all(s_["met"] for s_ in spots_nt)
    m["status"] = "complete"
    stack.write_manifest(d, m)
    shutil.rmtree(d / PARTIAL_DIR, ignore_errors=True)
    if job.detect_kwargs is None:
        return d
    return _detect_into(job, d)


def _detect_into(job: RenderJob, ideal_dir: Path) -> Path:
    """Run the film's detector model on the ideal capture; counts land in ``job.out_dir``.

    (``detect_stack`` writes into a temporary sibling and moves the files in
    with the manifest last, keeping ``ideal/``.)
    """
    from spad_detector import detect_stack

    return detect_stack(ideal_dir, job.out_dir, progress=True, **job.detect_kwargs)


def render(scene_file, out_dir, *, defines=None, spp: int = 0, seed: int = 0, variant: str | None = None,
           resume: bool = False, progress: bool | None = None, noise_target=None) -> Path:
    """Validate, render and write a capture; see :mod:`transient_mi.render_capture`."""
    job = prepare_render(scene_file, out_dir, defines=defines, spp=spp, seed=seed, variant=variant,
                         resume=resume, noise_target=noise_target)
    return run_render(job, progress=progress)
