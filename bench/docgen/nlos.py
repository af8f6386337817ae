"""NLOS capture regions: against mitransient, the pipeline, the estimator's agreement
(docs/benchmarks.md, docs/nlos.md).
"""

from __future__ import annotations

from docgen.common import _gb, not_measured, provenance, s


def _nlos_sp(c, e):
    star = "" if c.get("speedup_basis", {}).get(e, "measured") == "measured" else "*"
    return f"{c['speedup_time_to_equal_error'][e]:.1f}x{star}"


def nlos_readme_table(R) -> str:

    rec = R("nlos")
    r = rec["result"]
    ver = rec["versions"].get("mitransient")
    lines = ["| configuration | speed-up at equal RMSE 0.2 / 0.1 / 0.05 | time to RMSE 0.1: ours / mitransient | "
             "peak RSS per run: ours / mitransient |", "|---|---|---|---|"]
    for c in r["configs"]:
        o, m = c["ours"], c.get("mitransient")
        if m is None:
            lines.append(f"| {c['name']} | mitransient not run | {_t(o, '0.1')} / - | - |")
            continue
        if c["capture"] == "array" and c.get("ours_pipeline"):
            rss_o = f"{max(v['peak_rss_mb'] for v in c['ours_pipeline'].values()):.0f} MB (streamed render)"
        else:
            rss_o = _rss_range(o["peak_rss_per_run_mb"])
        rss_m = _rss_range(m.get("render_rss_per_run_mb") or m["peak_rss_per_run_mb"])
        sp = " / ".join(_nlos_sp(c, e) for e in ("0.2", "0.1", "0.05"))
        lines.append(f"| {c['name']} | {sp} | {_t(o, '0.1')} / {_t(m, '0.1')} | {rss_o} / {rss_m} |")
    lines += ["", f"(`*`: at least one side did not reach that error in the measured runs; the time comes from "
                  f"the fitted power law beyond the measured range and is labelled extrapolated. mitransient "
                  f"{ver}; its peak RSS is its renderer alone, per run, in its own process.) {provenance(rec)}"]
    return "\n" + "\n".join(lines) + "\n"


def nlos_docs_table(R) -> str:

    rec = R("nlos")
    return "\n" + markdown_table(rec["result"]) + "\n\n" + provenance(rec) + "\n"


def nlos_pipeline_para(R) -> str:
    rec = R("nlos")
    arr = [c for c in rec["result"]["configs"] if c.get("ours_pipeline")]
    if not arr:
        return not_measured(["nlos"], False)
    c = arr[0]
    parts = [f"{v['peak_rss_mb']:.0f} MB with {k.replace('_spots', '').replace('x', ' x ')} spots ({v['files']} files, "
             f"{s(v['time_s'])})" for k, v in c["ours_pipeline"].items()]
    m = c.get("mitransient")
    mt = ""
    if m:
        mt = (f" mitransient holds the whole exhaustive capture in memory: its render peaks at "
              f"{_gb(max(m.get('render_rss_per_run_mb') or m['peak_rss_per_run_mb']))} per run.")
    return ("\nIts streaming render of the same capture (`transient-mi render`, one EXR file per spot, spp 4) peaks "
            "at " + ", ".join(parts) + f": memory does not grow with the number of spots.{mt} "
            f"{provenance(rec, short=True)}.\n")


def nlos_agreement(R) -> str:
    rec = R("nlos")
    cs = [c for c in rec["result"]["configs"] if c.get("mean_agreement")]
    if not cs:
        return "(mitransient was not run: no agreement to report)"
    ag = [c["mean_agreement"] for c in cs]
    ratio = " / ".join(f"{a['scale_ours_over_mitransient']:.5f}" for a in ag)
    expected = " / ".join(f"{a['expected_scale']:.5f}" for a in ag)
    resid = " / ".join(f"{100 * a['rel_rms_residual_of_totals']:.2f} %" for a in ag)
    dt = " / ".join(f"{a['mean_arrival_bin_difference']['mean']:.2f}" for a in ag)
    names = ", ".join(c["name"] for c in cs)
    return (f"for {names}, the fitted ratio of the per-(spot, pixel) totals is {ratio} against the expected "
            f"{expected}, the residual scatter {resid} (the references' own noise), and the mean arrival times "
            f"differ by {dt} bins on average ({provenance(rec, short=True)}).")


def nlos_betas(R) -> str:
    rec = R("nlos")
    parts = []
    for c in rec["result"]["configs"]:
        m = c.get("mitransient")
        mb = f"{m['error_model']['beta']:.2f}" if m else "-"
        parts.append(f"{c['name']} {c['ours']['error_model']['beta']:.2f} / {mb}")
    return "; ".join(parts)


def _t(x: dict, eps: str) -> str:
    """Time to a relative RMSE, labelled when the fit extrapolates beyond the measured runs."""
    lab = "" if x.get("time_to_rel_rmse_basis", {}).get(eps, "measured") == "measured" else " (extrapolated)"
    return f"{x['time_to_rel_rmse_s'][eps]:.3g} s{lab}"


def _rss_range(values) -> str:
    lo, hi = min(values), max(values)
    return f"{lo:.0f} MB" if round(lo) == round(hi) else f"{lo:.0f}-{hi:.0f} MB"


def markdown_table(report: dict) -> str:
    """The benchmark table (markdown) of a report produced by ``bench_nlos.main``.

    Times to an error level that no run reached are marked "(extrapolated)"
    (the fitted power law beyond the measured range); speed-ups likewise
    ("*" = extrapolated on at least one side). Peak memory is each run's own
    peak (VmHWM, reset before every run; the range over the runs); for
    mitransient the peak up to the end of its render (before the benchmark's
    numpy copy).
    """
    rows = ["| Configuration | transient-mi: rel. RMSE @ spp (time) | mitransient: rel. RMSE @ spp (time) | "
            "fitted exponent beta (ours / mitransient) | time to rel. RMSE 0.1 (ours / mitransient) | "
            "speed-up at equal RMSE 0.2 / 0.1 / 0.05 | peak RSS per run (ours / mitransient) |",
            "| --- | --- | --- | --- | --- | --- | --- |"]
    for c in report["configs"]:
        o, m = c["ours"], c.get("mitransient")

        def runs(x):
            return "; ".join(f"{q['rel_rmse']:.3f} @ {q['spp']} ({q.get('time_full_capture_s', q['time_s']):.3g} s)"
                             for q in x["runs"])

        if c["capture"] == "array" and c.get("ours_pipeline"):
            rss_o = f"{max(v['peak_rss_mb'] for v in c['ours_pipeline'].values()):.0f} MB (streamed render)"
        else:
            rss_o = _rss_range(o.get("peak_rss_per_run_mb") or [o["peak_rss_mb"]])
        if m is None:
            rows.append(f"| {c['name']} | {runs(o)} | - | {o['error_model']['beta']:.2f} / - | "
                        f"{_t(o, '0.1')} / - | - | {rss_o} / - |")
            continue
        sp = c["speedup_time_to_equal_error"]
        basis = c.get("speedup_basis", {})
        spd = " / ".join(f"{sp[e]:.1f}x" + ("*" if basis.get(e, "measured") != "measured" else "")
                         for e in ("0.2", "0.1", "0.05"))
        rss_m = _rss_range(m.get("render_rss_per_run_mb") or m.get("peak_rss_per_run_mb") or [m["peak_rss_mb"]])
        rows.append(f"| {c['name']} | {runs(o)} | {runs(m)} | {o['error_model']['beta']:.2f} / "
                    f"{m['error_model']['beta']:.2f} | {_t(o, '0.1')} / {_t(m, '0.1')} | {spd} | "
                    f"{rss_o} / {rss_m} |")
    return "\n".join(rows)
