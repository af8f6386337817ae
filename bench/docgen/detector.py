"""Detector model regions (docs/benchmarks.md, docs/detector.md)."""

from __future__ import annotations

from docgen.common import g2, provenance, s, sci


def detector_readme_inline(R) -> str:
    r = R("detector")["result"]
    g = r["analytic_gated"]
    return f"{s(g['warm_s'])} warm, {s(g['cold_s'])} cold, for {int(r['pixels'] ** 0.5)} x {int(r['pixels'] ** 0.5)} " \
           f"pixels x {r['n_bins']} bins x {sci(g['pulses'])} pulses; {provenance(R('detector'), short=True)}"


def detector_para(R) -> str:
    rec = R("detector")
    r = rec["result"]
    g, u, e = r["analytic_gated"], r["analytic_ungated"], r["exact"]
    side = int(r["pixels"] ** 0.5)
    return (f"\n**Detector** (`python bench/bench_detector.py`): the analytic engine on {side} x {side} pixels x "
            f"{r['n_bins']} bins x {sci(g['pulses'])} pulses takes {s(g['warm_s'])} gated (warm; {s(g['cold_s'])} for "
            f"the first call in a process; goal < {g['goal_s']:g} s), {s(u['warm_s'])} ungated; the exact engine "
            f"simulates {g2(e['pixel_pulses_per_s'])} pixel-pulses/s. {provenance(rec)}\n")


def detector_docs_table(R) -> str:
    rec = R("detector")
    r = rec["result"]
    g, u, e = r["analytic_gated"], r["analytic_ungated"], r["exact"]

    def ts(x):
        return ", ".join(f"{v:.3g}" for v in x["times_s"])

    lines = ["| case | warm (fastest) | cold (first call in the process) | every call (s) |", "|---|---|---|---|",
             f"| analytic, gated (the paper's setup; exact regime) | {s(g['warm_s'])} | {s(g['cold_s'])} | {ts(g)} |",
             f"| analytic, ungated (Markov chain for every pixel) | {s(u['warm_s'])} | {s(u['cold_s'])} | {ts(u)} |",
             f"| exact engine, {e['pulses']:,} pulses | {g2(e['pixel_pulses_per_s'])} pixel-pulses/s "
             f"({g2(e['events_per_s'])} events/s) | first call {s(e['first_call_s'])} (compile) | {e['seconds']:.3g} |",
             "", provenance(rec)]
    return "\n" + "\n".join(lines) + "\n"
