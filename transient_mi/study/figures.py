"""Figures of the studies (matplotlib, Agg backend, written atomically)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from transient_mi.reporting import save_figure, subplots

#: Error metrics a figure may show: key -> (label, scale to display units).
ERROR_PANELS = {
    "chamfer_m": ("Chamfer distance (cm)", 100.0),
    "depth_mae_m": ("depth MAE (cm)", 100.0),
    "iou": ("occupancy IoU", 1.0),
    "localisation_error_m": ("localisation error (cm)", 100.0),
}


def _config_label(r: dict, vary: set) -> str:
    parts = []
    if "laser_power_w" in vary:
        parts.append(f"{1e3 * r['laser_power_w']:g} mW")
    if "dark_count_rate_cps" in vary or not parts:
        parts.append(f"dark {r['dark_count_rate_cps']:g} cps")
    if "dead_time_ns" in vary:
        parts.append(f"dead {r['dead_time_ns']:g} ns")
    return ", ".join(parts)


def _styles(rows: list[dict]):
    """Colour per dark-count rate, line style per dead time (markers filled for the shortest, open otherwise),
    marker per laser power; and the set of keys that vary."""
    darks = sorted({r["dark_count_rate_cps"] for r in rows})
    deads = sorted({r["dead_time_ns"] for r in rows})
    powers = sorted({r["laser_power_w"] for r in rows})
    markers = "osD^v<>"
    lines = ["-", "--", ":", "-."]

    def style(r):
        color = f"C{darks.index(r['dark_count_rate_cps']) % 10}"
        return dict(color=color, linestyle=lines[deads.index(r["dead_time_ns"]) % len(lines)],
                    marker=markers[powers.index(r["laser_power_w"]) % len(markers)],
                    mfc=color if r["dead_time_ns"] == deads[0] else "none")

    vary = {k for k, v in (("dark_count_rate_cps", darks), ("dead_time_ns", deads), ("laser_power_w", powers))
            if len(v) > 1}
    return style, vary


def _configs(rows: list[dict]) -> list[tuple]:
    keys = sorted({(r["laser_power_w"], r["dark_count_rate_cps"], r["dead_time_ns"]) for r in rows})
    return keys


def error_vs_photons(path: Path, aggregate: list[dict]) -> Path | None:
    """Reconstruction error (mean +- sd over seeds) vs detected counts per pixel per spot; None if no metrics."""
    panels = [k for k in ERROR_PANELS if any(r.get(f"{k}_mean") is not None for r in aggregate)]
    if not panels:
        return None
    style, vary = _styles(aggregate)
    fig, axes = subplots(1, len(panels), figsize=(4.6 * len(panels), 3.8), squeeze=False)
    for ax, key in zip(axes[0], panels):
        label, scale = ERROR_PANELS[key]
        for cfg in _configs(aggregate):
            rs = sorted((r for r in aggregate if (r["laser_power_w"], r["dark_count_rate_cps"], r["dead_time_ns"])
                         == cfg and r.get(f"{key}_mean") is not None),
                        key=lambda r: r["counts_per_pixel_per_spot_mean"])
            if not rs:
                continue
            x = np.array([max(r["counts_per_pixel_per_spot_mean"], 1e-3) for r in rs])
            y = np.array([r[f"{key}_mean"] for r in rs]) * scale
            e = np.array([r[f"{key}_sd"] or 0.0 for r in rs]) * scale
            ax.errorbar(x, y, yerr=e, capsize=2, ms=4, lw=1.2, label=_config_label(rs[0], vary), **style(rs[0]))
        _render_noise_marks(ax, aggregate)
        ax.set_xscale("log")
        ax.set_xlabel("detected counts per pixel per laser spot")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3, which="both")
    axes[0, 0].legend(fontsize=7)
    worst = max((r.get("render_noise_ratio") or 0.0) for r in aggregate)
    fig.suptitle("Reconstruction error vs photon budget (mean and sd over detection seeds); rendering noise of the "
                 f"ideal capture <= {worst:.2g} x the photon noise at every budget", fontsize=10)
    fig.tight_layout()
    return save_figure(fig, path)


def _render_noise_marks(ax, aggregate: list[dict]) -> None:
    """Vertical lines where the ideal capture's rendering variance reaches 0.1 x and 1 x the photon variance
    (interpolated in log-log over the first configuration's budgets; R grows in proportion to the budget)."""
    cfgs = _configs(aggregate)
    if not cfgs:
        return
    rs = sorted((r for r in aggregate if (r["laser_power_w"], r["dark_count_rate_cps"], r["dead_time_ns"]) == cfgs[0]
                 and r.get("render_noise_ratio")), key=lambda r: r["counts_per_pixel_per_spot_mean"])
    if len(rs) < 2:
        return
    x = np.log([max(r["counts_per_pixel_per_spot_mean"], 1e-3) for r in rs])
    y = np.log([r["render_noise_ratio"] for r in rs])
    for level, ls in ((0.1, ":"), (1.0, "--")):
        if y[0] <= math.log(level) <= y[-1]:
            xv = float(np.exp(np.interp(math.log(level), y, x)))
            ax.axvline(xv, color="0.3", ls=ls, lw=1,
                       label=f"rendering noise = {level:g} x photon noise" if level == 1.0 else
                       "rendering noise = 0.1 x photon noise")


def snr_vs_photons(path: Path, snr_bins: list[dict], snr_pixels: list[dict], snr_ceiling: float | None = None) -> Path:
    """Per-bin SNR, per-bin signal SNR and per-pixel SNR against detected counts, with the closed forms.

    ``snr_ceiling``: the ideal capture's rendering-noise ceiling on the per-bin SNR (mu / sqrt(V), the
    inverse relative rendering error, independent of the budget), drawn as a horizontal line.
    """
    fig, axes = subplots(1, 3, figsize=(15, 4.4))

    def ok(*vals):
        return all(v is not None and math.isfinite(v) and v > 0 for v in vals)

    snr_bins = [r for r in snr_bins if ok(r["mean_counts"], r["snr"])]
    snr_pixels = [r for r in snr_pixels if ok(r["mean_counts"], r["snr"])]
    rows = snr_bins + snr_pixels
    style, vary = _styles(rows) if rows else (lambda r: {}, set())

    def line(ax, lo, hi, label):
        x = np.logspace(math.log10(lo), math.log10(hi), 50)
        ax.plot(x, np.sqrt(x), color="k", lw=1, label=label)

    ax = axes[0]
    seen = set()
    for r in snr_bins:
        st = style(r)
        lab = _config_label(r, vary)
        ax.plot(r["mean_counts"], r["snr"], linestyle="none", marker=st["marker"], color=st["color"], ms=4,
                mfc=st["mfc"], alpha=0.8, label=None if lab in seen else lab)
        seen.add(lab)
    if snr_bins:
        xs = [r["mean_counts"] for r in snr_bins]
        line(ax, min(xs) / 2, max(xs) * 2, "Poisson: SNR = sqrt(N)")
    if snr_ceiling:
        ax.axhline(snr_ceiling, color="C1", ls="--", lw=1.2,
                   label=f"rendering-noise ceiling of this render (SNR {snr_ceiling:.3g}): across renders, "
                         "SNR = N / sqrt(N + V)")
    ax.set_title("per bin: mean / sd of counts over seeds", fontsize=10)
    ax.set_xlabel("detected counts per bin (N)")
    ax.set_ylabel("SNR")

    ax = axes[1]
    pos = [r for r in snr_bins if ok(r["signal_counts"], r["signal_snr"], r["signal_snr_poisson"])]
    for r in pos:
        st = style(r)
        ax.plot(r["signal_counts"], r["signal_snr"], linestyle="none", marker=st["marker"], color=st["color"], ms=4,
                mfc=st["mfc"], alpha=0.8)
        ax.plot(r["signal_counts"], r["signal_snr_poisson"], linestyle="none", marker="_", color="k", ms=7)
    if pos:
        xs = [r["signal_counts"] for r in pos]
        line(ax, min(xs) / 2, max(xs) * 2, "shot-noise limit sqrt(N_s)")
        ax.plot([], [], linestyle="none", marker="_", color="k", ms=7, label="Poisson with background: "
                "N_s / sqrt(N_s + N_bg)")
    ax.set_title("per bin, signal only: N_s / sd (the scene's photons)", fontsize=10)
    ax.set_xlabel("detected signal counts per bin (N_s)")
    ax.set_ylabel("signal SNR")

    ax = axes[2]
    for r in snr_pixels:
        st = style(r)
        ax.plot(r["mean_counts"], r["snr"], linestyle="none", marker=st["marker"], color=st["color"], ms=4,
                mfc=st["mfc"], alpha=0.8)
        if r.get("predicted_snr") is not None and ok(r["predicted_snr"]):
            ax.plot(r["mean_counts"], r["predicted_snr"], linestyle="none", marker="o", mfc="none", ms=10,
                    mew=1.5, color="k")
    if snr_pixels:
        xs = [r["mean_counts"] for r in snr_pixels]
        line(ax, min(xs) / 2, max(xs) * 2, "Poisson: sqrt(N)")
        if any(r.get("predicted_snr") is not None for r in snr_pixels):
            ax.plot([], [], linestyle="none", marker="o", mfc="none", ms=10, mew=1.5, color="k",
                    label="renewal model (whole blind cycles): sqrt(N / F)")
    ax.set_title("per pixel: total counts of a histogram", fontsize=10)
    ax.set_xlabel("detected counts per pixel per spot (N)")
    ax.set_ylabel("SNR")
    for ax in axes:
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.grid(alpha=0.3, which="both")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
    fig.suptitle("SNR over repeated detections of one render, which freezes its rendering noise (colour: dark-count rate; filled markers: the "
                 "shortest dead time, open: longer ones)", fontsize=10)
    fig.tight_layout()
    return save_figure(fig, path)


def reconstruction_strip(path: Path, previews: list[tuple[str, dict]], mesh=None, title: str = "") -> Path:
    """Front views (filtered volume, max over z) side by side, after the ground-truth silhouette if known."""
    n = len(previews) + (1 if mesh is not None else 0)
    fig, axes = subplots(1, n, figsize=(2.6 * n, 2.9), squeeze=False)
    axes = axes[0]
    i = 0
    if mesh is not None and previews:
        from recon.ground_truth import ground_truth_silhouette

        v = previews[0][1]
        axes[0].imshow(ground_truth_silhouette(mesh, v["x_m"], v["y_m"]), origin="lower", extent=v["extent"],
                       cmap="gray")
        axes[0].set_title("ground truth", fontsize=9)
        i = 1
    for ax, (label, v) in zip(axes[i:], previews):
        ax.imshow(v["image"], origin="lower", extent=v["extent"], cmap="inferno")
        ax.set_title(label, fontsize=9)
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return save_figure(fig, path)


def array_size_figure(path: Path, rows: list[dict], timings: list[dict]) -> Path:
    """Error metrics and the time of each step against the array size."""
    n = [r["array"] for r in rows]
    fig, axes = subplots(1, 2, figsize=(11, 4.8))
    ax = axes[0]
    have = False
    for key, label in (("chamfer_m", "Chamfer"), ("accuracy_m", "accuracy"), ("completeness_m", "completeness"),
                       ("depth_mae_m", "depth MAE"), ("localisation_error_m", "localisation")):
        ys = [r.get(key) for r in rows]
        if any(y is not None for y in ys):
            have = True
            ax.plot(n, [np.nan if y is None else 100 * y for y in ys], marker="o", label=label)
    ax.set_xlabel("SPAD array side (pixels)")
    ax.set_ylabel("error (cm)")
    handles, labels = ax.get_legend_handles_labels()
    if any(r.get("iou") is not None for r in rows):
        tw = ax.twinx()
        tw.plot(n, [np.nan if r.get("iou") is None else r["iou"] for r in rows], marker="s", color="k", ls="--",
                label="IoU (right axis)")
        tw.set_ylabel("occupancy IoU")
        h2, l2 = tw.get_legend_handles_labels()
        handles, labels = handles + h2, labels + l2
    if have:  # below the axes: never over the data
        ax.legend(handles, labels, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=3, fontsize=8,
                  frameon=False)
    else:
        ax.text(0.5, 0.5, "no ground truth: no error metrics", transform=ax.transAxes, ha="center")
    ax.set_xscale("log", base=2)
    ax.set_xticks(n, [f"{a}x{a}" for a in n])
    ax.set_title("reconstruction error", fontsize=10)
    ax = axes[1]
    for key in ("render_s", "detect_s", "reconstruct_s", "metrics_s", "total_s"):
        ax.plot(n, [t[key] for t in timings], marker="o", label=key[:-2], lw=2 if key == "total_s" else 1.2)
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xticks(n, [f"{a}x{a}" for a in n])
    ax.set_xlabel("SPAD array side (pixels)")
    ax.set_ylabel("wall-clock time (s)")
    ax.set_title("time per step", fontsize=10)
    ax.grid(alpha=0.3, which="both")
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=3, fontsize=8, frameon=False)
    fig.tight_layout()
    return save_figure(fig, path)
