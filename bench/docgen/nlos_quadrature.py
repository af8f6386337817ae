"""The deterministic three-bounce estimator against mitransient at equal error (docs/benchmarks.md,
docs/quadrature.md), from ``bench/results/nlos_quadrature.json`` (``bench/bench_nlos_quadrature.py``)."""

from __future__ import annotations

from .common import provenance


def _mm(h: float) -> str:
    return f"{h * 1000:.0f} mm"


def _t(x: float) -> str:
    return f"{x:.3g} s"


def _sweep(q: dict) -> str:
    return "; ".join(f"{_mm(s['element_size_m'])}: {s['rel_rmse']:.3f}" for s in q["sweep"])


def _mt(m: dict, target: float) -> str:
    lab = "" if m["time_to_target_basis"] == "measured" else ", extrapolated"
    return f"{m['spp']} spp: {m['rel_rmse']:.3f}, {_t(m['time_s'])}; to {target:g}: {_t(m['time_to_target_s'])}{lab}"


def _row(c: dict) -> str:
    q, m = c.get("quadrature"), c.get("mitransient")
    if q is None:
        ms = _mt(m, c["target_rel_rmse"]) if m else "not run"
        return f"| {c['name']} | not measured: {c.get('quadrature_not_run', '')} | - | {ms} | - | - |"
    sel = q.get("selected") if q else None
    target = c["target_rel_rmse"]
    if sel:
        spots = f", all {sel['timed_spots']} spots" if sel["timed_spots"] > 1 else ""
        qs = (f"{_mm(sel['element_size_m'])} ({sel['elements']} elements): {sel['rel_rmse']:.3f} (its stated "
              f"estimate: {sel['stated_rel_rmse']:.3f}), {_t(sel['time_s'])}{spots}")
    else:
        qs = f"no setting of the sweep reached {target:g}"
    d = [s for s in q["sweep"] if abs(s["element_size_m"] - q["defaults"]["element_size_m"]) < 1e-12]
    ref = q["reference"]
    part = "" if c["capture"] == "confocal" else f" ({len(c['error_spots'])} spots)"
    if d:
        ds = f"{d[0]['rel_rmse']:.4f}, {_t(d[0]['first_call_s'])}{part}, first call"
    elif abs(ref["element_size_m"] - q["defaults"]["element_size_m"]) < 1e-12 and \
            ref.get("self_convergence_rel_rmse") is not None:
        ds = (f"the reference: about {ref['self_convergence_rel_rmse']:.1e} (self-convergence), "
              f"{_t(ref['first_call_s'])}{part}, first call")
    else:
        ds = "not in the sweep"
    if m:
        ms = _mt(m, target)
        rss_m = f"{m['render_rss_mb']:.0f} MB"
    else:
        ms, rss_m = "not run", "-"
    sp = c.get("speedup_at_target")
    star = "" if c.get("speedup_basis") == "measured" else "*"
    sps = "-" if sp is None else (f"{sp:.2g}x" if sp < 10 else f"{sp:.0f}x") + star
    rss_q = f"{sel['timed_peak_rss_mb']:.0f} MB" if sel else "-"
    return f"| {c['name']} | {qs} | {ds} | {ms} | {sps} | {rss_q} / {rss_m} |"


#: Records of configurations measured in a later run (``--only NAME --record-suffix NAME``): their rows replace
#: the main record's rows of the same configuration.
LATER = ("nlos_quadrature_64x64", "nlos_quadrature_confocal", "nlos_quadrature_array")


def _later(R) -> list[dict]:
    from .common import Missing

    out = []
    for name in LATER:
        try:
            out.append(R(name))
        except Missing:
            pass
    return out


def nlos_quadrature_table(R) -> str:
    """Per configuration: the coarsest quadrature at the target, the defaults, mitransient at the target."""
    rec = R("nlos_quadrature")
    later = _later(R)
    by_name = {c["name"]: c for c in rec["result"]["configs"]}
    for r in later:
        for c in r["result"]["configs"]:
            if c.get("quadrature") is not None:
                by_name[c["name"]] = c
    cs = list(by_name.values())
    target = cs[0]["target_rel_rmse"] if cs else 0.05
    rows = [f"| configuration | quadrature, coarsest element size at rel. RMSE <= {target:g}: RMSE, time | "
            "quadrature at its defaults (10 mm): RMSE, time | mitransient: RMSE at its spp (measured), time; time to the "
            "target | "
            f"speed-up at RMSE {target:g} | peak RSS: quadrature / mitransient |",
            "|---|---|---|---|---|---|"]
    rows += [_row(c) for c in cs]
    n_err = [len(c["error_spots"]) for c in cs if c.get("error_spots")]
    arr = f" (array: over {n_err[0]} spots spread over the scan, the same for both)" if n_err else ""
    notes = []
    for c in cs:
        q, x = c.get("quadrature"), c.get("reference_check_monte_carlo")
        if not q:
            continue
        r = q["reference"]
        sc = r.get("self_convergence_rel_rmse")
        scs = f", self-convergence estimate {sc:.1e}" if sc is not None else ""
        ag = c.get("mean_agreement")
        ags = (f"; mean agreement with mitransient: ratio {ag['scale_ours_over_mitransient']:.5f} against the "
               f"expected {ag['expected_scale']:.5f}") if ag else ""
        notes.append(f"{c['name']}: reference {_mm(r['element_size_m'])} elements{scs}; against transient-mi's "
                     f"Monte Carlo at {x['spp']} spp its relative RMSE is below {x['reference_rel_rmse_bound_3sd']:.1e} "
                     f"(3 sd){ags}; RMSE by element size: {_sweep(q)}")
    return ("\n".join(rows) + "\n\n"
            f"Relative RMSE over all (spot, pixel, bin) values{arr}, `pixel_sampling={cs[0]['pixel_sampling']}`"
            f"{' (mitransient' + chr(39) + 's estimand)' if cs[0]['pixel_sampling'] == 'center' else ''}. The quadrature's error is measured "
            "against a much finer quadrature level; mitransient's from two independent renders at its spp "
            "(MSE = mean((a - b)^2) / 2, no reference needed); its time to the target is the measured run's "
            "scaled by the 1/spp law (mitransient's fitted exponent in bench_nlos is 1.00): a reduction where the "
            "run reached the target, an extrapolation (`*`, labelled) where it did not. Times: the second call in "
            "the process (the first compiles); the quadrature's is the whole capture. " + ". ".join(notes) + ".\n\n"
            + provenance(rec) + "".join(f" Rows of {', '.join(c['name'] for c in r['result']['configs'])}: "
                                        f"{provenance(r)}" for r in later))


def array_speedup_inline(R) -> str:
    """The array capture against mitransient at equal error, in a sentence (bench_nlos_quadrature's array record)."""
    rec = R("nlos_quadrature_array")
    c = rec["result"]["configs"][0]
    q, m = c["quadrature"]["selected"], c["mitransient"]
    return (f"{c['speedup_at_target']:.0f}x on the array, measured side by side (mitransient's two "
            f"{m['spp']}-spp renders, {m['time_s']:.0f} s each, reached {m['rel_rmse']:.3f}, {m['time_to_target_s']:.0f} s "
            f"to 0.05; the quadrature {q['time_s']:.1f} s at {q['element_size_m'] * 1000:.0f} mm; "
            f"{provenance(rec, short=True)}, {rec['machine']['cpu_model']})")


def confocal_speedup_inline(R) -> str:
    """The two confocal captures against mitransient at equal error, in a sentence (bench_nlos_quadrature's
    confocal record: both renderers side by side)."""
    rec = R("nlos_quadrature_confocal")
    by = {c["name"]: c for c in rec["result"]["configs"]}
    parts = []
    for name, what in (("confocal_32x32_400bins", "the confocal 32 x 32 capture"),
                       ("confocal_64x64_2048bins", "the 64 x 64 one")):
        c = by[name]
        q, m = c["quadrature"]["selected"], c["mitransient"]
        parts.append(f"{c['speedup_at_target']:.0f}x on {what} (the quadrature {q['time_s']:.2f} s, mitransient "
                     f"{m['time_to_target_s']:.1f} s to 0.05)")
    return f"{parts[0]} and {parts[1]} ({provenance(rec, short=True)}, {rec['machine']['cpu_model']})"


def work_arrays_inline(R) -> str:
    """The array capture with the quadrature's work arrays kept between groups and allocated afresh."""
    rec = R("work_arrays")
    r = rec["result"]
    n = len(r["times_s"]["kept"])
    return (f"the array capture ({r['groups']} groups of {r['spots_per_group']} spots) in {r['median_s']['kept']:.1f} s "
            f"with the arrays kept against {r['median_s']['fresh']:.1f} s allocated afresh, "
            f"{r['fresh_over_kept']:.2f}x (medians of {n} alternating runs each in one process; "
            f"{provenance(rec, short=True)})")
