"""Figure for docs/noise.md: rendering noise against photon noise on the paper scene.

Renders the embedded paper scene (4 x 4 array, 2 x 2 laser spots, 8 ps bins) at several spp, detects each
with the paper's detector at the demo's budget (10 ms per spot), and draws

* left: one pixel's expected counts at a low and a high spp with the rendering +-1 sd band (from the stored
  variance) and the photon (Poisson) +-1 sd band;
* right: the noise ratio (rendering / photon variance, bins and pixel totals) against spp, with the 1/spp law.

With 8 ps bins the jitter averages rendering noise over fewer bins than with the paper's 1 ps bins, so the
ratio per bin is higher here than in the demo at the same spp (docs/noise.md).

Run: ``python bench/noise_figure.py`` (writes docs/img/render_noise.png and bench/results/render_noise_vs_spp.json;
a few minutes on 2 cores).
"""

from __future__ import annotations

import json
import platform
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SPPS = (64, 256, 1024, 4096, 16384, 65536)
EXPOSURE_S = 0.01


def main() -> None:
    import transient_mi  # noqa: F401
    from transient_core import stack
    from spad_detector import detect_stack
    from spad_detector.model import apply_jitter_kernel
    from spad_detector.stream import resolve_gates, spot_model_for
    from spad_detector.budget import resolve_budget
    from transient_mi.experiment import PaperConfig, paper_detector, render_ideal
    from transient_mi.reporting import save_figure, subplots

    params = paper_detector()
    rows, curves = [], {}
    with tempfile.TemporaryDirectory() as td:
        for spp in SPPS:
            cfg = PaperConfig(array=4, spots=2, spp=spp, bin_width_ps=8.0, n_bins=1438, estimator="monte_carlo")
            t0 = time.perf_counter()
            ideal = render_ideal(cfg, Path(td) / f"ideal_{spp}", seed=1, progress=False)
            t_render = time.perf_counter() - t0
            counts = detect_stack(ideal, Path(td) / f"counts_{spp}", params, exposure_s=EXPOSURE_S, seed=0,
                                  progress=False, warn=lambda line: None)
            rn = stack.read_manifest(counts)["detector"]["resolved"]["render_noise"]
            rows.append({"spp": spp, "ratio_bins": rn["ratio"], "ratio_pixel_totals": rn["pixel_totals"]["ratio_pooled"],
                         "render_s": t_render})
            if spp in (SPPS[0], SPPS[-1]):
                m = stack.read_manifest(ideal)
                x = stack.read_spot(ideal, 0, m)[1, 1].astype(np.float64)
                var = stack.read_variance(ideal, 0, m)[0][1, 1].astype(np.float64)
                budget = resolve_budget(params, m.get("laser"), exposure_s=EXPOSURE_S)
                run_params, _, gates = resolve_gates(m, params)
                model = spot_model_for(m, run_params, gates, 0, budget)
                T = m["time"]["n_bins"]
                mu = apply_jitter_kernel(model.intensity(x[None])[:, :T], model.kernel_first, model.kernel)[0]
                mu *= budget.n_pulses
                w = (model.params.pde * model.gate_slots[:T]) ** 2
                v = apply_jitter_kernel((w * var)[None], model.kernel_first, np.square(model.kernel))[0]
                v *= float(budget.n_pulses) ** 2
                t_ns = (m["time"]["t0_ps"] + (np.arange(T) + 0.5) * m["time"]["bin_width_ps"]) / 1000
                curves[spp] = (t_ns, mu, np.sqrt(v))
    fig, axes = subplots(1, 2, figsize=(12, 4.2))
    ax = axes[0]
    for spp, color in ((SPPS[0], "C3"), (SPPS[-1], "C0")):
        t, mu, sd = curves[spp]
        sel = mu > 0.05 * mu.max()
        lo, hi = np.flatnonzero(sel)[[0, -1]]
        sl = slice(max(lo - 10, 0), hi + 10)
        ax.plot(t[sl], mu[sl], color=color, lw=1, label=f"expected counts, {spp} spp")
        ax.fill_between(t[sl], (mu - sd)[sl], (mu + sd)[sl], color=color, alpha=0.25,
                        label=f"rendering noise +-1 sd ({spp} spp)")
    t, mu, _ = curves[SPPS[-1]]
    ax.plot(t[sl], (mu + np.sqrt(mu))[sl], color="k", lw=0.7, ls="--", label="photon noise +-1 sd (Poisson)")
    ax.plot(t[sl], (mu - np.sqrt(mu))[sl], color="k", lw=0.7, ls="--")
    ax.set_xlabel("time of flight (ns)")
    ax.set_ylabel("counts per 8 ps bin, one pixel, 10 ms")
    ax.set_title("one pixel of the paper scene (4x4 array, spot 0)", fontsize=10)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    ax = axes[1]
    s = np.array([r["spp"] for r in rows], dtype=float)
    rb = np.array([r["ratio_bins"] for r in rows])
    rt = np.array([r["ratio_pixel_totals"] for r in rows])
    ax.loglog(s, rb, "o-", color="C0", label="bins (largest class ratio)")
    ax.loglog(s, rt, "s-", color="C1", label="per-pixel totals")
    ax.loglog(s, rb[0] * s[0] / s, color="0.4", ls=":", label="1/spp from the first point")
    ax.axhline(0.1, color="k", lw=1, ls="--", label="target 0.1")
    ax.set_xlabel("samples per pixel per spot")
    ax.set_ylabel("rendering variance / photon variance")
    ax.set_title("noise ratio at the demo's budget (10 ms per spot)", fontsize=10)
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    save_figure(fig, ROOT / "docs" / "img" / "render_noise.png")
    out = ROOT / "bench" / "results" / "render_noise_vs_spp.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    sys.path.insert(0, str(ROOT / "bench"))
    import _record

    out.write_text(json.dumps(_record.as_record(out.stem, {
        "benchmark": "render_noise_vs_spp", "command": "python bench/noise_figure.py",
        "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "machine": {"cpu": platform.processor() or platform.machine(), "python": platform.python_version()},
        "scene": "paper_mannequin, array 4, spots 2, 8 ps bins, render seed 1", "exposure_s": EXPOSURE_S,
        "rows": rows}), indent=1) + "\n")
    print(json.dumps(rows, indent=1))


if __name__ == "__main__":
    sys.exit(main())
