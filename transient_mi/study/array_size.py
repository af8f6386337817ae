"""The array-size study: the paper's sweep of SPAD array sizes (4x4 .. 32x32) and beyond (64x64).

For every array size: render the scene's ideal capture (``-D array=N``, or
``-D width=N -D height=N`` for scenes without ``array``), detect it with the
detector for ``exposure_s`` per laser spot (detection seed ``seed + 1``), load
the counts capture from disk and reconstruct it (backprojection + the paper's
filter by default), score it against the ground truth, and time each step
(wall clock, with the disk I/O a user's pipeline has). The smallest size is
first run once untimed (Mitsuba and numba compile their kernels on first use).

Outputs (``out_dir``, built under a temporary name and renamed at the end):
``results.csv``/``results.json`` (one row per array size: metrics, counts,
data sizes; byte-identical for the same arguments), ``timings.csv``/
``timings.json``, ``array_size.png`` (error and time against array size),
``reconstructions.png``, ``summary.md``, and with ``keep_captures`` the
captures ``captures/array_NN/{ideal,counts}``.
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path

import numpy as np

from transient_core.progress import progress_bar
from transient_core.errors import UserInputError
from transient_mi.reporting import atomic_output_dir, markdown_table, write_csv, write_json

from . import validate as V
from .common import (METRIC_COLUMNS, bar_enabled, capture_estimator, check_method_fits, front_view, metric_values,
                     quiet_inner_bars, reconstruct, render)
from .study_result import StudyResult
from .scene import array_size_defines, base_detector, load_study_ground_truth, reconstruction_bounds, study_scene

#: The paper's array sizes and 64x64.
DEFAULT_ARRAYS = (4, 8, 16, 32, 64)
ROW_COLUMNS = ("array", "pixels", "n_spots", "pulses_per_spot", "counts_per_pixel_per_spot", "render_noise_ratio",
               "estimator", "ideal_bytes", "counts_bytes", "engines", "exact") + METRIC_COLUMNS
TIMING_COLUMNS = ("array", "render_s", "detect_s", "reconstruct_s", "metrics_s", "total_s")


def run_array_size_study(scene="paper_mannequin", out_dir="out/study-array-size", *, arrays=DEFAULT_ARRAYS,
                         defines=None, exposure_s: float = 0.01, voxels=(64, 64, 32), seed: int = 0,
                         quick: bool = False, progress: bool | None = None, ground_truth=None, detector=None,
                         bounds=None, method: str = "bp", threshold: str = "rel:0.3", keep_captures: bool = False,
                         overwrite: bool = False, log=None) -> StudyResult:
    """Run the array-size study (see the module docstring).

    Parameters
    ----------
    scene : str or path
        A shipped scene name (``paper_mannequin``) or an XML file with an
        ``array`` parameter or ``width`` and ``height``.
    out_dir : path
        Output directory (must not exist or be empty, unless ``overwrite``).
    arrays : sequence of int
        Array sides (pixels), each in [1, 256].
    defines : dict, optional
        Further scene parameters (``-D``); the array size is set by the study.
    exposure_s : float
        Exposure per laser spot, seconds (the paper's budget: 10 ms, 5e5 pulses at 50 MHz).
    voxels : int or (nx, ny, nz)
    seed : int
        Render seed; detection uses ``seed + 1``.
    quick : bool
        Coarser render (paper scene: 8 ps bins, 256 spp).
    progress : bool, optional
        Progress bar (default: when stderr is a terminal).
    ground_truth, detector, bounds, method, threshold
        As for :func:`~transient_mi.study.run_photon_budget_study`.
    keep_captures : bool
        Keep every ideal and counts capture under ``captures/`` (they are
        deleted after use otherwise; a 64x64 capture with 1 ps bins is large).
    overwrite : bool
    log : callable, optional

    Returns
    -------
    StudyResult
    """
    log = log or (lambda msg: None)
    arrays = tuple(sorted(V.integers_list(arrays, "arrays", 1, 257)))
    (exposure,) = V.numbers_list([exposure_s] if not isinstance(exposure_s, (list, tuple)) else exposure_s,
                                 "exposure_s")
    vox = V.voxels(voxels)
    seed = V.integer(seed, "seed", 0, 2**32)
    quick = V.flag(quick, "quick")
    keep = V.flag(keep_captures, "keep_captures")
    overwrite = V.flag(overwrite, "overwrite")
    progress = V.progress(progress)
    method = V.method(method)
    sc = study_scene(scene, defines, quick=quick)
    if any(k in (defines or {}) for k in array_size_defines(sc, arrays[0])):
        raise UserInputError(f"defines: {', '.join(array_size_defines(sc, arrays[0]))} are set by the study; "
                             "choose the sizes with arrays (--arrays)")
    gt, gt_desc = load_study_ground_truth(sc, ground_truth)
    bnds = reconstruction_bounds(sc, bounds)
    params = base_detector(sc, detector)
    if sc.is_paper and round(exposure * 50e6) < 1:
        raise UserInputError(f"exposure_s={exposure:g}: at the scene's 50 MHz that is {exposure * 50e6:.3g} pulses; "
                             "need at least 1")
    out = Path(out_dir)
    t_start = time.perf_counter()
    bar = bar_enabled(progress)
    rows, timings, previews = [], [], []
    with atomic_output_dir(out, overwrite) as tmp, quiet_inner_bars():
        if gt is not None and gt.mesh is not None:
            gt.mesh.export(tmp / "ground_truth.ply")
        with progress_bar("array-size study", total=len(arrays) + 1, mode=bar) as advance:
            # Warm-up, untimed: Mitsuba compiles its kernels (and numba its loops) on first use, which would
            # otherwise be charged to the first array size.
            log(f"warm-up: {arrays[0]}x{arrays[0]} (not timed)")
            _one(tmp / "warmup", sc.with_defines(**array_size_defines(sc, arrays[0])), arrays[0], params, exposure,
                 vox, seed, bnds, method, threshold, None, False)
            shutil.rmtree(tmp / "warmup", ignore_errors=True)
            advance(1)
            for i, n in enumerate(arrays):
                log(f"[{i + 1}/{len(arrays)}] {n}x{n} SPAD array: render, detect, reconstruct")
                row, timing, rec, bnds = _one(tmp, sc.with_defines(**array_size_defines(sc, n)), n, params,
                                              exposure, vox, seed, bnds, method, threshold, gt, keep)
                rows.append(row)
                timings.append(timing)
                previews.append((f"{n}x{n}", front_view(rec)))
                advance(1)
        if not keep and (tmp / "captures").exists():
            shutil.rmtree(tmp / "captures")
        total = time.perf_counter() - t_start
        files = _write_outputs(tmp, sc, rows, timings, previews, gt, gt_desc, params, exposure, vox, seed, bnds,
                               method, threshold, quick, total)
    log(f"wrote {out} in {time.perf_counter() - t_start:.1f} s")
    return StudyResult(study="array_size", out_dir=out, rows=rows, timings=timings,
                       tables={k: out / v for k, v in files["tables"].items()},
                       figures={k: out / v for k, v in files["figures"].items()}, summary=out / "summary.md",
                       aggregate=rows)


def _dir_bytes(path: Path) -> int:
    return sum(f.stat().st_size for f in path.glob("spot_*.exr"))


def _one(tmp: Path, sc, n: int, params, exposure: float, vox, seed: int, bounds, method, threshold, gt, keep: bool):
    import recon
    from transient_core.stack import iter_spots, read_manifest
    from spad_detector import detect_stack

    cap_dir = tmp / "captures" / f"array_{n:02d}"
    cap_dir.mkdir(parents=True)
    t0 = time.perf_counter()
    ideal = render(sc, cap_dir / "ideal", seed)
    t1 = time.perf_counter()
    check_method_fits(method, read_manifest(ideal))
    counts = detect_stack(ideal, cap_dir / "counts", params, exposure_s=exposure, seed=seed + 1, progress=False)
    t2 = time.perf_counter()
    capture = recon.load_capture(counts)
    if bounds is None:
        from recon.grid import default_bounds

        bounds = tuple(float(b) for b in default_bounds(capture))
    rec, metrics, _, t_met = reconstruct(capture, method=method, bounds=bounds, voxels=vox, threshold=threshold,
                                             ground_truth=gt, seed=seed)
    t3 = time.perf_counter()
    m = read_manifest(counts)
    total = sum(int(d.sum(dtype=np.int64)) for _, d in iter_spots(counts))
    res = m["detector"]["resolved"]
    row = {"array": n, "pixels": n * n, "n_spots": m["n_files"], "pulses_per_spot": int(m["detector"]["pulses"]),
           "counts_per_pixel_per_spot": total / (n * n * m["n_files"]),
           # rendering variance / photon variance of these counts (spad_detector.render_noise; None if unknown)
           "render_noise_ratio": (res.get("render_noise") or {}).get("ratio"),
           # which estimator made the ideal capture (quadrature: a stated error, not samples)
           "estimator": capture_estimator(ideal), "ideal_bytes": _dir_bytes(ideal),
           "counts_bytes": _dir_bytes(counts), "engines": "/".join(sorted(set(res["engines_used"]))),
           "exact": bool(res["exact"]), **metric_values(metrics)}
    timing = {"array": n, "render_s": t1 - t0, "detect_s": t2 - t1, "reconstruct_s": t3 - t2 - t_met,
              "metrics_s": t_met, "total_s": t3 - t0}
    if not keep:
        shutil.rmtree(cap_dir)
    return row, timing, rec, bounds


def _write_outputs(tmp: Path, sc, rows, timings, previews, gt, gt_desc, params, exposure, vox, seed, bounds, method,
                   threshold, quick, total_s) -> dict:
    from transient_mi.scene_io import file_sha256

    from . import figures

    settings = {"scene": sc.name, "scene_file": sc.path.name, "scene_sha256": file_sha256(sc.path),
                "defines": {k: v for k, v in sorted(sc.defines.items()) if k not in ("array", "width", "height")},
                "spp": sc.spp, "quick": quick, "arrays": [r["array"] for r in rows], "exposure_s": exposure,
                "render_seed": seed, "detection_seed": seed + 1, "detector": params.to_dict(), "method": method,
                "filter": "paper", "threshold": threshold, "voxels": list(vox),
                "bounds_m": None if bounds is None else list(bounds), "ground_truth": gt_desc}
    write_csv(tmp / "results.csv", rows, ROW_COLUMNS)
    write_json(tmp / "results.json", {"study": "array_size", "settings": settings, "rows": rows})
    write_csv(tmp / "timings.csv", timings, TIMING_COLUMNS)
    write_json(tmp / "timings.json", {"total_s": total_s, "rows": timings})
    figures.array_size_figure(tmp / "array_size.png", rows, timings)
    figures.reconstruction_strip(tmp / "reconstructions.png", previews, gt.mesh if gt is not None else None,
                                 title="filtered reconstructions (max over depth) per array size")
    figs = {"array_size": "array_size.png", "reconstructions": "reconstructions.png"}
    _write_summary(tmp / "summary.md", settings, rows, timings, figs, total_s)
    return {"tables": {"results_csv": "results.csv", "results_json": "results.json", "timings_csv": "timings.csv",
                       "timings_json": "timings.json"}, "figures": figs}


def _noise_sentence(rows, spp: int) -> str:
    """How much of the counts' noise is the ideal captures' rendering noise (measured per array), and which
    estimator made them (Monte Carlo at ``spp``, or the quadrature, whose stated error stands for it)."""
    ratios = {r["array"]: r.get("render_noise_ratio") for r in rows if r.get("render_noise_ratio") is not None}
    if not ratios:
        return "The ideal captures store no variance: their rendering noise is unknown."
    from spad_detector.render_noise import DEFAULT_THRESHOLD

    worst = max(ratios.values())
    per = ", ".join(f"{a}x{a}: {v:.3g}" for a, v in ratios.items())
    quadrature = {r.get("estimator") for r in rows} == {"quadrature"}
    verdict = (f"at most the usual {DEFAULT_THRESHOLD:g}" if worst <= DEFAULT_THRESHOLD else
               f"above the usual {DEFAULT_THRESHOLD:g}: part of the error at large arrays is "
               + ("the quadrature's discretisation error, not photon noise; use `study methods`, which refines it "
                  "to a noise target" if quadrature else
                  "Monte Carlo noise, not photon noise; raise `-D spp` (or use `study methods`, which renders to a "
                  "noise target)"))
    made = ("by the deterministic quadrature, its stated error bound standing for the noise" if quadrature
            else f"{spp} spp")
    return (f"Rendering noise of the ideal captures ({made}) relative to the photon noise at this budget "
            f"(`spad_detector.render_noise`): {per}; {verdict}.")


def _write_summary(path: Path, s: dict, rows, timings, figs, total_s: float) -> None:
    def cm(v):
        return f"{100 * v:.2f}"

    has = any(r.get("chamfer_m") is not None for r in rows)
    headers = ["array", "counts/px/spot"]
    fmts = [None, lambda v: f"{v:.4g}"]
    if has:
        headers += ["Chamfer (cm)", "accuracy (cm)", "completeness (cm)", "depth MAE (cm)", "IoU"]
        fmts += [cm, cm, cm, cm, lambda v: f"{v:.3f}"]
    headers += ["ideal data (MB)", "render (s)", "detect (s)", "reconstruct (s)", "metrics (s)", "exact detection"]
    fmts += [lambda v: f"{v / 1e6:.1f}"] + [lambda v: f"{v:.1f}"] * 4 + [None]
    table_rows = []
    for r, t in zip(rows, timings):
        row = [f"{r['array']}x{r['array']}", r["counts_per_pixel_per_spot"]]
        if has:
            row += [r["chamfer_m"], r["accuracy_m"], r["completeness_m"], r["depth_mae_m"], r["iou"]]
        row += [r["ideal_bytes"], t["render_s"], t["detect_s"], t["reconstruct_s"], t["metrics_s"],
                "yes" if r["exact"] else "no (analytic engine, Markov-chain regime)"]
        table_rows.append(row)
    d = s["detector"]
    text = f"""# Array-size study

Scene `{s['scene_file']}` ({', '.join(f'{k}={v}' for k, v in s['defines'].items()) or 'its defaults'}), SPAD
arrays {', '.join(f'{a}x{a}' for a in s['arrays'])}. Each size: render (seed {s['render_seed']}), detection for
{s['exposure_s'] * 1e3:g} ms per laser spot (PDE {d['pde']:g}, jitter {d['jitter_ps']:g} ps FWHM, dark counts
{d['dark_count_rate_cps']:g} cps, dead time {d['dead_time_ns']:g} ns, TCSPC {d['tcspc_dead_time_ns']:g} ns,
{'automatic gate' if d['auto_gate'] else 'gate as given'}; seed {s['detection_seed']}), reconstruction
({s['method']} + the paper's filter, threshold `{s['threshold']}`, {s['voxels'][0]} x {s['voxels'][1]} x
{s['voxels'][2]} voxels over {s['bounds_m']} m). Ground truth: {s['ground_truth']}. Total {total_s:.0f} s.

{markdown_table(headers, table_rows, fmts)}

{_noise_sentence(rows, s['spp'])}

Times are wall clock on this machine, with the disk I/O of each step (EXR stacks written and read).
Chamfer = mean of accuracy (reconstructed voxels to the surface) and completeness (surface to the
reconstruction); definitions in `recon/metrics.py`.

## Figures

{chr(10).join(f'![{k}]({v})' for k, v in figs.items())}

## Files

- `results.csv`, `results.json`: one row per array size (same arguments, same bytes).
- `timings.csv`, `timings.json`: seconds per step.
"""
    path.write_text(text)
