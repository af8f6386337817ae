"""``transient-mi demo``: the paper's mannequin experiment end to end, on the embedded defaults.

For each SPAD array size (4x4, 8x8, 16x16, 32x32):

1. render the ideal capture of ``scenes/paper_mannequin.xml`` (expected
   photons per pulse per bin; the laser scans 2 x 2 spots over the 1 m wall);
2. detect it with the paper's detector (70 % PDE, 25 ps FWHM jitter, 25 cps
   dark counts, automatic gate with 120 ps transitions, 20 MHz TCSPC) for
   the photon budget;
3. reconstruct with ellipsoidal backprojection, then the paper's filter
   (Gaussian, Laplacian, threshold);
4. score against the rendered mannequin (Chamfer distance, depth error,
   occupancy IoU).

Then write figures in the spirit of the paper's Fig. 4 (histograms per array
size) and Fig. 5 (raw and filtered reconstructions per array size next to the
ground-truth silhouette), ``metrics.csv``/``metrics.json`` and ``summary.md``.
The output directory is built under a temporary name and renamed when
complete.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from transient_core.errors import UserInputError

from .capture_error import quadrature_settings_per_spot
from .experiment import (HistogramSum, detect_counts, ground_truth, reconstruct, render_ideal,
                         write_ground_truth)
# DemoSettings and QUICK live in paper.py, beside the settings they start from, so the studies read them
# without importing the demo
from .paper import PAPER, PAPER_BOUNDS_M, QUICK, DemoSettings, paper_detector  # noqa: F401  (re-exported)
from .noise_target import rendered_spp
from .noise_target_quadrature import coarser_start
from .reporting import METRIC_KEYS, atomic_output_dir, save_figure as _savefig, subplots, write_csv


@dataclass
class ArrayResult:
    array: int
    metrics: dict
    times_s: dict
    pulses_per_spot: int
    counts_per_pixel_per_spot: float
    files: dict = field(default_factory=dict)
    spp: int = 0
    render_noise: dict = field(default_factory=dict)
    #: which estimator made the ideal capture (``quadrature`` or ``monte_carlo``) and, for the quadrature, the
    #: largest element size (m), fewest cells per patch side and fewest visibility refinement levels its spots were
    #: rendered with
    estimator: str = "monte_carlo"
    quadrature: dict = field(default_factory=dict)


def _is_previous_demo(out: Path) -> bool:
    """A directory written by an earlier demo run (its summary.md says so)."""
    summary = out / "summary.md"
    return summary.is_file() and summary.read_text(errors="replace").startswith("# transient-mi demo:")


def run_demo(out_dir="out/demo", *, quick: bool = False, settings: DemoSettings | None = None,
             overwrite: bool = False, progress: bool | None = None, log=print) -> Path:
    """Run the demo; returns the output directory (see the module docstring).

    An existing ``out_dir`` is replaced only if it holds an earlier demo's
    output (or with ``overwrite``); anything else is refused.
    """
    s = settings if settings is not None else (QUICK if quick else DemoSettings())
    for a in s.arrays:
        if not isinstance(a, int) or a < 1:
            raise UserInputError(f"--arrays: {a!r} is not a positive integer")
    out = Path(out_dir)
    t_start = time.perf_counter()
    with atomic_output_dir(out, overwrite or _is_previous_demo(out)) as tmp:
        results, hists = _run(tmp, s, progress, log)
        gt = ground_truth(s.config(s.arrays[0]))
        log("writing figures, metrics and summary")
        _figure_histograms(tmp / "fig4_histograms.png", hists, s)
        _figure_reconstructions(tmp / "fig5_reconstructions.png", tmp, results, gt, s)
        _figure_best_array_method(tmp, results, gt, s)
        _write_metrics(tmp, results)
        total = time.perf_counter() - t_start
        _write_summary(tmp / "summary.md", results, s, quick, total)
    log(f"wrote {out} in {time.perf_counter() - t_start:.1f} s")
    return out


def _run(tmp: Path, s: DemoSettings, progress, log):
    """Render, detect and reconstruct every array size; returns results and histograms."""
    from recon.output import write_outputs

    cfg0 = s.config(s.arrays[0])
    write_ground_truth(cfg0, tmp / "ground_truth.ply")
    mesh = ground_truth(cfg0)
    params = paper_detector()
    (tmp / "recon").mkdir()
    results, hists = [], {}
    start = {}  # the quadrature settings the noise target starts from (below)
    target = s.target()
    for i, n in enumerate(s.arrays):
        cfg = s.config(n).replace(**start)
        cap = tmp / "captures" / f"array_{n:02d}"
        cap.mkdir(parents=True)
        log(f"[{i + 1}/{len(s.arrays)}] {n}x{n} SPAD array: render, detect, reconstruct")
        t0 = time.perf_counter()
        ideal = render_ideal(cfg, cap / "ideal", seed=s.seed, progress=progress, noise_target=target,
                             exposure_s=s.exposure_s, params=params, log=log)
        t1 = time.perf_counter()
        time_axis = json.loads((ideal / "manifest.json").read_text())["time"]
        sum_ideal, sum_counts = HistogramSum(time_axis), HistogramSum(time_axis)

        def summed(j, ideal_j, counts_j):  # (Fig. 4's histograms, from the arrays detect holds: no files read back)
            sum_ideal.add(ideal_j)
            sum_counts.add(counts_j)

        counts = detect_counts(ideal, cap / "counts", params=params, exposure_s=s.exposure_s,
                               seed=s.seed + 1, progress=progress is not False, on_spot=summed)
        t2 = time.perf_counter()
        rec, metrics = reconstruct(counts, voxels=s.voxels, bounds=PAPER_BOUNDS_M, threshold=s.threshold,
                                   mesh=mesh, seed=s.seed)
        t3 = time.perf_counter()
        # (the capture as the demo folder names it: ``counts`` lies in the temporary folder renamed at the end)
        source = f"captures/array_{n:02d}/counts"
        write_outputs(tmp / "recon" / f"array_{n:02d}", rec, meta={"capture": {"source": source}}, metrics=metrics)
        t_ideal, h_ideal, h_counts = sum_ideal.t_ns, sum_ideal.total, sum_counts.total
        m = json.loads((counts / "manifest.json").read_text())
        pulses = int(m["detector"]["pulses"])
        hists[n] = (t_ideal, h_ideal, h_counts, m["detector"]["resolved"])
        n_spots = m["n_files"]
        rn = m["detector"]["resolved"].get("render_noise") or {}
        estimator, quad = _estimator_of(ideal)
        if estimator == "quadrature" and target is not None:
            # the next array starts its refinement from the settings this one needed (same scene, exposure and
            # detector: the same parts of the error set its ratio), not from the scene's: one round instead of two;
            # its elements enlarged by what this one's ratio leaves below the target (coarser_start)
            start = _next_start(ideal, target)
        spp_used = 0 if estimator == "quadrature" else rendered_spp(ideal, s.spp)
        results.append(ArrayResult(
            array=n, metrics=metrics, pulses_per_spot=pulses, spp=spp_used, render_noise=rn,
            estimator=estimator, quadrature=quad,
            counts_per_pixel_per_spot=float(h_counts.sum() / (n * n * n_spots)),
            times_s={"render": t1 - t0, "detect": t2 - t1, "reconstruct": t3 - t2},
            files={"ideal": f"captures/array_{n:02d}/ideal", "counts": f"captures/array_{n:02d}/counts",
                   "recon": f"recon/array_{n:02d}"}))
        with np.load(tmp / "recon" / f"array_{n:02d}" / "volume.npz") as z:
            assert z["volume"].shape == tuple(reversed(s.voxels))
    return results, hists


#: The quadrature's settings a capture records per spot
#: (:func:`~transient_mi.capture_error.quadrature_settings_per_spot`).
_QUADRATURE_SETTINGS = ("element_size_m", "patch_cells", "refine_levels")


def _next_start(ideal: Path, target: float) -> dict:
    """Where the next array's refinement starts, from a rendered ideal capture's manifest (read once): the finest
    quadrature settings any of its spots needed (smallest ``element_size_m``, most ``patch_cells`` and
    ``refine_levels``), as :class:`~transient_mi.paper.PaperConfig` fields, its elements enlarged by what its worst
    spot's ratio (``render.noise_target.spots``) leaves below ``target``
    (:func:`~transient_mi.noise_target_quadrature.coarser_start`); empty for a capture without those settings."""
    m = json.loads((Path(ideal) / "manifest.json").read_text())
    per = quadrature_settings_per_spot(m)
    if not all(k in p for p in per for k in _QUADRATURE_SETTINGS):
        return {}
    finest = {"element_size_m": min(p["element_size_m"] for p in per),
              "patch_cells": max(p["patch_cells"] for p in per),
              "refine_levels": max(p["refine_levels"] for p in per)}
    spots = ((m.get("render") or {}).get("noise_target") or {}).get("spots") or []
    ratios = [float(p["ratio"]) for p in spots if p and p.get("ratio") is not None]
    return coarser_start(finest, max(ratios) if ratios else float("nan"), target)


def _estimator_of(ideal: Path) -> tuple[str, dict]:
    """``(estimator, settings)`` of a rendered ideal capture (its manifest): for the quadrature, the coarsest
    element size, cells per patch side and visibility levels over its spots (refined ones with a noise target)."""
    m = json.loads((Path(ideal) / "manifest.json").read_text())
    est = (m.get("render") or {}).get("estimator", "monte_carlo")
    if est != "quadrature":
        return est, {}
    per = quadrature_settings_per_spot(m)
    coarsest = {"element_size_m": max, "patch_cells": min, "refine_levels": min}
    return est, {k: pick(p[k] for p in per) for k, pick in coarsest.items() if all(k in p for p in per)}


# ------------------------------------------------------------------ figures


#: The array method shown beside the paper's backprojection (the leaderboard's best on the mannequin's surface).
BEST_ARRAY_METHOD = "midpoint-fk"


def _figure_best_array_method(root: Path, results: list[ArrayResult], mesh, s: DemoSettings) -> None:
    """``fig6_methods.png`` and ``methods.json``: the largest array's counts reconstructed with
    :data:`BEST_ARRAY_METHOD` (its default filter) beside the paper's backprojection, both scored, and the same
    reconstruction closed behind its front under the completion prior (:mod:`recon.completion`), scored too."""
    import recon
    from recon.completion import complete_surface
    from recon.filters import depth_map
    from recon.ground_truth import ground_truth_silhouette
    from recon.metrics import GroundTruth, compute_metrics, mesh_occupancy
    from recon.output import load_volume, write_outputs
    from transient_mi.study.methods import COMPLETION_SUFFIX

    r = results[-1]
    gt = GroundTruth(mesh=mesh, source="mannequin")
    cap = recon.load_capture(root / r.files["counts"])
    rec = recon.reconstruct(cap, BEST_ARRAY_METHOD, bounds=PAPER_BOUNDS_M, voxels=s.voxels)
    metrics = compute_metrics(rec, gt, seed=s.seed)
    name = f"recon/array_{r.array:02d}_{BEST_ARRAY_METHOD}"
    write_outputs(root / name, rec, meta={"capture": {"source": r.files["counts"]}}, metrics=metrics)
    done = complete_surface(rec, "auto")
    done_metrics = compute_metrics(done, gt, seed=s.seed)
    done_name = f"{name}_completed"
    write_outputs(root / done_name, done, meta={"capture": {"source": r.files["counts"]}}, metrics=done_metrics)
    bp = load_volume(root / r.files["recon"])
    keys = ("chamfer_m", "completeness_m", "iou", "depth_mae_m", "visible_chamfer_m", "visible_completeness_m",
            "visible_iou", "silhouette_iou", "normal_error_deg")
    bp_metrics = compute_metrics(bp, gt, seed=s.seed)
    completed = f"{BEST_ARRAY_METHOD}{COMPLETION_SUFFIX}"
    table = {"array": r.array, "recon": {"bp": r.files["recon"], BEST_ARRAY_METHOD: name, completed: done_name},
             "metrics": {"bp": {k: bp_metrics.get(k) for k in keys},
                         BEST_ARRAY_METHOD: {k: metrics.get(k) for k in keys},
                         completed: {k: done_metrics.get(k) for k in keys}},
             "completion": done.params["completion"]}
    (root / "methods.json").write_text(json.dumps(table, indent=1) + "\n")
    g = rec.grid
    ext = [g.x_m[0], g.x_m[-1], g.y_m[0], g.y_m[-1]]
    side_ext = [g.z_m[0], g.z_m[-1], g.y_m[0], g.y_m[-1]]

    def side(ax, occupancy, title):   # the view from the side (+x): depth z across, height y up
        ax.imshow(occupancy.any(axis=2).T, origin="lower", extent=side_ext, cmap="gray")
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("z (m)")

    fig, axes = subplots(2, 4, figsize=(14, 7.8))
    axes[0, 0].imshow(ground_truth_silhouette(mesh, g.x_m, g.y_m), origin="lower", extent=ext, cmap="gray")
    axes[0, 0].set_title("ground-truth silhouette")
    side(axes[1, 0], mesh_occupancy(mesh, g, seed=s.seed), "ground truth, side view")
    for col, (label, vol, mt) in enumerate((("bp (the paper's pipeline)", bp.volume, bp_metrics),
                                            (BEST_ARRAY_METHOD, rec.volume, metrics)), start=1):
        axes[0, col].imshow(vol.max(axis=0), origin="lower", extent=ext, cmap="inferno")
        axes[0, col].set_title(f"{label}: filtered, front view", fontsize=9)
        im = axes[1, col].imshow(depth_map(vol, g), origin="lower", extent=ext, cmap="viridis",
                                 vmin=g.z_m[0], vmax=g.z_m[-1])
        axes[1, col].set_title(f"depth; Chamfer {_fmt(mt.get('chamfer_m'), 100, '.2f')} cm, "
                               f"IoU {_fmt(mt.get('iou'), 1, '.2f')},\n"
                               f"depth MAE {_fmt(mt.get('depth_mae_m'), 100, '.2f')} cm, "
                               f"normals {_fmt(mt.get('normal_error_deg'), 1, '.0f')} deg", fontsize=8)
        fig.colorbar(im, ax=axes[1, col], fraction=0.046, label="z (m)")
    side(axes[0, 3], rec.volume > 0, f"{BEST_ARRAY_METHOD}, side view: the front only\n"
                                     f"(visible Chamfer {_fmt(metrics.get('visible_chamfer_m'), 100, '.2f')} cm)")
    aspects = ", ".join(f"{a['aspect']:.2f}" for a in done.params["completion"]["aspects"][:3])
    side(axes[1, 3], done.volume > 0,
         f"closed behind the front\n(a prior: elliptical sections, aspect {aspects}):\n"
         f"Chamfer {_fmt(done_metrics.get('chamfer_m'), 100, '.2f')} cm, "
         f"completeness {_fmt(done_metrics.get('completeness_m'), 100, '.2f')} cm,\n"
         f"IoU {_fmt(done_metrics.get('iou'), 1, '.2f')} (whole mesh)")
    fig.suptitle(f"{r.array}x{r.array} array, same counts: the paper's backprojection and {BEST_ARRAY_METHOD} "
                 "(midpoint conversion + f-k migration), and its completion behind the front", fontsize=10)
    fig.tight_layout()
    _savefig(fig, root / "fig6_methods.png")


def _figure_histograms(path: Path, hists: dict, s: DemoSettings) -> None:
    """Fig. 4 style: per array size, the detected histogram (all pixels and spots) and the ideal expectation."""
    arrays = list(hists)
    fig, axes = subplots(1, len(arrays), figsize=(4.2 * len(arrays), 3.6), sharey=False)
    axes = np.atleast_1d(axes)
    for ax, n in zip(axes, arrays):
        t, ideal, counts, resolved = hists[n]
        pulses = s.exposure_s * PAPER.repetition_rate_hz
        expected = _jittered(ideal, t, paper_detector()) * pulses * PAPER.pde
        ax.semilogy(t, np.clip(expected, 1e-3, None), color="0.6", lw=0.8,
                    label="expected counts: photons x PDE, jitter (no gate)")
        ax.semilogy(t, np.clip(counts, 0.5, None), color="C3", lw=0.8, label="detected counts (gated)")
        g0, g1 = resolved.get("gate_open_ps"), resolved.get("gate_close_ps")
        if g0 is not None and g1 is not None:
            ax.axvspan(g0 / 1000, g1 / 1000, color="C2", alpha=0.12, label="gates (per spot) open")
        ax.set_title(f"{n} x {n} SPAD array")
        ax.set_xlabel("time of flight (ns)")
        ax.set_ylim(0.5, None)
    axes[0].set_ylabel("counts per bin (all pixels and spots)")
    handles, labels = axes[0].get_legend_handles_labels()
    # one legend for every panel, below them: never over the data
    fig.legend(handles, labels, loc="lower center", ncol=len(labels), fontsize=8, frameon=False)
    fig.suptitle("Histograms per array size (cf. the paper's Fig. 4), summed over pixels and laser spots: the "
                 "mannequin's three-bounce light arrives over ~15-23 ns; shaded: the span of the per-spot gates",
                 fontsize=10)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    _savefig(fig, path)


def _fmt(v, scale: float, spec: str) -> str:
    """``v * scale`` formatted, or ``n/a`` for a metric that could not be computed (e.g. an empty volume)."""
    return "n/a" if v is None else format(scale * v, spec)


def _jittered(values: np.ndarray, t_ns: np.ndarray, params) -> np.ndarray:
    """``values`` (per bin, bin centres ``t_ns``) convolved with the detector's jitter kernel."""
    from spad_detector.jitter import Jitter
    from spad_detector.model import apply_jitter_kernel

    bw_ps = float(t_ns[1] - t_ns[0]) * 1000.0 if len(t_ns) > 1 else 1.0
    first, kernel = Jitter.from_params(params).bin_kernel(bw_ps, max_shift_bins=len(values))
    return apply_jitter_kernel(np.asarray(values, dtype=np.float64)[None], first, kernel)[0]


def _figure_reconstructions(path: Path, root: Path, results: list[ArrayResult], mesh, s: DemoSettings) -> None:
    """Fig. 5 style: raw and filtered front views per array size, next to the ground-truth silhouette."""
    from recon.ground_truth import ground_truth_silhouette

    n = len(results)
    fig, axes = subplots(n, 4, figsize=(12.5, 3.0 * n), squeeze=False)
    for row, r in enumerate(results):
        with np.load(root / r.files["recon"] / "volume.npz") as z:
            raw, vol, x, y, zz = z["raw"], z["volume"], z["x_m"], z["y_m"], z["z_m"]
        ext = [x[0], x[-1], y[0], y[-1]]
        sil = ground_truth_silhouette(mesh, x, y)
        axes[row, 0].imshow(sil, origin="lower", extent=ext, cmap="gray")
        axes[row, 0].set_title("ground-truth silhouette" if row == 0 else "")
        axes[row, 1].imshow(raw.max(axis=0), origin="lower", extent=ext, cmap="inferno")
        axes[row, 1].set_title(f"{r.array}x{r.array}: raw backprojection")
        axes[row, 2].imshow(vol.max(axis=0), origin="lower", extent=ext, cmap="inferno")
        axes[row, 2].set_title("filtered (Gaussian, Laplacian, threshold)")
        depth = np.where((vol > 0).any(axis=0), zz[np.argmax(vol, axis=0)], np.nan)
        im = axes[row, 3].imshow(depth, origin="lower", extent=ext, cmap="viridis", vmin=zz[0], vmax=zz[-1])
        mt = r.metrics or {}
        axes[row, 3].set_title(f"depth; Chamfer {100 * (mt.get('chamfer_m') or np.nan):.1f} cm, "
                               f"IoU {mt.get('iou') or 0:.2f}", fontsize=9)
        fig.colorbar(im, ax=axes[row, 3], fraction=0.046, label="z (m)")
        for ax in axes[row]:
            ax.set_xlabel("x (m)")
            ax.set_ylabel("y (m)")
    fig.suptitle("Reconstructions per array size (cf. the paper's Fig. 5), seen from the wall", fontsize=11)
    fig.tight_layout()
    _savefig(fig, path)


# ------------------------------------------------------------------ tables


def _write_metrics(root: Path, results: list[ArrayResult]) -> None:
    rows = []
    for r in results:
        row = {"array": f"{r.array}x{r.array}", "pixels": r.array * r.array}
        row.update({k: (r.metrics or {}).get(k) for k in METRIC_KEYS})
        row.update({"counts_per_pixel_per_spot": r.counts_per_pixel_per_spot, "pulses_per_spot": r.pulses_per_spot,
                    "spp": r.spp, "estimator": r.estimator, **{f"quadrature_{k}": v for k, v in r.quadrature.items()},
                    "render_noise_ratio": r.render_noise.get("ratio"),
                    "render_noise_ratio_pixel_totals": (r.render_noise.get("pixel_totals") or {}).get("ratio_pooled")})
        row.update({f"{k}_s": round(v, 3) for k, v in r.times_s.items()})
        rows.append(row)
    write_csv(root / "metrics.csv", rows)
    (root / "metrics.json").write_text(json.dumps(
        {"rows": rows, "per_array": {r.array: asdict(r) for r in results}}, indent=1, default=float) + "\n")


def metrics_table_markdown(rows: list[dict]) -> str:
    """The metrics as a Markdown table (used by summary.md and the README)."""
    def cm(v):
        return "n/a" if v is None else f"{100 * v:.2f}"

    def ratio(v):
        return "n/a" if v is None else f"{v:.3g}"

    def rendered(r):  # which estimator made the capture, and with what
        if r.get("estimator", "monte_carlo") != "quadrature":
            return f"{r.get('spp', 'n/a')} spp"
        h, c = r.get("quadrature_element_size_m"), r.get("quadrature_patch_cells")
        lv = r.get("quadrature_refine_levels")
        return "quadrature" + (f", {1000 * h:.3g} mm, {c} cell{'' if c == 1 else 's'}" if h is not None and c is not None
                               else "") + ("" if lv is None else f", {lv} visibility level{'' if lv == 1 else 's'}")

    lines = ["| array | Chamfer (cm) | accuracy (cm) | completeness (cm) | depth MAE (cm) | depth coverage | IoU | "
             "counts / pixel / spot | rendered with | rendering / photon noise (bins; pixel totals) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        cov = "n/a" if r["depth_coverage"] is None else f"{r['depth_coverage']:.2f}"
        iou = "n/a" if r["iou"] is None else f"{r['iou']:.3f}"
        lines.append(f"| {r['array']} | {cm(r['chamfer_m'])} | {cm(r['accuracy_m'])} | {cm(r['completeness_m'])} | "
                     f"{cm(r['depth_mae_m'])} | {cov} | {iou} | {r['counts_per_pixel_per_spot']:.0f} | "
                     f"{rendered(r)} | {ratio(r.get('render_noise_ratio'))}; "
                     f"{ratio(r.get('render_noise_ratio_pixel_totals'))} |")
    return "\n".join(lines)


def _spp_text(s: DemoSettings) -> str:
    target = s.target()
    if s.estimator == "quadrature":
        if target is None:
            return ("Three-bounce light integrated deterministically (estimator=quadrature, the scene's element size "
                    "and cells; docs/quadrature.md)")
        return ("Three-bounce light integrated deterministically (estimator=quadrature), its elements and cells "
                f"refined per spot until the stated error is at most {target:g} x the photon noise at the "
                "budget (`transient-mi render --noise-target`)")
    if target is None:
        return f"Monte Carlo, {s.spp} samples per pixel per spot"
    return (f"Monte Carlo, samples per pixel per spot chosen per spot so that rendering noise is at most "
            f"{target:g} x the photon noise at the budget (pilot {s.spp} spp; "
            "`transient-mi render --noise-target`)")


def _noise_text(s: DemoSettings, results: list) -> str:
    worst = max((r.render_noise.get("ratio") or 0.0) for r in results)
    target = s.target()
    if target is None and s.estimator == "quadrature":
        return (f"This run used the quadrature's default settings and no noise target: the ratio reaches "
                f"{worst:.3g}.")
    if target is None:
        return (f"This run used a fixed {s.spp} spp and no noise target: the ratio reaches {worst:.3g}, so the "
                "detected counts here show rendering noise as much as photon noise (run without --quick for "
                "captures rendered to a noise target: 0.01 by the quadrature, the demo's default).")
    ok = worst <= target
    return (f"Target {target:g}: " + ("met for every array" if ok else
            f"NOT met (largest ratio {worst:.3g}, by a factor {worst / target:.2g})") + ".")


def _write_summary(path: Path, results: list[ArrayResult], s: DemoSettings, quick: bool, total_s: float) -> None:
    rows = json.loads((path.parent / "metrics.json").read_text())["rows"]
    timing = "\n".join(f"| {r.array}x{r.array} | {r.times_s['render']:.1f} | {r.times_s['detect']:.1f} | "
                       f"{r.times_s['reconstruct']:.1f} |" for r in results)
    P, B = PAPER, PAPER_BOUNDS_M
    text = f"""# transient-mi demo: the paper's mannequin experiment{' (--quick)' if quick else ''}

Scene `scenes/paper_mannequin.xml`: {P.wall_size_m:g} m x {P.wall_size_m:g} m Lambertian relay wall (albedo
{P.wall_albedo:g}) at z = 0, a {P.mannequin_height_m * 100:g} cm x {P.mannequin_width_m * 100:g} cm mannequin (albedo
{P.mannequin_albedo:g}) centred {P.mannequin_distance_m * 100:g} cm in front of it, {P.wavelength_nm:g} nm laser at
{P.repetition_rate_hz / 1e6:g} MHz and {s.power_w * 1e3:g} mW scanned over {s.spots} x {s.spots} wall spots, SPAD arrays
whose pixels each see {P.pixel_footprint_m * 100:g} cm x {P.pixel_footprint_m * 100:g} cm of wall spread over the whole
wall. {_spp_text(s)}, {s.n_bins} bins of {s.bin_width_ps:g} ps from {s.t0_ps / 1000:g} ns. Detector: the paper's
({P.pde * 100:g} % PDE, {P.jitter_ps:g} ps FWHM jitter, {P.dark_count_rate_cps:g} cps dark counts, automatic gate with
{P.gate_transition_ps:g} ps transitions, {P.tcspc_max_count_rate_hz / 1e6:g} MHz TCSPC), {s.exposure_s * 1e3:g} ms per
laser spot. Reconstruction: ellipsoidal backprojection, Gaussian + Laplacian filter, threshold
`{s.threshold}`, {s.voxels[0]} x {s.voxels[1]} x {s.voxels[2]} voxels over x in [{B[0]:g}, {B[1]:g}] m,
y in [{B[2]:g}, {B[3]:g}] m, z in [{B[4]:g}, {B[5]:g}] m. Seed {s.seed}. Total time {total_s:.0f} s.

## Metrics against the rendered mannequin

{metrics_table_markdown(rows)}

Chamfer = mean of accuracy (reconstructed voxels to the surface) and completeness (surface to the
reconstruction); depth MAE over the columns where both exist; IoU of occupied voxels
(definitions: `recon/metrics.py`).

## Rendering noise against photon noise

The ideal capture is an estimate (by {s.estimator}; the "rendered with" column); detection draws photon counts
around it, so the counts carry the render's error as well as the photon noise. "rendering / photon noise" is the
ratio of the two variances in the detected bins (after gate, PDE and jitter; the largest over classes of bins
holding >= 1 % of the counts), and on per-pixel totals; `detect` computes it from the error every ideal capture
stores (`variance/`: a Monte Carlo capture's variance from independent replicates, or the quadrature's error
estimate squared). {_noise_text(s, results)}

## Figures

- [fig4_histograms.png](fig4_histograms.png): histograms per array size (the paper's Fig. 4).
- [fig5_reconstructions.png](fig5_reconstructions.png): raw and filtered reconstructions per array size
  next to the ground-truth silhouette (the paper's Fig. 5).
- [fig6_methods.png](fig6_methods.png), `methods.json`: the largest array's counts reconstructed with
  {BEST_ARRAY_METHOD} beside the paper's backprojection, and closed behind its front under a stated prior
  (elliptical cross-sections, `recon/completion.py`: the back sends no three-bounce light, so it is assumed,
  not measured).

![histograms](fig4_histograms.png)

![reconstructions](fig5_reconstructions.png)

## Files

- `ground_truth.ply`: the rendered mannequin.
- `captures/array_NN/ideal`, `captures/array_NN/counts`: EXR stacks (`transient-mi detect` and
  `transient-mi recon` take them).
- `recon/array_NN/`: `volume.npz` (`volume`, `raw`, `x_m`, `y_m`, `z_m`), projections, depth map,
  `metrics.json`.
- `metrics.csv`, `metrics.json`: the table above, with timings.

## Timings (s)

| array | render | detect | reconstruct |
|---|---|---|---|
{timing}
"""
    path.write_text(text)
