"""The deterministic three-bounce estimator against Monte Carlo (docs/quadrature.md, README)."""

from __future__ import annotations

from .common import Missing, provenance


def _r(x) -> str:
    return "-" if x is None else f"{x:.3g}"


def quadrature_table(R) -> str:
    """Stated (and, for the accuracy capture, actual) rendering-error ratios and render times, side by side."""
    rec = R("quadrature")
    res = rec["result"]
    exp = [f"{e:g} ms" for e in res["exposures_ms"]]
    keys = [f"{e:g}ms" for e in res["exposures_ms"]]
    a, b = res["accuracy"], res["readme_capture"]
    head = "| capture | estimator | render time | " + " | ".join(f"ratio at {e}" for e in exp) + " |"
    sep = "|---|---|---:|" + "---:|" * len(exp)
    rows = [head, sep]

    def row(cap, est, d, kind="stated"):
        vals = " | ".join(_r(d[kind][k]["ratio"]) for k in keys)
        rows.append(f"| {cap} | {est} | {d['time_s']:.1f} s | {vals} |")

    row(a["config"], "quadrature (stated error estimate)", a["quadrature"])
    row(a["config"], "quadrature (actual error against the reference)", a["quadrature"], "actual")
    row(a["config"], f"Monte Carlo, {res['spp_mc']} spp (stated variance)", a["monte_carlo"])
    row(b["config"], "quadrature (stated error estimate)", b["quadrature"])
    row(b["config"], f"Monte Carlo, {res['spp_mc']} spp (stated variance)", b["monte_carlo"])
    mc = b["monte_carlo"]
    ref = a["reference"]
    return ("\n".join(rows) + "\n\n"
            f"Ratio: rendering variance (the square of the quadrature's error estimate) over photon variance, as "
            f"`transient-mi detect` states it ({res['detector']}); the project's noise standard is 0.1, the issue's "
            f"target for deterministic captures 0.01. The reference is the quadrature with "
            f"{ref['element_size_m'] * 1000:g} mm elements and {ref['patch_cells']} x {ref['patch_cells']} cells "
            f"({ref['time_s']:.0f} s). Monte Carlo would need about {mc['spp_for_0.01_at_10ms_extrapolated']:,} spp "
            f"(about {mc['time_for_0.01_at_10ms_extrapolated_s'] / 3600:.1f} h) for 0.01 at 10 ms on the README "
            f"capture (extrapolated from its variance, ~1/spp: not measured).\n\n" + provenance(rec))


def quadrature_inline(R) -> str:
    """One sentence for the README: the accuracy capture's actual ratio and render time against Monte Carlo's."""
    rec = R("quadrature")
    res = rec["result"]
    a = res["accuracy"]
    b = res["readme_capture"]
    return (f"on the letter at 10 ms per spot its actual rendering error is "
            f"{a['quadrature']['actual']['10ms']['ratio']:.2g}x the photon noise (variance ratio; 4096-spp Monte "
            f"Carlo: {a['monte_carlo']['stated']['10ms']['ratio']:.3g}x), and the README's 16 x 16, 4 x 4-spot "
            f"capture renders in {b['quadrature']['time_s']:.0f} s where Monte Carlo would need about "
            f"{b['monte_carlo']['time_for_0.01_at_10ms_extrapolated_s'] / 3600:.1f} h (extrapolated) "
            f"({provenance(rec, short=True)})")


#: bench/bench_quadrature.py's record and the same with the code and scene defaults before the cell's curvature (run
#: one after the other).
LETTER_CURVATURE = ("quadrature", "quadrature_before_curvature")


def letter_curvature_inline(R) -> str:
    """The README letter capture's render time and stated ratio at 10 ms, this code against the code before."""
    now, before = R(LETTER_CURVATURE[0]), R(LETTER_CURVATURE[1])
    n, b = now["result"]["readme_capture"], before["result"]["readme_capture"]
    return (f"the README's 16 x 16, 4 x 4-spot capture rendered in {n['quadrature']['time_s']:.1f} s, stating "
            f"{n['quadrature']['stated']['10ms']['ratio']:.2g} at 10 ms, against {b['quadrature']['time_s']:.1f} s "
            f"and {b['quadrature']['stated']['10ms']['ratio']:.2g} with 10 mm, 6 cells and the code before, one run "
            f"after the other (4096-spp Monte Carlo: {n['monte_carlo']['time_s']:.2f} s and "
            f"{b['monte_carlo']['time_s']:.2f} s; {_sources(now, before)})")

def quadrature_cost_inline(R) -> str:
    """How the render time grows when one factor is multiplied by 4 (linear would be 4)."""
    rec = R("quadrature_cost")
    rows = rec["result"]["rows"]
    b = rows["base"]
    parts = [f"{name.split(' ')[0]} {rows[name]['ratio_to_base']:.1f}x" for name in rows if name != "base"]
    parts[0] += f" (half the element size: {rows['elements x4']['elements'] / b['elements']:.1f}x the elements)"
    return (f"multiplying one factor by 4 multiplies the render time by: " + ", ".join(parts)
            + f" (base {rows['base']['time_s']:.2f} s: the letter at 4 x 4 pixels, 2 spots, 512 bins, 2 cm elements; "
            + f"{provenance(rec, short=True)})")


#: bench/bench_paper_estimators.py's records quoted in quadrature.md ("When Monte Carlo is still used"): 16 x 16 pixels
#: at the demo's 1 ps bins and 10 ms to a target of 0.01 (both estimators), then 4 x 4 pixels at 1 s per spot (Monte
#: Carlo alone: its samples reach the cap), then the paper's 32 x 32 array by the quadrature alone, at the paper
#: scene's cells (one per patch), the same with the code before the latest change to the quadrature's speed (run right
#: before it, the same load; its note names the commit), and at two per side (an earlier record).
PAPER_ESTIMATORS = ("paper_estimators_a16_e10ms", "paper_estimators_a4_e1000ms", "paper_estimators_a32_e10ms",
                    "paper_estimators_a32_e10ms_before_pages", "paper_estimators_a32_e10ms_cells2",
                    "paper_estimators_a32_e10ms_owned", "paper_estimators_a32_e10ms_before_owned",
                    "paper_estimators_a32_e10ms_masses", "paper_estimators_a32_e10ms_before_masses")


def paper_estimators_table(R) -> str:
    """The paper scene at a noise target by each estimator, side by side (one run each, the same load)."""
    lines = ["  | pixels, bins, target | exposure per spot | estimator | render (s) | CPU (s) | ended with | ratio "
             "stated by detect (bins; pixel totals) | target met |", "  |---|---|---|---:|---:|---|---:|---|"]
    recs = [R(PAPER_ESTIMATORS[0])]
    for name in PAPER_ESTIMATORS[1:]:
        try:
            recs.append(R(name))
        except Missing:
            pass
    for rec in recs:
        r = rec["result"]
        for x in r["runs"]:
            sp = x["spots"]
            if x["estimator"] == "quadrature":
                h = max(s_["element_size_m"] for s_ in sp)
                c = min(s_['patch_cells'] for s_ in sp)
                how = (f"{1000 * h:.3g} mm elements, {c} cell{'' if c == 1 else 's'}, "
                       f"{max(s_['rounds'] for s_ in sp)} round(s)")
            else:
                lo, hi = min(s_["spp"] for s_ in sp), max(s_["spp"] for s_ in sp)
                how = f"{lo} spp" if lo == hi else f"{lo}-{hi} spp"
            tot = x.get("render_noise_ratio_pixel_totals")
            lines.append(f"  | {r['array']} x {r['array']}, {r['bin_width_ps']:g} ps, {r['target']:g} | "
                         f"{r['exposure_ms']:g} ms | {x['estimator']} | {x['render_wall_s']:.0f} | "
                         f"{'n/a' if x.get('render_cpu_s') is None else format(x['render_cpu_s'], '.0f')} | {how} | "
                         f"{x['render_noise_ratio_detect']:.3g}; {'n/a' if tot is None else format(tot, '.3g')} | "
                         f"{'yes' if x['met'] else 'no'} |")
    lines += ["", f"  ({recs[0]['result']['spots']} spots, the paper's detector; Monte Carlo from the demo's 1024-spp "
              "pilot, capped at 2^20 spp; the quadrature from the paper scene's settings when its record was made, its "
              "cells per patch side in the row; render times include the first render's JIT compilation and writing "
              "the capture; CPU: every thread of the process, where recorded, which moves less than the wall time "
              "when other work shares the machine.) " + " ".join(provenance(rec) for rec in recs)]
    return "\n" + "\n".join(lines) + "\n"


#: bench/bench_quadrature_settings.py's record quoted in quadrature.md (the paper scene's quadrature settings).
QUADRATURE_SETTINGS = "quadrature_settings_a8_b8"


def quadrature_settings_table(R) -> str:
    """What refinement levels, cells and element sizes cost and buy on the paper scene."""
    rec = R(QUADRATURE_SETTINGS)
    r = rec["result"]
    key = f"ratio_at_{r['exposure_ms']:g}ms"
    lines = [f"  | refine_levels | element_size_m | patch_cells | elements | render (s) | error ratio at "
             f"{r['exposure_ms']:g} ms |", "  |---:|---:|---:|---:|---:|---:|"]
    for x in r["rows"]:
        lines.append(f"  | {x['refine_levels']} | {x['element_size_m']:g} | {x['patch_cells']} | {x['elements']} | "
                     f"{x['render_s']:.1f} | {x[key]:.3g} |")
    lines += ["", f"  ({r['array']} x {r['array']} pixels, {r['spots']} spots, {r['bin_width_ps']:g} ps bins, the "
              "paper's detector; the first row is the default; JIT compiled before.) " + provenance(rec)]
    return "\n" + "\n".join(lines) + "\n"


#: bench/bench_quadrature_settings.py's records for the letter and the tilted plane (their scene files' settings).
SCENE_SETTINGS = ("quadrature_settings_letter_a8", "quadrature_settings_tilted_plane_a8")


def _scene_default(scene: str, name: str) -> float:
    """A ``<default name=... value=...>`` of an embedded scene file (the settings' one source)."""
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / scene).read_text()
    return float(re.search(rf'<default name="{name}" value="([^"]+)"/>', text).group(1))


def scene_settings_table(R) -> str:
    """The letter's and the tilted plane's settings side by side: what cells and element sizes cost and buy (each
    scene file's own default in bold)."""
    lines = ["| scene | element_size_m | patch_cells | elements | render (s) | error ratio at 10 ms |",
             "|---|---:|---:|---:|---:|---:|"]
    recs = []
    for name in SCENE_SETTINGS:
        try:
            recs.append(R(name))
        except Missing:
            continue
    if not recs:
        raise Missing(SCENE_SETTINGS[0])
    for rec in recs:
        r = rec["result"]
        key = f"ratio_at_{r['exposure_ms']:g}ms"
        default = (_scene_default(r["scene"], "element_size_m"), int(_scene_default(r["scene"], "patch_cells")))
        for x in r["rows"]:
            cells = [f"`{r['scene'].split('/')[-1]}`", f"{x['element_size_m']:g}", f"{x['patch_cells']}",
                     f"{x['elements']}", f"{x['render_s']:.1f}", f"{x[key]:.3g}"]
            if (x["element_size_m"], x["patch_cells"]) == default:
                cells = cells[:1] + [f"**{c}**" for c in cells[1:]]
            lines.append("| " + " | ".join(cells) + " |")
    r = recs[0]["result"]
    lines += ["", f"({r['array']} x {r['array']} pixels, {r['spots']} spots, {r['bin_width_ps']:g} ps bins, wall "
              f"return on, {r['detector']}; refine_levels 1; in bold each scene file's default; JIT compiled "
              "before.) " + " ".join(provenance(rec) for rec in recs)]
    return "\n".join(lines) + "\n"


#: bench/bench_quadrature_profile.py's records: where a render's time goes (the README letter, the paper's 32 x 32).
QUADRATURE_PROFILES = ("quadrature_profile_letter", "quadrature_profile_paper")


def quadrature_profile_inline(R) -> str:
    """Each profiled render's CPU time and the shares of its largest stages (CPU: every thread)."""
    parts = []
    for name in QUADRATURE_PROFILES:
        rec = R(name)
        r = rec["result"]
        tot = r["render_call"]["cpu_s"]
        st = r["stages"]

        def share(k):
            return 100.0 * st[k]["cpu_s"] / tot if k in st and tot > 0 else 0.0

        levels = ", ".join(f"{k.split(': ')[1]} level {share(k):.0f} %" for k in st if k.startswith("level: "))
        parts.append(f"{r['config'].split(' (')[0] if name.endswith('letter') else r['config'].split(',')[0]} of "
                     f"`{r['scene'].split('/')[-1]}`: {tot:.0f} s CPU ({r['render_call']['wall_s']:.0f} s wall) of "
                     f"which the bin masses and deposits {share('bin masses and deposits'):.0f} %, the pair geometry "
                     f"{share('pair geometry'):.0f} %, visibility rays {share('visibility rays'):.0f} %, the elements "
                     f"and their refinement {share('elements and visibility refinement'):.0f} %, the error estimate "
                     f"{share('error estimate'):.0f} % (by level: {levels}) ({provenance(rec, short=True)})")
    return "; ".join(parts)


QUADRATURE_PARTS = "quadrature_parts_a8_e1000ms"


def quadrature_parts_table(R) -> str:
    """The parts of the quadrature's error on the demo's 8 x 8 capture at 1 s per spot, at several settings: what
    the noise target's refinement reads to choose what to refine."""
    rec = R(QUADRATURE_PARTS)
    res = rec["result"]
    rows = ["| elements | cells per patch side | visibility levels | ratio | visibility part | elements part | "
            "cells part | pairs | render (s) |", "|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in res["rows"]:
        p = r["parts"] or {}
        rows.append(f"| {1000 * r['element_size_m']:g} mm | {r['patch_cells']} | {r['refine_levels']} | "
                    f"{_r(r['ratio'])} | {_r(p.get('visibility'))} | {_r(p.get('elements'))} | "
                    f"{_r(p.get('cells')) if 'cells' in p else 'in the elements part'} | {r['pairs']:,} | "
                    f"{r['render_s']:.1f} |")
    return ("\n".join(rows) + "\n\n"
            f"({res['config']}, {res['exposure_ms']:g} ms per spot, the demo's target {res['target']:g}; "
            f"{res['ratio']}. {provenance(rec)})\n")


#: The demo's 4 x 4 array at 1 s per spot: its first round and where the plan ended with two cells and with one.
QUADRATURE_PARTS_A4 = "quadrature_parts_a4_e1000ms"


def cells_plan_para(R) -> str:
    """The demo's 4 x 4 array at 1 s per spot: the first round's parts, and the two cells per side the plan took
    before it counted the cells' part falling with the elements against the one it keeps now (ratios and pairs:
    the record's first row, and its last rows with two cells and with one, the finest of each)."""
    rec = R(QUADRATURE_PARTS_A4)
    rows = rec["result"]["rows"]
    first = rows[0]
    two, one = ([r for r in rows[1:] if r["patch_cells"] == m][-1] for m in (2, 1))
    p = first["parts"]

    def setting(r):
        return (f"{1000 * r['element_size_m']:.1f} mm, {r['patch_cells']} cell{'s' if r['patch_cells'] > 1 else ''} "
                f"per side and {r['refine_levels']} visibility levels")

    return (f"On the demo's 4 x 4 array at 1 s per spot the first round (the scene's "
            f"{1000 * first['element_size_m']:g} mm, one cell, one level) states {_r(first['ratio'])}: visibility "
            f"{_r(p['visibility'])}, elements {_r(p['elements'])}, cells {_r(p['cells'])}. Holding the cells' part "
            f"fixed, the plan took a second cell per side and the array ended at {setting(two)} ({_r(two['ratio'])}, "
            f"{two['pairs']:,} pairs); counting its fall, it ends at {setting(one)} ({_r(one['ratio'])}, "
            f"{one['pairs']:,} pairs, {two['pairs'] / one['pairs']:.1f} times fewer). {provenance(rec)}\n")


def _sources(*recs) -> str:
    """The short provenance of each record compared in one sentence, in order, separated by semicolons."""
    return "; ".join(provenance(r, short=True) for r in recs)


#: The paper scene's render-call profile and the same with the code before the latest change to the quadrature (run
#: right after it on the same machine; its note names the commit).
PROFILE_COMPARE = ("quadrature_profile_paper", "quadrature_profile_paper_before_pages")


def profile_compare_inline(R) -> str:
    """The paper scene's render call alone, this code against the code before (bench_quadrature_profile.py)."""
    now, before = R(PROFILE_COMPARE[0]), R(PROFILE_COMPARE[1])
    return (f"{now['result']['render_call']['wall_s']:.1f} s, {before['result']['render_call']['wall_s']:.1f} s for "
            f"the code before, one run after the other: {_sources(now, before)}")


#: bench_quadrature_profile.py's records of the demo's 32 x 32 capture at 1 s (10.3 mm, one cell, three levels):
#: the children's pairs skipped before their geometry and tested with their ancestors' pairs only, against before.
PROFILE_OWNED = ("quadrature_profile_paper_es0.0103469_pc1_rl3",
                 "quadrature_profile_paper_es0.0103469_pc1_rl3_before_owned")


def profile_owned_inline(R) -> str:
    """The demo's 32 x 32 capture at 1 s, this code against the code before the owned pairs: render call and the
    stages that changed (bench_quadrature_profile.py)."""
    now, before = R(PROFILE_OWNED[0]), R(PROFILE_OWNED[1])
    a, b = now["result"], before["result"]

    def stage(r, k):
        return r["stages"][k]["wall_s"]

    return (f"the demo's 32 x 32 capture at 1 s per spot ({a['config'].split('ps, ')[1]}) rendered in "
            f"{a['render_call']['wall_s']:.0f} s ({a['render_call']['cpu_s']:.0f} s CPU) against "
            f"{b['render_call']['wall_s']:.0f} s ({b['render_call']['cpu_s']:.0f} s CPU) before, one run after the "
            f"other: the pair geometry {stage(a, 'pair geometry'):.0f} s against {stage(b, 'pair geometry'):.0f} s, "
            f"the elements and their refinement {stage(a, 'elements and visibility refinement'):.0f} s against "
            f"{stage(b, 'elements and visibility refinement'):.0f} s ({_sources(now, before)})")


#: The bin masses' two runs (every piece, then the tails' closed form) and their one-pass differences, against the
#: code before (570d32d), one run after the other: the paper's 32 x 32 array at a target (bench_paper_estimators.py),
#: then its render call alone (bench_quadrature_profile.py).
MASSES = ("paper_estimators_a32_e10ms_masses", "paper_estimators_a32_e10ms_before_masses",
          "quadrature_profile_paper_masses", "quadrature_profile_paper_before_masses")


def masses_inline(R) -> str:
    """The paper's 32 x 32 array at 10 ms, the bin masses' two runs against the code before: the whole command's
    render, then the render call and its bin masses (one run after the other each)."""
    now, before, pnow, pbefore = (R(n) for n in MASSES)
    a, b = now["result"]["runs"][0], before["result"]["runs"][0]
    pa, pb = pnow["result"], pbefore["result"]
    m = "bin masses and deposits"
    return (f"{a['render_wall_s']:.1f} s ({a['render_cpu_s']:.0f} s CPU) against {b['render_wall_s']:.1f} s "
            f"({b['render_cpu_s']:.0f} s CPU) for the code before, one run after the other, the same stated ratio "
            f"({a['render_noise_ratio_detect']:.3g}); the render call alone {pa['render_call']['wall_s']:.1f} s against "
            f"{pb['render_call']['wall_s']:.1f} s, its bin masses and deposits {pa['stages'][m]['wall_s']:.1f} s "
            f"against {pb['stages'][m]['wall_s']:.1f} s ({_sources(now, before, pnow, pbefore)})")


#: bench_nlos_quadrature.py's quadrature side of the 64 x 64 confocal letter: the laser side a block of elements at
#: a time, against the whole level's at once (run back to back).
CONFOCAL_BLOCKS = ("nlos_quadrature_confocal64_blocks", "nlos_quadrature_confocal64_before_blocks")


def confocal_blocks_inline(R) -> str:
    """The 64 x 64 confocal letter's reference render (the finest): peak memory and time, blocks against before."""
    now, before = R(CONFOCAL_BLOCKS[0]), R(CONFOCAL_BLOCKS[1])
    a, b = (r["result"]["configs"][0]["quadrature"]["reference"] for r in (now, before))
    return (f"its reference render ({1000 * a['element_size_m']:.0f} mm elements, {a['elements']:,} of them, "
            f"{r_name(now)}) peaked at {a['peak_rss_mb'] / 1024:.1f} GB in {a['first_call_s']:.1f} s, against "
            f"{b['peak_rss_mb'] / 1024:.1f} GB in {b['first_call_s']:.1f} s with the level's laser side at once, one "
            f"run after the other ({_sources(now, before)})")


def r_name(rec) -> str:
    """The configuration a bench_nlos_quadrature record measured."""
    return rec["result"]["configs"][0]["name"].replace("_", " ")


REFINEMENT_RULE = "refinement_rule"


def refinement_rule_inline(R) -> str:
    """How many elements the first visibility refinement test splits under each rule (bench_refinement_rule.py)."""
    rec = R(REFINEMENT_RULE)
    r = rec["result"]
    s = r["split"]
    return (f"on the paper scene at {r['array']} x {r['array']} pixels and {100 * r['element_size_m']:.2f} cm "
            f"elements the first test split {s['any']:,} of {r['fine_elements']:,} elements by the cell or the spot "
            f"alone, {s['combined']:,} with the masks combined and {s['lit']:,} with the side test too "
            f"({provenance(rec, short=True)})")


#: bench/bench_quadrature_cells_error.py's record: the letter's cells' part, actual against stated.
CELLS_ERROR = "quadrature_cells_error_letter_a8"


def cells_error_table(R) -> str:
    """Per cells per patch side on the letter: render time, the actual error's ratio against a much finer
    reference (same elements: the cells' part), and the ratio the capture states."""
    rec = R(CELLS_ERROR)
    r = rec["result"]
    lines = ["| patch_cells | render (s) | actual ratio (against " f"{r['reference_cells']} cells) | stated ratio | "
             "stated over actual |", "|---:|---:|---:|---:|---:|"]
    for x in r["rows"]:
        lines.append(f"| {x['patch_cells']} | {x['render_s']:.2f} | {x['actual_ratio']:.2g} | "
                     f"{x['stated_ratio']:.2g} | {x['stated_over_actual']:.3g} |")
    lines += ["", f"({r['array']} x {r['array']} pixels, spots {', '.join(map(str, r['spots']))} of the 4 x 4, "
              f"{r['bin_width_ps']:g} ps bins, {r['element_size_m'] * 1000:g} mm elements, refine_levels "
              f"{r['refine_levels']}, the paper's detector defaults with --auto-gate at {r['exposure_ms']:g} ms per "
              "spot; the ratio is detect's headline, the largest over the spots; JIT compiled before.) "
              + provenance(rec)]
    return "\n" + "\n".join(lines) + "\n"


#: The same benchmark with the cell's curvature in the spread (``cell_curvature``, 2026-12-08): its rows against
#: :data:`CELLS_ERROR`'s, the code before it.
CELLS_CURVATURE = "quadrature_cells_error_letter_a8_curvature"


def cells_curvature_inline(R) -> str:
    """Per cells per patch side on the letter: the actual and the stated ratio before the cell's curvature and with
    it (bench_quadrature_cells_error.py, the same settings)."""
    before, now = R(CELLS_ERROR), R(CELLS_CURVATURE)
    old = {x["patch_cells"]: x for x in before["result"]["rows"]}
    parts = [f"{x['patch_cells']} cell{'s' if x['patch_cells'] > 1 else ''} {old[x['patch_cells']]['actual_ratio']:.2g} "
             f"-> {x['actual_ratio']:.2g} (stated {old[x['patch_cells']]['stated_ratio']:.2g} -> "
             f"{x['stated_ratio']:.2g})" for x in now["result"]["rows"] if x["patch_cells"] in old]
    return ("the actual error ratio at 10 ms against 12 cells, per cells per patch side: " + ", ".join(parts)
            + f" ({_sources(now, before)})")


#: bench/bench_quadrature_element_slope.py's record: actual and stated error with and without the element's slope.
ELEMENT_SLOPE = "quadrature_element_slope"
_SLOPE_CAPTURES = {"letter": "`nlos_letter.xml`, 8 x 8, 10 ms", "paper": "the demo's paper capture, 8 x 8, 1000 ms"}


def _slope_pairs(r):
    """``(capture, with-slope row, without-slope row)`` per setting, in the record's order."""
    for cap, c in r["captures"].items():
        rows = c["rows"]
        for k in range(0, len(rows) - 1, 2):
            yes, no = rows[k], rows[k + 1]
            if yes["element_slope"] and not no["element_slope"]:
                yield cap, c, yes, no


def element_slope_table(R) -> str:
    """Per capture and setting: the actual and the stated ratio with the element's slope and without, and the
    render times."""
    rec = R(ELEMENT_SLOPE)
    r = rec["result"]
    lines = ["| capture | elements, cells per patch side, visibility levels | actual ratio: slope / none | "
             "stated ratio: slope / none | elements part stated: slope / none | render (s): slope / none |",
             "|---|---|---|---|---|---|"]
    refs = []
    for cap, c, y, n in _slope_pairs(r):
        lines.append(f"| {_SLOPE_CAPTURES[cap]} | {y['element_size_m'] * 1000:g} mm, {y['patch_cells']}, "
                     f"{y['refine_levels']} | {y['actual_ratio']:.2g} / {n['actual_ratio']:.2g} | "
                     f"{y['stated_ratio']:.2g} / {n['stated_ratio']:.2g} | {y['stated_parts']['elements']:.2g} / "
                     f"{n['stated_parts']['elements']:.2g} | {y['render_s']:.2f} / {n['render_s']:.2f} |")
    for cap, c in r["captures"].items():
        f = c["reference"]
        refs.append(f"{_SLOPE_CAPTURES[cap]}: {f['element_size_m'] * 1000:g} mm, {f['patch_cells']} cells, "
                    f"{f['refine_levels']} levels, stating {f['stated_ratio']:.2g}")
    lines += ["", "(ratio: rendering-error variance over photon variance as detect states it, the largest over the "
              "spots; actual: the difference from a much finer reference level, with the slope (" + "; ".join(refs)
              + "); the letter's spots 0, 5, 10, 15 of its 4 x 4, 16 ps bins, the paper's detector defaults with "
              "--auto-gate; the paper capture's 2 x 2 spots, 1 ps bins, the paper's detector; JIT compiled before.) "
              + provenance(rec)]
    return "\n" + "\n".join(lines) + "\n"


def element_slope_inline(R) -> str:
    """The actual error's fall with the slope on each capture, over the record's rows."""
    rec = R(ELEMENT_SLOPE)
    r = rec["result"]
    parts = []
    for cap in r["captures"]:
        f = [n["actual_ratio"] / y["actual_ratio"] for c_, _, y, n in _slope_pairs(r) if c_ == cap]
        parts.append(f"{min(f):.1f} to {max(f):.1f} times lower actual error ratio on {_SLOPE_CAPTURES[cap]}")
    return "; ".join(parts) + f" ({provenance(rec, short=True)}; the table under *The letter's and the tilted " \
                              "plane's settings*)"
