"""``preview.png``: a picture of a capture a person can look at.

Camera renders: the time-integrated image, four time slices (at the times by
which 10/30/50/70 % of the light has arrived) and an x-t streak image of the
middle row; in colour for R, G, B captures. NLOS captures: the time-integrated photons per pixel, the x-t
streak image of the middle pixel row and the histogram of the brightest
pixel, for one laser spot.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from transient_core.atomic import atomic_file


def _tonemap(img: np.ndarray) -> np.ndarray:
    """Scale to the 98th percentile and apply a 1/2.2 gamma (for display only)."""
    img = np.clip(np.nan_to_num(img.astype(np.float64)), 0, None)
    hi = np.percentile(img, 98.0) if img.size else 0.0
    if hi <= 0:
        hi = img.max() if img.max() > 0 else 1.0
    return np.clip(img / hi, 0, 1) ** (1 / 2.2)


def _tonemap_rgb(img: np.ndarray) -> np.ndarray:
    """``[H, W, 3]`` linear RGB for display: one scale for the three channels (the 98th percentile of the
    brightest channel), clipped, 1/2.2 gamma."""
    img = np.clip(np.nan_to_num(img.astype(np.float64)), 0, None)
    peak = img.max(axis=-1)
    hi = np.percentile(peak, 98.0) if peak.size else 0.0
    if hi <= 0:
        hi = peak.max() if peak.size and peak.max() > 0 else 1.0
    return np.clip(img / hi, 0, 1) ** (1 / 2.2)


def slice_bins(hist: np.ndarray, fractions=(0.1, 0.3, 0.5, 0.7)) -> list[int]:
    """Bins by which the given fractions of the light have arrived, every pixel weighted equally.

    (Weighting pixels equally keeps a directly visible light source from
    deciding every slice.)
    """
    flat = hist.reshape(-1, hist.shape[-1]).astype(np.float64)
    tot = flat.sum(axis=1, keepdims=True)
    per_bin = (flat / np.where(tot > 0, tot, 1.0)).sum(axis=0)
    cum = np.cumsum(per_bin)
    if cum[-1] <= 0:
        n = hist.shape[-1]
        return [int(f * (n - 1)) for f in fractions]
    return [int(np.searchsorted(cum, f * cum[-1])) for f in fractions]


def wall_return_mask(manifest: dict, spot: int, shape: tuple[int, int, int]) -> np.ndarray:
    """Bins ``[height, width, n_bins]`` that can hold the relay wall's own (first-bounce) return.

    For pixel patch centre ``P`` and laser spot ``S`` the earliest light that
    reaches a hidden point travels ``|L - S| + |S - P| + |P - D|`` (laser
    ``L``, detector ``D``; without them when the capture excludes the first
    and last segments; through windows the first and last legs' optical path
    lengths from the manifest); the wall return arrives no later than that plus the
    patch and spot size. Bins starting before that time plus a margin of one
    pixel footprint (times sqrt 2) and two bins are marked. Hidden-scene light
    arrives at least ``2 z / c`` later, so only objects within about a pixel
    footprint of the wall are hidden by the mask. All False when the capture
    has no wall return (``include_wall_return`` false) or no geometry.
    """
    H, W, n = shape
    g = manifest.get("geometry") or {}
    if not g.get("include_wall_return") or "pixel_centers" not in g or "spots" not in g:
        return np.zeros(shape, bool)
    c_m_per_ps = 299792458.0 * 1e-12
    P = np.asarray(g["pixel_centers"], np.float64).reshape(H, W, 3)
    S = np.asarray(g["spots"], np.float64).reshape(-1, 3)
    S = S[spot] if manifest["capture"] != "confocal" else S.reshape(H, W, 3)
    path = np.linalg.norm(P - S, axis=-1)
    if manifest.get("include_first_last") and g.get("spot_leg_opl_m") is not None:  # legs through windows
        legs = np.asarray(g["spot_leg_opl_m"], np.float64)
        legs = legs[spot] if manifest["capture"] != "confocal" else legs.reshape(H, W)
        path = path + legs + np.asarray(g["pixel_leg_opl_m"], np.float64).reshape(H, W)
    elif manifest.get("include_first_last"):
        L, D = np.asarray(g["laser_origin"], np.float64), np.asarray(g["detector_origin"], np.float64)
        path = path + np.linalg.norm(S - L, axis=-1) + np.linalg.norm(P - D, axis=-1)
    t = manifest["time"]
    margin_m = float(g.get("pixel_footprint_m", 0.0)) * np.sqrt(2) + 2 * t["bin_width_ps"] * c_m_per_ps
    t_end = (path + margin_m) / c_m_per_ps  # ps
    starts = t["t0_ps"] + np.arange(n) * t["bin_width_ps"]
    return starts[None, None, :] < t_end[..., None]


def write_preview(path: str | Path, hist: np.ndarray, manifest: dict, spot: int = 0,
                  rgb: np.ndarray | None = None) -> Path:
    """Write ``preview.png`` for one spot's histograms ``hist[height, width, n_bins]`` (atomically).

    ``rgb``: the same spot as ``[height, width, n_bins, 3]`` linear R, G, B (camera renders of colour
    captures), for the images in colour; the streak image stays the intensity ``hist``."""
    # The object-oriented API without pyplot: saving needs no backend, and the session's backend
    # (Jupyter's inline one, a GUI) is left alone.
    from matplotlib.figure import Figure

    t = manifest["time"]
    t0, bw, n = t["t0_ps"], t["bin_width_ps"], t["n_bins"]
    t_ns = lambda b: (t0 + (b + 0.5) * bw) / 1000.0  # noqa: E731
    H, W, _ = hist.shape
    steady = hist.sum(axis=-1, dtype=np.float64)
    row = H // 2
    streak = hist[row].astype(np.float64)  # [x, t]
    extent_xt = [t0 / 1000.0, (t0 + n * bw) / 1000.0, W - 0.5, -0.5]

    if manifest["capture"] == "camera":
        bins = slice_bins(hist)
        fig = Figure(figsize=(18, 3.4))
        axes = fig.subplots(1, 6, gridspec_kw={"width_ratios": [1, 1, 1, 1, 1, 1.6]})
        if rgb is None:
            axes[0].imshow(_tonemap(steady), cmap="gray")
        else:
            axes[0].imshow(_tonemap_rgb(rgb.sum(axis=2, dtype=np.float64)))
        axes[0].set_title("time-integrated")
        for ax, b in zip(axes[1:5], bins):
            lo, hi = max(0, b - 2), min(n, b + 3)
            if rgb is None:
                ax.imshow(_tonemap(hist[..., lo:hi].sum(axis=-1, dtype=np.float64)), cmap="inferno")
            else:
                ax.imshow(_tonemap_rgb(rgb[:, :, lo:hi].sum(axis=2, dtype=np.float64)))
            ax.set_title(f"t = {t_ns(b):.2f} ns")
        axes[5].imshow(_tonemap(streak), cmap="inferno", aspect="auto", extent=extent_xt)
        axes[5].set_title(f"x-t streak, row {row}")
        axes[5].set_xlabel("time (ns)")
        axes[5].set_ylabel("pixel x")
        for ax in axes[:5]:
            ax.set_xticks([])
            ax.set_yticks([])
    else:
        wall = wall_return_mask(manifest, spot, hist.shape)
        hidden = np.where(wall, 0.0, hist.astype(np.float64))
        steady_h = hidden.sum(axis=-1)
        fig = Figure(figsize=(14, 3.8))
        axes = fig.subplots(1, 3, gridspec_kw={"width_ratios": [1, 1.6, 1.6]})
        im = axes[0].imshow(steady_h, cmap="viridis", origin="lower")
        axes[0].set_title(f"photons/pulse, spot {spot}\n(wall return excluded)" if wall.any()
                          else f"photons/pulse, spot {spot}")
        fig.colorbar(im, ax=axes[0], fraction=0.046)
        axes[1].imshow(_tonemap(hidden[row]), cmap="inferno", aspect="auto", extent=extent_xt)
        axes[1].set_title(f"x-t streak, pixel row {row}" + (" (wall return excluded)" if wall.any() else ""))
        axes[1].set_xlabel("time (ns)")
        axes[1].set_ylabel("pixel x")
        y, x = np.unravel_index(int(np.argmax(steady_h if steady_h.max() > 0 else steady)), steady.shape)
        tt = (t0 + (np.arange(n) + 0.5) * bw) / 1000.0
        unit = manifest.get("quantity", "value") + " per bin"
        ax = axes[2]
        ax.plot(tt, hidden[y, x], color="C0", label="hidden scene")
        ax.set_title(f"histogram of pixel (y={y}, x={x})")
        ax.set_xlabel("time (ns)")
        ax.set_ylabel(unit, color="C0")
        wall_px = np.where(wall[y, x], hist[y, x].astype(np.float64), 0.0)
        if wall_px.any():  # the first bounce, orders of magnitude brighter: on its own axis
            ax2 = ax.twinx()
            ax2.plot(tt, wall_px, color="C1", lw=0.8)
            ax2.set_ylabel("wall return (own scale)", color="C1")
        fig.tight_layout()
    path = Path(path)
    with atomic_file(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=90)
    return path
