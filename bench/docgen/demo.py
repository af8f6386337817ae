"""The demo and rendering-noise regions (docs/demo.md, docs/noise.md, README quick start)."""

from __future__ import annotations

from docgen.common import _gb, _own_provenance, provenance


def demo_table(R) -> str:
    from bench_demo import markdown_metrics

    rec = R("demo")
    r = rec["result"]
    f = r["fastest"]
    st = f["step_sums_s"]
    return ("\n" + markdown_metrics(r) + "\n\n"
            f"(`transient-mi demo`, seed 0, 64 x 64 x 32 voxels of 1.6 cm; {f['wall_s']:.0f} s on "
            f"{rec['machine']['cores']} cores ({rec['machine']['cpu_model']}): render {st['render']:.0f} s, detect "
            f"{st['detect']:.0f} s, reconstruct {st['reconstruct']:.0f} s, figures, metrics and start-up the rest; "
            f"peak RSS {_gb(f['peak_rss_mb'])}. {provenance(rec)})\n")


def demo_wall_inline(R) -> str:
    rec = R("demo")
    return f"{rec['result']['fastest']['wall_s']:.0f} s ({provenance(rec, short=True)})"


def demo_quick_inline(R) -> str:
    rec = R("demo_quick")
    return f"{rec['result']['fastest']['wall_s']:.0f} s ({provenance(rec, short=True)})"


def noise_demo_para(R) -> str:
    rec = R("noise_target")
    res = rec["result"]
    d = res["demo"]
    head = ("| array | pilot ratio (1024 spp, worst spot) | spp chosen | ratio reached (worst spot) | "
            "ratio in detect (bins; pixel totals) | render (s) | detect (s) |\n|---|---|---|---|---|---|---|\n")
    rows = "\n".join(
        f"| {a['array']}x{a['array']} | {a['pilot_ratio_worst_spot']:.3g} | {a['spp']} | "
        f"{a['ratio_worst_spot_render']:.3g} | {a['ratio_detect_bins']:.3g}; {a['ratio_detect_pixel_totals']:.3g} | "
        f"{a['render_s']:.0f} | {a['detect_s']:.0f} |" for a in d["arrays"])
    t = {x["technique"]: x for x in res["techniques"]}
    q = t["rqmc off (plain Monte Carlo)"]
    h = t["hidden-geometry sampling off (BSDF sampling only)"]
    return (head + rows
            + f"\n\nThe whole demo at the noise target: {d['wall_s']:.0f} s wall, {d['cpu_s']:.0f} s CPU (goal: 10 min "
            f"on 2 cores). Variance reduction at equal spp (1024, 8x8 array), variance without / with the "
            f"technique: randomised QMC {q['variance_reduction_factor_bins']:.2g}x on bins and "
            f"{q['variance_reduction_factor_pixel_totals']:.2g}x on pixel totals (with 8 replicates of 128 samples "
            f"little is left of its advantage), hidden-geometry sampling {h['variance_reduction_factor_bins']:.2g}x "
            f"on bins and {h['variance_reduction_factor_pixel_totals']:.2g}x on pixel totals. "
            + _own_provenance(rec, "noise_target") + "\n")


def noise_cost_inline(R) -> str:
    parts = []
    for name in ("render_variance_cost", "render_variance_cost_16k"):
        res = R(name)["result"]
        w = res["median_wall_s"]
        spp = res["scene"].split("spp=")[1].split()[0]
        parts.append(f"at {spp} spp {w['replicates_8'] / w['replicates_1']:.2f}x the render time of a single "
                     f"replicate ({w['replicates_8']:.2f} s vs {w['replicates_1']:.2f} s wall, CPU "
                     f"{1 + res['time_overhead_cpu']:.2f}x) and {res['disk_ratio']:.2f}x its disk")
    rec = R("render_variance_cost_16k")
    scene = rec["result"]["scene"].split(" spp=")[0]
    return ("; ".join(parts) + f" ({scene}, 11500 x 1 ps bins, 2 x 2 spots; the cost is a fixed ~1-2 s per group "
            "of spots for collecting the film once per replicate, so it shrinks relatively as spp grows; "
            "`variance_replicates=1` turns it off; "
            + _own_provenance(rec, "render_variance_cost_16k").replace("Source: ", "").rstrip(".") + " and "
            "`bench/results/render_variance_cost.json`)")


def noise_vs_spp_inline(R) -> str:
    rec = R("render_noise_vs_spp")
    r = {x["spp"]: x for x in rec["result"]["rows"]}
    lo, mid, hi = min(r), 1024, max(r)
    return (f"{r[lo]['ratio_bins']:.3g} at {lo} spp, {r[mid]['ratio_bins']:.3g} at {mid}, {r[hi]['ratio_bins']:.3g} at "
            f"{hi} (" + _own_provenance(rec, "render_noise_vs_spp").replace("Source: ", "").rstrip(".") + ")")


#: The demo's records by exposure per spot and noise target (bench_demo.py --exposure-ms, --noise-target; the plain
#: record is the default 10 ms and auto target).
DEMO_EXPOSURES = (("demo_e1ms", 1.0), ("demo", 10.0), ("demo_nt0.1", 10.0), ("demo_e1000ms", 1000.0),
                  ("demo_e1000ms_nt0.1", 1000.0))


def demo_exposures_table(R) -> str:
    """The demo at each measured exposure per spot: wall time against issue 27's 3 minutes, the render's share,
    the quadrature's settings and the worst rendering / photon noise ratio of its table."""
    from .common import Missing

    head = ("| exposure per spot | noise target | demo wall (s) | render (s) | elements, cells per patch[, visibility "
            "levels] | worst rendering / photon noise (bins) | within 3 min | 1-min load (start -> end) | record |\n"
            "|---|---|---|---|---|---|---|---|---|\n")
    rows = []
    for name, ms in DEMO_EXPOSURES:
        try:
            rec = R(name)
        except Missing:
            rows.append(f"| {ms:g} ms | | not measured | | | | | | `bench/results/{name}.json` missing |")
            continue
        run = min((r for r in rec["result"]["runs"] if r["status"] == "ok"), key=lambda r: r["wall_s"])  # (fastest)
        sizes = sorted({(round(1000 * r["quadrature_element_size_m"], 1), r["quadrature_patch_cells"],
                         r.get("quadrature_refine_levels"))
                        for r in run["rows"] if r.get("estimator") == "quadrature"}, key=lambda t: t[:2])
        settings = "; ".join(f"{s:g} mm, {c}" + ("" if lv is None else f", {lv}") for s, c, lv in sizes) \
            if sizes else "Monte Carlo"
        worst = max(r["render_noise_ratio"] for r in run["rows"])
        m = rec["machine"]
        nt = rec["result"]["noise_target"]
        nt = "auto (0.01 by the quadrature)" if nt == "auto" else f"`--noise-target {nt}`"
        rows.append(f"| {ms:g} ms | {nt} | {run['wall_s']:.0f} | {run['step_sums_s']['render']:.0f} | {settings} | "
                    f"{worst:.2g} | {'yes' if run['wall_s'] <= 180 else 'no'} | "
                    f"{m['load_average_1min_start']:.1f} -> {m['load_average_1min_end']:.1f} | "
                    f"`bench/results/{name}.json`, {rec['date_utc'][:10]} |")
    return ("\n" + head + "\n".join(rows)
            + "\n\n(`python bench/bench_demo.py [--exposure-ms MS] [--noise-target R] --save`, 2 cores.)\n")
