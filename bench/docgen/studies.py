"""Studies, datasets, viewer and fit regions (docs/benchmarks.md, docs/studies.md, docs/dataset.md,
docs/view.md, docs/fit.md).
"""

from __future__ import annotations

from docgen.common import Missing, _gb, not_measured, provenance, shown_command


def _study_cases(R):
    rec = R("studies")
    return rec, {c["case"]: c for c in rec["result"]["cases"]}


def studies_para(R) -> str:
    rec, c = _study_cases(R)

    def one(k, what):
        x = c.get(k)
        if not x or x.get("status") != "ok":
            return f"{what}: not yet re-measured (`--full`)"
        return f"{what} {x['wall_s']:.0f} s, {_gb(x['peak_rss_mb'])}"

    pq = c.get("photon_quick", {})
    return (f"\n**Studies** (`{shown_command(rec)}`): "
            + one("photon_quick", f"`study photon-budget --quick` ({pq.get('runs', '?')} detections and "
                                  f"reconstructions)") + "; "
            + one("photon_default", "with 1 ps bins") + "; "
            + one("array_quick", "`study array-size --quick` (4x4 to 64x64)") + "; "
            + one("array_default", "with 1 ps bins") + f" (wall time of the whole command, peak RSS). "
            f"{provenance(rec)}\n")


def _study_inline(key):
    def gen(R):
        rec, c = _study_cases(R)
        x = c.get(key)
        if not x or x.get("status") != "ok":
            raise Missing("studies")
        return f"{x['wall_s']:.0f} s, {_gb(x['peak_rss_mb'])} peak on {rec['machine']['cores']} cores"
    return gen


def dataset_para(R) -> str:
    rec = R("dataset_dataset_example")
    r = rec["result"]
    runs = ", ".join(f"{x['items_per_hour']:.0f} (`--workers {x['workers']}`, {x['items']} items in {x['wall_s']:.0f} s)"
                     for x in r["runs"])
    text = (f"\n**Datasets** (`{shown_command(rec)}`, the camera example "
            f"`docs/examples/dataset_example.yaml`, wall time of the whole command): items per hour {runs}. "
            f"{provenance(rec)}")
    try:
        n = R("dataset_dataset_nlos_mannequin")
        nr = ", ".join(f"{x['items_per_hour']:.0f} (`--workers {x['workers']}`)" for x in n["result"]["runs"])
        text += (f" The NLOS example spec (`docs/examples/dataset_nlos_mannequin.yaml`: paper scene, 16x16/32x32 "
                 f"arrays, counts, ground truth): items per hour {nr}. {provenance(n)}")
    except Missing:
        text += (" The NLOS example spec (`docs/examples/dataset_nlos_mannequin.yaml`): not yet re-measured "
                 "(`bench/results/dataset_dataset_nlos_mannequin.json` missing).")
    return text + "\n"


#: How the docs name each estimator of three-bounce light.
ESTIMATOR_NAMES = {"quadrature": "the quadrature", "monte_carlo": "Monte Carlo"}


def dataset_nlos_inline(R) -> str:
    """The NLOS example spec at its own settings: items, wall time, items per hour and the largest stated ratio."""
    rec = R("dataset_dataset_nlos_mannequin")
    x = rec["result"]["runs"][0]
    return (f"{x['items']} items in {x['wall_s']:.0f} s with `--workers {x['workers']}`, i.e. about "
            f"{x['items_per_hour']:.0f} items per hour on {rec['machine']['cores']} cores, rendered by "
            + " and ".join(ESTIMATOR_NAMES.get(e, e) for e in sorted(x["estimators"])) + f" (the paper scene's default), each capture's stated "
            f"rendering error at most {x['render_noise_ratio_max']:.2g} x the photon noise "
            f"(`{shown_command(rec)}`; {provenance(rec, short=True)})")


def dataset_docs_table(R) -> str:
    rec = R("dataset_dataset_example")
    r = rec["result"]
    lines = ["| configuration | items | wall (s) | items per hour | mean item time in a worker (s) |",
             "|---|---|---|---|---|"]
    for x in r["runs"]:
        where = f"`--scheduler {x['scheduler']}`" if x.get("scheduler") else f"local, `--workers {x['workers']}`"
        lines.append(f"| {where} | {x['items']} | {x['wall_s']:.1f} | {x['items_per_hour']:.0f} | "
                     f"{x['mean_item_s_in_worker']:.2f} |")
    lines += ["", provenance(rec)]
    return "\n" + "\n".join(lines) + "\n"


def view_para(R) -> str:
    rec = R("view")
    res = rec["result"]
    c = res["cases"]
    fp, de, rc = c["first_page"], c["detector_update"], c["recon_update"]
    load = res.get("load_average_1_5_15_min", {})
    lo = load.get("before", [None])[0]

    def met(case):
        return "met" if case["goal_met"] else "not met"

    cpu_d = sorted(de["server_cpu_ms"])
    cpu_r = sorted(rc["server_cpu_ms"])
    return (f"**Viewer** (`{rec['command'].strip()}`, timed in headless Chromium, median of {res['repeats']}): a "
            f"detector-slider change on a {de['capture']} capture reaches the page in {de['median_s']:.2f} s (goal "
            f"<= {de['goal_s']:g} s, {met(de)}; server CPU {cpu_d[0]:.0f}-{cpu_d[-1]:.0f} ms); a reconstruction change "
            f"at {rc['voxels']} ({rc['methods']}) in {rc['median_s']:.2f} s (goal <= {rc['goal_s']:g} s, {met(rc)}; "
            f"server CPU {cpu_r[0]:.0f}-{cpu_r[-1]:.0f} ms); the first page {fp['median_s']:.1f} s after starting the "
            f"command ({fp['from_server_ready_median_s']:.1f} s after the server printed its address; goal <= "
            f"{fp['goal_s']:g} s, {met(fp)}"
            + (f"; the first start of the run, untimed, {fp['cold_start_s']:.1f} s" if "cold_start_s" in fp else "")
            + f"). Source: `bench/results/view.json` ({rec['date_utc'][:10]}; "
            f"{rec['machine'].get('cpu_model') or rec['machine'].get('cpu')}, {rec['machine'].get('cores_available') or rec['machine']['cores']} cores"
            + (f", 1-min load {lo:.1f} at the start" if lo is not None else "") + ").\n")


def view_docs_table(R) -> str:
    rec = R("view")
    res = rec["result"]
    c = res["cases"]
    fp, de, rc = c["first_page"], c["detector_update"], c["recon_update"]
    load = res.get("load_average_1_5_15_min", {})

    def goal(case):
        return f"<= {case['goal_s']:g} s: {'met' if case['goal_met'] else 'not met'}"

    def span(ms):
        v = sorted(ms)
        return f"{v[0] / 1000:.2f}-{v[-1] / 1000:.2f}"

    return ("| case | median (worst) of %d, in the browser | server per update | goal |\n|---|---|---|---|\n" % res["repeats"]
            + f"| detector update, {de['capture']} | {de['median_s']:.2f} s ({de['worst_s']:.2f} s) | "
              f"{span(de['server_ms'])} s wall, {span(de['server_cpu_ms'])} s CPU | {goal(de)} |\n"
            + f"| reconstruction update, {rc['voxels']} | {rc['median_s']:.2f} s ({rc['worst_s']:.2f} s) | "
              f"{span(rc['server_ms'])} s wall, {span(rc['server_cpu_ms'])} s CPU | {goal(rc)} |\n"
            + f"| first page, from the command's start | {fp['median_s']:.1f} s ({fp['worst_s']:.1f} s) | "
              f"({fp['from_server_ready_median_s']:.1f} s median from the printed address"
              + (f"; the first start of the run {fp['cold_start_s']:.1f} s, untimed" if "cold_start_s" in fp else "")
              + f") | {goal(fp)} |\n\n"
            + f"Source: `bench/results/view.json` ({rec['date_utc'][:10]}; {rec['machine'].get('cpu_model') or rec['machine'].get('cpu')}, "
              f"{rec['machine'].get('cores_available') or rec['machine']['cores']} cores; 1-min load average {load.get('before', ['?'])[0]} before "
              f"and {load.get('after', ['?'])[0]} after the run).\n")


#: name -> (generator, records it reads, inline?)
def fit_para(R) -> str:
    rec = R("fit")
    r = rec["result"]
    m = r["metrics"]
    f, b = m["fit"], m["backprojection"]
    t = r["targets"]
    err = r["parameters"]["error"]

    def ok(good: bool) -> str:
        return "met" if good else "missed"

    cap = r["capture"]
    rows = [
        ("joint angles, largest error (mean)", f"{m['joint_error_max_deg']:.1f} deg ({m['joint_error_mean_deg']:.1f})",
         "", f"<= {t['joint_error_max_deg']:g} deg: {ok(m['joint_error_max_deg'] <= t['joint_error_max_deg'])}"),
        ("body centre, distance", f"{100 * m['position_error_m']:.2f} cm", "",
         f"<= {100 * t['position_error_m']:g} cm: {ok(m['position_error_m'] <= t['position_error_m'])}"),
        ("height, reflectance", f"{100 * err['height_m']:+.2f} cm, {err['albedo']:+.3f}", "", ""),
        ("Chamfer (voxels, as the demo scores backprojection)", f"{100 * f['chamfer_m']:.2f} cm",
         f"{100 * b['chamfer_m']:.2f} cm", f"<= {100 * t['chamfer_m']:g} cm: {ok(f['chamfer_m'] <= t['chamfer_m'])}"),
        ("occupancy IoU", f"{f['iou']:.2f}", f"{b['iou']:.2f}", f">= {t['iou']:g}: {ok(f['iou'] >= t['iou'])}"),
        ("Chamfer, fitted surface to true surface", f"{100 * f['chamfer_mesh_m']:.2f} cm", "", ""),
        ("depth MAE, silhouette IoU", f"{100 * f['depth_mae_m']:.2f} cm, {f['silhouette_iou']:.2f}",
         f"{100 * b['depth_mae_m']:.2f} cm, {b['silhouette_iou']:.2f}", ""),
        ("time (fit command, wall)", f"{r['fit_wall_s']:.0f} s", "",
         f"<= {t['fit_wall_s'] / 60:g} min: {ok(r['fit_wall_s'] <= t['fit_wall_s'])}"),
    ]
    head = "| | fit | backprojection (paper's filter) | target |\n|---|---|---|---|\n"
    body = "\n".join(f"| {a} | {x} | {y} | {z} |" for a, x, y, z in rows)
    names = ESTIMATOR_NAMES
    cap_est = names.get(cap["defines"].get("estimator", "monte_carlo"), "Monte Carlo")
    return (f"\nThe paper's scene ({cap['array']}x{cap['array']} array, 2 x 2 laser spots, the paper's detector for "
            f"{cap['exposure_s'] * 1000:g} ms per spot, rendered by {cap_est} to the demo's noise target"
            + (f", {cap['noise_target']:g}" if cap.get("noise_target") is not None else "") + ") with the "
            f"mannequin in a "
            f"pose the fit does not start from (`{cap['defines'].get('joints', '')}`, turned "
            f"{cap['defines']['rotation']} degrees, {cap['defines']['distance']} m from the wall); the fit ran with its "
            f"defaults ({_fit_method(r, names)}):\n\n" + head + body
            + f"\n\nPoisson NLL of the counts{_nll_pixels(r)}: {r['poisson_nll']['start']:.6g} at the start, "
            f"{r['poisson_nll']['fit']:.6g} fitted. {provenance(rec)}\n" + _fit_arrays_line(R) + _fit_adam_line(R, names))


def _fit_arrays_line(R) -> str:
    """The same pose and defaults on smaller arrays (``bench_fit.py --array N``), where recorded."""
    parts = []
    for n in (16, 8):
        try:
            rec = R(f"fit_{n}")
        except Missing:
            continue
        r = rec["result"]
        m, o = r["metrics"], r.get("optimizer") or {}
        step = int(o.get("pixel_step", 1))
        h, w = o.get("pixels_used", (n, n))
        which = "every pixel" if step == 1 else f"every {_ordinal(step)} pixel along each axis"
        parts.append(f"{n}x{n} array ({which}: {h} x {w}): {r['fit_wall_s']:.0f} s, joint angles within "
                     f"{m['joint_error_max_deg']:.1f} deg, body centre within {100 * m['position_error_m']:.2f} cm, "
                     f"occupancy IoU {m['fit']['iou']:.2f} ({provenance(rec, short=True)})")
    return ("\nThe same pose with the same defaults on smaller arrays (`python bench/bench_fit.py --array N --save`): "
            + "; ".join(parts) + ".\n") if parts else ""


def _fit_method(r: dict, names: dict) -> str:
    """What ran: the optimiser, its iterations, the forward model and, for Gauss-Newton, the pixels and the twin."""
    o = r.get("optimizer") or {"used": "adam", "iterations": r["settings"]["iterations"]}
    est = names[r["estimator"]["used"]] if r.get("estimator") else "Monte Carlo"
    if o["used"] == "gauss_newton":
        h, w = o["pixels_used"]
        which = "every pixel" if o["pixel_step"] == 1 else f"every {_ordinal(o['pixel_step'])} pixel along each axis"
        return (f"Gauss-Newton, {o['iterations']} iterations, forward model: {est}, {which} ({h} x {w}), the twin at "
                f"{o['detail']} segments")
    return f"Adam, {o['iterations']} iterations, forward model: {est}"


def _ordinal(k: int) -> str:
    return f"{k}{'th' if 10 <= k % 100 <= 20 else {1: 'st', 2: 'nd', 3: 'rd'}.get(k % 10, 'th')}"


def _nll_pixels(r: dict) -> str:
    step = r["poisson_nll"].get("pixel_step") or 1
    return "" if step == 1 else " (of the pixels the fit used)"


def _fit_adam_line(R, names: dict) -> str:
    """One line on the Monte Carlo and Adam fit of the same capture (the defaults until Gauss-Newton)."""
    try:
        rec = R("fit_adam")
    except Missing:
        return ""
    r = rec["result"]
    m = r["metrics"]
    return (f"\nWith Monte Carlo and Adam (`--estimator monte_carlo`: {_fit_method(r, names)}; the defaults until "
            f"2026-12-06, when the command below ran them): joint angles within {m['joint_error_max_deg']:.1f} deg, body centre within "
            f"{100 * m['position_error_m']:.2f} cm, occupancy IoU {m['fit']['iou']:.2f}, surface Chamfer "
            f"{100 * m['fit']['chamfer_mesh_m']:.2f} cm, in {r['fit_wall_s']:.0f} s. {provenance(rec)}\n")


#: The NLOS example with every item rendered to a noise target, by each estimator (Monte Carlo, the default until the
#: quadrature became it, and the quadrature), at the project's noise standard 0.1 and the issue's 0.01:
#: ``bench_dataset.py --spec docs/examples/dataset_nlos_mannequin.yaml --noise-target R [-D estimator=monte_carlo]``.
DATASET_NT = tuple(f"dataset_dataset_nlos_mannequin_nt{r}_{e}" for r in ("0.01", "0.1")
                   for e in ("monte_carlo", "quadrature"))


def dataset_noise_standard_table(R) -> str:
    """Items per hour of the NLOS example with every item rendered to a noise target, by each estimator, and the
    quadrature's items per hour over Monte Carlo's at the same target (both measured)."""
    lines = ["| noise target | estimator | items | wall (s) | items per hour | against Monte Carlo | "
             "mean render time per item in a worker (s) | spp per item | largest ratio (median) | target met |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    recs, missing = [], []
    for name in DATASET_NT:
        try:
            recs.append(R(name))
        except Missing:
            missing.append(name)
    mc = {rec["result"]["noise_target"]: rec["result"]["runs"][0]["items_per_hour"] for rec in recs
          if "monte_carlo" in rec["result"]["runs"][0]["estimators"]}
    for rec in recs:
        target = rec["result"]["noise_target"]
        for x in rec["result"]["runs"]:
            est = "+".join(sorted(x["estimators"]))
            spp = "-" if not x.get("spp_used_range") else "{}-{}".format(*x["spp_used_range"])
            vs = (f"{x['items_per_hour'] / mc[target]:.2g}x" if target in mc and est == "quadrature" else "")
            lines.append(f"| {target:g} | {est} (`--workers {x['workers']}`) | {x['items']} | {x['wall_s']:.0f} | "
                         f"{x['items_per_hour']:.1f} | {vs} | {x['mean_render_s_in_worker']:.1f} | {spp} | "
                         f"{x['render_noise_ratio_max']:.3g} ({x['render_noise_ratio_median']:.3g}) | "
                         f"{x['noise_target_met']} of {x['items']} |")
    lines.append("")
    lines += [provenance(rec) for rec in recs]
    if missing:
        lines += ["", not_measured(missing, True).strip("()") + "."]
    return "\n" + "\n".join(lines) + "\n"


def fit_quadrature_cost_table(R) -> str:
    """One fit iteration's cost per forward model on bench_fit's capture (bench_fit_quadrature_cost.py), with the
    300 default iterations' optimisation extrapolated (labelled)."""
    rec = R("fit_quadrature_cost_32")
    r = rec["result"]
    rows = r["rows"]
    mc = {x["detail"]: x["iteration_s"] for x in rows if x["estimator"] == "monte_carlo"}
    head = ("| forward model | twin detail (faces) | render | backward pass | iteration | against Monte Carlo | "
            "300 iterations (extrapolated) |\n|---|---|---|---|---|---|---|\n")
    body = []
    for x in rows:
        quad = x["estimator"] == "quadrature"
        what = f"quadrature, {100 * x['element_size_m']:g} cm" if quad else \
            f"Monte Carlo, {x['spp']} + {x['spp_residual']} spp"
        ratio = f"{x['iteration_s'] / mc[x['detail']]:.0f}x" if quad and x["detail"] in mc else ""
        body.append(f"| {what} | {x['detail']} ({x['faces']}) | {x['render_s']:.1f} s | {x['backward_s']:.1f} s | {x['iteration_s']:.1f} s | {ratio} | "
                    f"{300 * x['iteration_s'] / 60:.0f} min |")
    return (f"\nOne iteration of the fit (one render for the residual, one backward pass) on bench_fit's capture "
            f"({r['array']}x{r['array']} pixels, {r['spots']} laser spots, 10 ps bins), at the start pose; the "
            f"second of two iterations:\n\n" + head + "\n".join(body) + f"\n\n{provenance(rec)}\n")
