"""The photon-budget study: one render, detection over decades of budget, reconstruction of each.

1. Render the scene's ideal capture once (expected photons per pulse per bin).
2. For every laser power x dark-count rate x dead time x exposure per laser
   spot, and every detection seed: detect the capture with the SPAD + TCSPC
   model (in memory, the same counts ``transient-mi detect`` writes, see
   :mod:`.detection`), reconstruct it (backprojection + the paper's filter by
   default) and score it against the ground truth.
3. Over the seeds: the per-bin and per-pixel SNR against the detected counts,
   with the shot-noise limit and the dead-time (renewal) expectation
   (:mod:`.snr`).

Outputs (``out_dir``, built under a temporary name and renamed at the end):
``results.csv``/``results.json`` (one row per power, dark-count rate, dead
time, exposure and seed; byte-identical for the same arguments),
``timings.csv``/``timings.json`` (the run times, kept apart),
``snr_bins.csv``, ``snr_pixels.csv``, figures ``error_vs_photons.png``,
``snr_vs_photons.png``, ``reconstructions.png``, ``summary.md``, the ideal
capture ``ideal/`` (``transient-mi detect ideal -o ... --seed S`` reproduces
any row's counts) and ``ground_truth.ply`` for the paper scene.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from transient_core.progress import progress_bar
from transient_core.errors import UserInputError
from transient_mi.reporting import atomic_output_dir, markdown_table, write_csv, write_json

from . import validate as V
from .common import (METRIC_COLUMNS, bar_enabled, check_method_fits, front_view, metric_values, quiet_inner_bars,
                     reconstruct, render, resolve_noise_target, noise_target_spec)
from .study_result import StudyResult
from .scene import base_detector, load_study_ground_truth, reconstruction_bounds, study_scene

#: Exposure per laser spot (s): in the paper scene from 5 pulses (~0.07 detected counts per pixel per spot) to
#: 5e4 pulses (~700), well past where the reconstruction error stops improving (the paper's 10 ms, ~7000 counts,
#: costs seconds per run with strong dark counts: add it explicitly).
DEFAULT_EXPOSURES_S = (1e-7, 1e-6, 1e-5, 1e-4, 1e-3)
#: The paper's < 25 cps, a typical InGaAs/InP SPAD at 1550 nm, and a background comparable to the signal.
DEFAULT_DARK_COUNT_RATES_CPS = (25.0, 1e5, 1e7)
#: A fast SPAD (10 ns) and the microsecond hold-off InGaAs SPADs use against afterpulsing.
DEFAULT_DEAD_TIMES_NS = (10.0, 1000.0)
KEY_COLUMNS = ("laser_power_w", "exposure_s", "pulses_per_spot", "dark_count_rate_cps", "dead_time_ns", "seed")
ROW_COLUMNS = KEY_COLUMNS + ("counts_per_pixel_per_spot", "signal_counts_per_pixel_per_spot",
                             "background_counts_per_pixel_per_spot", "expected_background_low_flux_per_pixel_per_spot",
                             "p_det_mean", "p_det_max", "engines", "exact") + METRIC_COLUMNS
TIMING_COLUMNS = KEY_COLUMNS + ("detect_s", "reconstruct_s", "metrics_s", "total_s")
CONFIG_COLUMNS = ("laser_power_w", "exposure_s", "pulses_per_spot", "dark_count_rate_cps", "dead_time_ns")


def run_photon_budget_study(scene="paper_mannequin", out_dir="out/study-photon-budget", *, defines=None,
                            exposures_s=DEFAULT_EXPOSURES_S, dark_count_rates_cps=DEFAULT_DARK_COUNT_RATES_CPS,
                            dead_times_ns=DEFAULT_DEAD_TIMES_NS, seeds=(0, 1, 2), voxels=(64, 64, 32), seed: int = 0,
                            quick: bool = False, progress: bool | None = None, laser_powers_w=None,
                            ground_truth=None, detector=None, bounds=None, method: str = "bp",
                            threshold: str = "rel:0.3", overwrite: bool = False, log=None,
                            noise_target: float | None | str = "auto") -> StudyResult:
    """Run the photon-budget study (see the module docstring).

    Parameters
    ----------
    scene : str or path
        A shipped scene name (``paper_mannequin``) or an XML file.
    out_dir : path
        Output directory (must not exist or be empty, unless ``overwrite``).
    defines : dict, optional
        Scene parameters (``-D name=value``).
    exposures_s : sequence of float
        Exposure time per laser spot, seconds (pulses = exposure x repetition rate).
    dark_count_rates_cps : sequence of float
        Dark-count rates, counts per second (>= 0).
    dead_times_ns : sequence of float
        SPAD dead times, ns (>= 0; the TCSPC's own dead time stays that of the base detector).
    seeds : sequence of int
        Detection seeds (at least 2: the SNR is measured over them).
    voxels : int or (nx, ny, nz)
        Reconstruction grid.
    seed : int
        Render seed (also the metrics' surface-sampling seed).
    quick : bool
        Coarser render (paper scene: 8 ps bins, 256 spp; other scenes: 64 spp unless ``-D spp``).
    progress : bool, optional
        Progress bar (default: when stderr is a terminal).
    laser_powers_w : sequence of float, optional
        Laser average powers, W (default: the scene's). A power scales the photons per pulse, so, unlike the
        exposure, it changes the per-cycle detection probability and thus pile-up.
    ground_truth : path, trimesh.Trimesh, (n, 3) array or GroundTruth, optional
        For scenes other than the paper's: the hidden geometry (else no error metrics).
    detector : DetectorParams, optional
        Base detector (default: the paper's for the paper scene, else the defaults with ``auto_gate``).
    bounds : 6 floats, optional
        Reconstruction volume (default: the paper's, or recon's default for the capture).
    method, threshold : str
        Reconstruction method and the paper filter's threshold.
    overwrite : bool
        Replace an existing non-empty ``out_dir``.
    log : callable, optional
        ``log(message)`` for progress messages.
    noise_target : float, None or "auto"
        Render the ideal capture until its rendering variance is at most this share of the photon variance at
        the study's largest budget (largest exposure and power, lowest dark-count rate: every other setting
        then has a smaller ratio); the scene's spp is the pilot. ``"auto"``: 0.1 (0.01 where the quadrature
        renders the scene: :data:`~transient_mi.study.common.QUADRATURE_AUTO_TARGET`), or None with ``quick``.
        None: render the scene's spp as it is. Either way every budget's ratio is reported
        (``render_noise_ratio`` in the aggregate rows, the rendering-noise ceiling in the SNR figure).

    Returns
    -------
    StudyResult
    """
    log = log or (lambda msg: None)
    exposures = V.numbers_list(exposures_s, "exposures_s")
    darks = V.numbers_list(dark_count_rates_cps, "dark_count_rates_cps", lo_open=False)
    deads = V.numbers_list(dead_times_ns, "dead_times_ns", lo_open=False)
    powers = None if laser_powers_w is None else V.numbers_list(laser_powers_w, "laser_powers_w")
    seeds = V.integers_list(seeds, "seeds", 0, 2**63, min_count=2)
    vox = V.voxels(voxels)
    seed = V.integer(seed, "seed", 0, 2**32)
    quick = V.flag(quick, "quick")
    overwrite = V.flag(overwrite, "overwrite")
    progress = V.progress(progress)
    method = V.method(method)
    given_target = noise_target
    noise_target = resolve_noise_target(noise_target, quick)
    sc = study_scene(scene, defines, quick=quick)
    gt, gt_desc = load_study_ground_truth(sc, ground_truth)
    bnds = reconstruction_bounds(sc, bounds)
    base = base_detector(sc, detector)
    if sc.is_paper:  # the scene's repetition rate is known: check every budget holds a pulse
        for e in exposures:
            if round(e * 50e6) < 1:
                raise UserInputError(f"exposures_s: {e:g} s at the scene's 50 MHz is {e * 50e6:.3g} pulses; "
                                     "need at least 1 (>= 1e-8 s)")
    out = Path(out_dir)
    t_start = time.perf_counter()
    bar = bar_enabled(progress)
    with atomic_output_dir(out, overwrite) as tmp, quiet_inner_bars():
        log(f"rendering {sc.describe()}")
        t0 = time.perf_counter()
        over = {} if powers is None else {"laser_power_w": max(powers)}
        spec = noise_target_spec(given_target, noise_target, base.replace(dark_count_rate_cps=min(darks), **over),
                                 max(exposures))
        ideal_dir = render(sc, tmp / "ideal", seed, noise_target=spec, log=log)
        render_s = time.perf_counter() - t0
        if gt is not None and gt.mesh is not None:
            gt.mesh.export(tmp / "ground_truth.ply")
        run = _Run(sc, ideal_dir, base, exposures, darks, deads, powers, seeds, vox, seed, bnds, method,
                   threshold, gt, bar, log)
        run.execute()
        files = _write_outputs(tmp, run, sc, gt, gt_desc, quick, render_s, time.perf_counter() - t_start)
    log(f"wrote {out} in {time.perf_counter() - t_start:.1f} s")
    return StudyResult(study="photon_budget", out_dir=out, rows=run.rows, timings=run.timings,
                       tables={k: out / v for k, v in files["tables"].items()},
                       figures={k: out / v for k, v in files["figures"].items()}, summary=out / "summary.md",
                       snr_bins=run.snr_bins, snr_pixels=run.snr_pixels, aggregate=run.aggregate)


class _Run:
    """The detection and reconstruction loop of one study."""

    def __init__(self, sc, ideal_dir, base, exposures, darks, deads, powers, seeds, vox, seed, bounds, method,
                 threshold, gt, progress, log):
        from .detection import Detection, IdealCapture

        self.ideal = IdealCapture(ideal_dir)
        check_method_fits(method, self.ideal.manifest)
        if bounds is None:
            import recon
            from recon.grid import default_bounds

            bounds = default_bounds(recon.load_capture(ideal_dir))
        self.bounds = tuple(float(b) for b in bounds)
        laser = self.ideal.manifest.get("laser") or {}
        scene_power = laser.get("average_power_w")
        if powers is None and scene_power is None:
            raise UserInputError(f"{sc.path.name}: the capture's laser has no average_power_w")
        self.powers = (float(scene_power),) if powers is None else powers
        self.powers_given = powers is not None
        self.configs = []
        for pw in self.powers:
            for dark in darks:
                for dead in deads:
                    over = {} if powers is None else {"laser_power_w": pw}
                    params = base.replace(dark_count_rate_cps=dark, dead_time_ns=dead, **over).validate()
                    for e in sorted(exposures):
                        # builds the budget, gates and checks them before any detection
                        det = Detection(self.ideal, params, exposure_s=e)
                        self.configs.append(({"laser_power_w": pw, "exposure_s": e, "pulses_per_spot": det.n_pulses,
                                              "dark_count_rate_cps": dark, "dead_time_ns": dead}, det))
        self.seeds, self.vox, self.seed, self.method, self.threshold = seeds, vox, seed, method, threshold
        self.gt, self.progress, self.log = gt, progress, log
        self.rows, self.timings, self.snr_bins, self.snr_pixels, self.aggregate = [], [], [], [], []
        self.previews = []
        self.base = base

    def execute(self) -> None:
        from .snr import SnrStats

        n = len(self.configs) * len(self.seeds)
        self.log(f"{len(self.configs)} detector settings x {len(self.seeds)} seeds = {n} detections and "
                 "reconstructions")
        first = self.configs[0][0]
        with progress_bar("photon-budget study", total=n, mode=self.progress) as advance:
            for key, det in self.configs:
                stats = SnrStats(det, self.seeds)
                for s in self.seeds:
                    row, timing, rec = self._one(key, det, stats, s)
                    self.rows.append(row)
                    self.timings.append(timing)
                    if s == self.seeds[0] and all(key[k] == first[k] for k in
                                                  ("laser_power_w", "dark_count_rate_cps", "dead_time_ns")):
                        self.previews.append((f"{row['counts_per_pixel_per_spot']:.3g} counts/px/spot",
                                              front_view(rec)))
                    advance(1)
                bg = stats.expected_background_per_pixel()
                p = stats.p_det()
                for r in self.rows[-len(self.seeds):]:
                    sig = stats.signal_counts_per_pixel(r["seed"])
                    r["signal_counts_per_pixel_per_spot"] = sig
                    r["background_counts_per_pixel_per_spot"] = r["counts_per_pixel_per_spot"] - sig
                    r["expected_background_low_flux_per_pixel_per_spot"] = bg
                    r["p_det_mean"], r["p_det_max"] = float(p.mean()), float(p.max())
                self.snr_bins += [dict(key, **r) for r in stats.bin_rows()]
                self.snr_pixels += [dict(key, **r) for r in stats.pixel_rows()]
                agg = _aggregate(key, self.rows[-len(self.seeds):])
                rn = det.render_noise()
                agg["render_noise_ratio"] = rn.get("ratio")
                agg["render_noise_ratio_pixel_totals"] = (rn.get("pixel_totals") or {}).get("ratio_pooled")
                agg["render_snr_ceiling_bins"] = rn.get("snr_ceiling_bins")
                self.aggregate.append(agg)

    def _one(self, key: dict, det, stats, s: int):
        seen: set = set()
        acc = {"detect_s": 0.0, "counts": 0, "exact": True}
        engines: set = set()

        def on_spot(j, counts, info):
            acc["detect_s"] += info["detect_s"]
            if j in seen:  # a method that reads a spot twice gets the same counts; count them once
                return
            seen.add(j)
            stats.add(j, s, counts)
            engines.add(info["engine"])
            acc["exact"] = acc["exact"] and bool(info["exact"])
            acc["counts"] += int(counts.sum(dtype=np.int64))

        cap = det.capture(s, on_spot=on_spot)
        t0 = time.perf_counter()
        rec, metrics, t_rec, t_met = reconstruct(cap, method=self.method, bounds=self.bounds, voxels=self.vox,
                                                 threshold=self.threshold, ground_truth=self.gt, seed=self.seed)
        for j in range(det.ideal.n_files):  # every spot enters the statistics, whatever the method read
            if not stats.has(j, s):
                cap.spot(j)
        wall = time.perf_counter() - t0
        n_files, H, W, _ = det.ideal.shape
        row = dict(key, seed=s, counts_per_pixel_per_spot=acc["counts"] / (n_files * H * W),
                   signal_counts_per_pixel_per_spot=None, background_counts_per_pixel_per_spot=None,
                   expected_background_low_flux_per_pixel_per_spot=None, p_det_mean=None, p_det_max=None,
                   engines="/".join(sorted(engines)), exact=acc["exact"], **metric_values(metrics))
        timing = dict(key, seed=s, detect_s=acc["detect_s"], reconstruct_s=max(t_rec - acc["detect_s"], 0.0),
                      metrics_s=t_met, total_s=wall)
        return row, timing, rec


def _mean_sd(values):
    v = [x for x in values if x is not None]
    if not v:
        return None, None
    a = np.asarray(v, dtype=np.float64)
    return float(a.mean()), float(a.std(ddof=1)) if len(a) > 1 else 0.0


def _aggregate(key: dict, rows: list[dict]) -> dict:
    out = dict(key, n_seeds=len(rows))
    for k in ("counts_per_pixel_per_spot", "signal_counts_per_pixel_per_spot") + METRIC_COLUMNS:
        out[f"{k}_mean"], out[f"{k}_sd"] = _mean_sd([r.get(k) for r in rows])
    out["exact"] = all(r["exact"] for r in rows)
    return out


# ------------------------------------------------------------------ outputs


def _settings(run: _Run, sc, gt_desc: str, quick: bool) -> dict:
    from transient_mi.scene_io import file_sha256

    return {"scene": sc.name, "scene_file": sc.path.name, "scene_sha256": file_sha256(sc.path),
            "defines": dict(sorted(sc.defines.items())), "spp": sc.spp, "quick": quick, "render_seed": run.seed,
            "estimator": run.ideal.manifest.get("render", {}).get("estimator", "monte_carlo"),
            "detection_seeds": list(run.seeds), "exposures_s": sorted({k["exposure_s"] for k, _ in run.configs}),
            "laser_powers_w": list(run.powers),
            "dark_count_rates_cps": sorted({k["dark_count_rate_cps"] for k, _ in run.configs}),
            "dead_times_ns": sorted({k["dead_time_ns"] for k, _ in run.configs}),
            "detector": {k: v for k, v in run.base.to_dict().items()}, "method": run.method,
            "filter": "paper", "threshold": run.threshold, "voxels": list(run.vox), "bounds_m": list(run.bounds),
            "ground_truth": gt_desc,
            "ideal_capture": {"shape": list(run.ideal.shape), "time": run.ideal.manifest["time"],
                              "laser": run.ideal.manifest.get("laser")}}


def _write_outputs(tmp: Path, run: _Run, sc, gt, gt_desc: str, quick: bool, render_s: float, total_s: float) -> dict:
    from . import figures

    settings = _settings(run, sc, gt_desc, quick)
    write_csv(tmp / "results.csv", run.rows, ROW_COLUMNS)
    write_json(tmp / "results.json", {"study": "photon_budget", "settings": settings, "rows": run.rows,
                                      "aggregate": run.aggregate, "snr_bins": run.snr_bins,
                                      "snr_pixels": run.snr_pixels})
    write_csv(tmp / "snr_bins.csv", run.snr_bins, list(run.snr_bins[0]) if run.snr_bins else ["none"])
    write_csv(tmp / "snr_pixels.csv", run.snr_pixels, list(run.snr_pixels[0]) if run.snr_pixels else ["none"])
    write_csv(tmp / "timings.csv", run.timings, TIMING_COLUMNS)
    write_json(tmp / "timings.json", {"render_s": render_s, "total_s": total_s, "rows": run.timings})
    figs = {}
    if figures.error_vs_photons(tmp / "error_vs_photons.png", run.aggregate) is not None:
        figs["error_vs_photons"] = "error_vs_photons.png"
    ceilings = [a.get("render_snr_ceiling_bins") for a in run.aggregate if a.get("render_snr_ceiling_bins")]
    figures.snr_vs_photons(tmp / "snr_vs_photons.png", run.snr_bins, run.snr_pixels,
                           snr_ceiling=min(ceilings) if ceilings else None)
    figs["snr_vs_photons"] = "snr_vs_photons.png"
    k0 = run.configs[0][0]
    figures.reconstruction_strip(
        tmp / "reconstructions.png", run.previews, gt.mesh if gt is not None else None,
        title=f"filtered reconstructions (max over depth) per budget; dark {k0['dark_count_rate_cps']:g} cps, "
              f"dead time {k0['dead_time_ns']:g} ns, seed {run.seeds[0]}")
    figs["reconstructions"] = "reconstructions.png"
    _write_summary(tmp / "summary.md", run, settings, figs, render_s, total_s)
    return {"tables": {"results_csv": "results.csv", "results_json": "results.json", "timings_csv": "timings.csv",
                       "timings_json": "timings.json", "snr_bins_csv": "snr_bins.csv",
                       "snr_pixels_csv": "snr_pixels.csv"}, "figures": figs}


def detect_flags(base, with_power: bool) -> str:
    """``transient-mi detect`` options that turn the default detector into ``base`` (dark counts and dead time
    are given per row), plus ``--laser-power-w P`` when the study varies the power."""
    import dataclasses

    from spad_detector import DetectorParams

    default = DetectorParams()
    flags = []
    for f in dataclasses.fields(DetectorParams):
        name, v = f.name, getattr(base, f.name)
        if name in ("dark_count_rate_cps", "dead_time_ns", "laser_power_w") or v == getattr(default, name):
            continue
        opt = "--" + name.replace("_", "-")
        if isinstance(v, bool):
            flags.append(opt if v else "")
        elif v is None and name == "tcspc_max_count_rate_hz":
            flags.append(f"{opt} 0")
        elif v is not None:
            flags.append(f"{opt} {v:g}" if isinstance(v, float) else f"{opt} {v}")
    if with_power:
        flags.append("--laser-power-w P")
    return " ".join(f for f in flags if f)


def _render_noise_text(run) -> str:
    """The rendering-noise paragraph of the summary: the ratio per budget of the first configuration."""
    rs = [a for a in run.aggregate if a.get("render_noise_ratio") is not None]
    if not rs:
        return ("The ideal capture stores no variance, so the share of rendering noise in the counts is unknown "
                "(render with spp a multiple of the integrator's variance_replicates).")
    worst = max(a["render_noise_ratio"] for a in rs)
    k0 = run.configs[0][0]
    first = [a for a in rs if all(a[k] == k0[k] for k in ("laser_power_w", "dark_count_rate_cps", "dead_time_ns"))]
    table = markdown_table(["exposure (s)", "counts/px/spot", "rendering / photon variance (bins)",
                            "(pixel totals)"],
                           [[f"{a['exposure_s']:g}", f"{a['counts_per_pixel_per_spot_mean']:.4g}",
                             f"{a['render_noise_ratio']:.3g}", f"{a['render_noise_ratio_pixel_totals']:.3g}"]
                            for a in first])
    verdict = ("below 0.1 at every budget: the detection noise studied here is photon noise" if worst <= 0.1 else
               f"up to {worst:.3g}: where it exceeds 0.1 the counts (and the error and SNR across detection seeds, "
               "which freeze one render) show rendering noise, not only photon noise; render with a noise target")
    return (f"Every detection's counts carry the ideal capture's Monte Carlo noise as well as photon noise. Ratio "
            f"of the two variances (after gate, PDE and jitter; largest over bin classes holding >= 1 % of the "
            f"counts), for dark {k0['dark_count_rate_cps']:g} cps and dead time {k0['dead_time_ns']:g} ns: "
            f"{verdict}.\n\n{table}")


def _write_summary(path: Path, run: _Run, settings: dict, figs: dict, render_s: float, total_s: float) -> None:
    has_metrics = any(a.get("chamfer_m_mean") is not None for a in run.aggregate)
    table_rows = []
    def ms(a, k, scale=100.0, fmt="{:.2f}"):
        m, s = a.get(f"{k}_mean"), a.get(f"{k}_sd")
        return None if m is None else (fmt.format(scale * m) + " +- " + fmt.format(scale * s))

    for a in run.aggregate:
        row = [f"{1e3 * a['laser_power_w']:g}", f"{a['exposure_s']:g}", a["pulses_per_spot"],
               f"{a['dark_count_rate_cps']:g}", f"{a['dead_time_ns']:g}", f"{a['counts_per_pixel_per_spot_mean']:.4g}"]
        if has_metrics:
            row += [ms(a, "chamfer_m"), ms(a, "depth_mae_m"), ms(a, "iou", 1.0, "{:.3f}")]
        row.append("yes" if a["exact"] else "no")
        table_rows.append(row)
    headers = ["power (mW)", "exposure (s)", "pulses", "dark (cps)", "dead time (ns)", "counts/px/spot"]
    if has_metrics:
        headers += ["Chamfer (cm)", "depth MAE (cm)", "IoU"]
    headers.append("exact detection")
    table = markdown_table(headers, table_rows)

    from .snr import MIN_COINCIDENCES

    z = [(r["fano"] - 1.0) / r["fano_sd"] for r in run.snr_bins
         if r.get("fano_sd") and r["coincidences"] >= MIN_COINCIDENCES]
    within = sum(abs(v) <= 3 for v in z)
    pix = [r for r in run.snr_pixels if r.get("predicted_fano") is not None and r.get("fano_sd")]
    zp = [(r["fano"] - r["predicted_fano"]) / r["fano_sd"] for r in pix]
    s = settings
    metrics_note = ("Error metrics against " + s["ground_truth"] + ".") if has_metrics else \
        ("No error metrics: " + s["ground_truth"] + ".")
    figures_md = "\n".join(f"![{k}]({v})" for k, v in figs.items())
    text = f"""# Photon-budget study

Scene `{s['scene_file']}` ({', '.join(f'{k}={v}' for k, v in s['defines'].items()) or 'its defaults'}),
rendered once ({s['ideal_capture']['shape'][0]} laser spot(s), {s['ideal_capture']['shape'][1]} x
{s['ideal_capture']['shape'][2]} pixels, {s['ideal_capture']['shape'][3]} bins of
{s['ideal_capture']['time']['bin_width_ps']:g} ps, render seed {s['render_seed']}), then detected for every
laser power x dark-count rate x dead time x exposure per laser spot, with detection seeds
{s['detection_seeds']}, and reconstructed ({s['method']} + the paper's filter, threshold `{s['threshold']}`,
{s['voxels'][0]} x {s['voxels'][1]} x {s['voxels'][2]} voxels over {s['bounds_m']} m). Base detector: PDE
{s['detector']['pde']:g}, jitter {s['detector']['jitter_ps']:g} ps FWHM, TCSPC dead time
{s['detector']['tcspc_dead_time_ns']:g} ns, {'automatic gate' if s['detector']['auto_gate'] else 'gate as given'}.
{metrics_note}

## Reconstruction error against photon budget (mean +- sd over seeds)

{table}

## Rendering noise

{_render_noise_text(run)}

## SNR

Per bin (signal region, {len(run.snr_bins)} classes of expected counts over all settings, {len(z)} with at least
{MIN_COINCIDENCES:g} expected same-bin coincidences between seeds, where the Gaussian standard error holds): the
measured Fano factor var/mean is within 3 standard errors of 1 (Poisson, SNR = sqrt(N)) for {within} of {len(z)}
classes (largest |z| = {max((abs(v) for v in z), default=float('nan')):.2f}; the settings share their detection
seeds, so classes of different settings are correlated). Per pixel (total counts), where the
detector's whole-blind-cycles regime holds and at least 100 counts are expected, the renewal model's Fano
factor (1 - p) / (1 + m p)^2 is compared with the measurement: {sum(abs(v) <= 3 for v in zp)} of {len(zp)}
classes within 3 standard errors. Definitions: `transient_mi/study/snr.py`, docs/studies.md.

## Figures

{figures_md}

## Files

- `results.csv`, `results.json`: one row per (power, exposure, dark-count rate, dead time, seed); also the
  seed means (`aggregate`) and the SNR tables. Same arguments, same bytes.
- `snr_bins.csv`, `snr_pixels.csv`: the SNR classes.
- `timings.csv`, `timings.json`: seconds per run (render {render_s:.1f} s; total {total_s:.0f} s).
- `ideal/`: the ideal capture. A row's counts, byte for byte:
  `transient-mi detect ideal -o counts --exposure-s E --seed S --dark-count-rate-cps D --dead-time-ns T
  {detect_flags(run.base, len(run.powers) > 1 or run.powers_given)}`.
"""
    path.write_text(text)
