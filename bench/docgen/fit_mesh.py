"""The free-mesh fit (``transient-mi fit --model mesh``) on a small capture (docs/fit.md)."""

from __future__ import annotations

from .common import provenance


def _cm(x) -> str:
    return "-" if x is None else f"{100 * x:.2f} cm"


def _f(x) -> str:
    return "-" if x is None else f"{x:.2f}"


def _arrow(m: dict, key: str, fmt) -> str:
    """``start -> aligned [-> carved] -> fit`` of one metric (the columns a record has)."""
    return " -> ".join(fmt(m[c][key]) for c in ("start", "aligned", "carved", "fit") if c in m)


def _step(r) -> int:
    """The record's pixel step (records before 2026-12-07 fitted every pixel and have none)."""
    return int(r.get("pixel_step") or 1)


def _every(step: int) -> str:
    """``"every pixel"``, ``"every second pixel"``, ``"every 4th pixel"``."""
    return "every pixel" if step == 1 else f"every {'second' if step == 2 else f'{step}th'} pixel"


def _pixels(r) -> str:
    """``", fitted on every second pixel (8 x 8)"`` where the record's fit used a pixel step, else nothing."""
    if _step(r) == 1:
        return ""
    n = int(r["width"]) // _step(r)
    return f", fitted on {_every(_step(r))} ({n} x {n})"


def fit_mesh_table(R) -> str:
    """The letter: fit, start and backprojection against the scene's hidden shapes, and the targets."""
    return _table(R("fit_mesh_letter"))


def fit_mesh_plane_table(R) -> str:
    """The tilted plane, as :func:`fit_mesh_table`."""
    return _table(R("fit_mesh_tilted_plane"))


def fit_mesh_full_table(R) -> str:
    """The letter and the tilted plane at the issue's full size (16 x 16 pixels, 4 x 4 spots): start -> aligned ->
    fit per metric and the targets."""
    recs = [R("fit_mesh_letter_16"), R("fit_mesh_tilted_plane_16")]
    rows = ["| scene | Chamfer, surface to surface (<= 0.5 cm) | silhouette IoU (>= 0.8) | occupancy IoU "
            "| triangles | time (align + fit, wall) |", "|---|---|---|---|---|---|"]
    captures = []
    for rec in recs:
        r = rec["result"]
        m, t = r["metrics"], r["targets"]
        rows.append(f"| {r['scene'].removeprefix('nlos_').replace('_', ' ')} "
                    f"| {_arrow(m, 'chamfer_mesh_m', _cm)}: {'met' if t['met']['chamfer'] else 'not met'} "
                    f"| {_arrow(m, 'silhouette_iou', _f)}: {'met' if t['met']['silhouette_iou'] else 'not met'} "
                    f"| {_arrow(m, 'iou', _f)} | {r['n_faces']['start']} -> {r['n_faces']['fit']} "
                    f"| {r['time_s']['fit_wall']:.0f} s |")
        captures.append(f"{r['scene'].removeprefix('nlos_').replace('_', ' ')}: {_capture(r)} "
                        f"({provenance(rec).strip()})")
    r0 = recs[0]["result"]
    ra = (r0.get("carve_result") or {}).get("realigned")
    then = f", then realigned in {ra['iterations']}" if ra else ""
    carve = f"carving ({r0['carve']} iterations{then}), " if r0.get("carve") else ""
    head = (f"Start -> aligned{' -> carved' if carve else ''} -> fit at the issue's full size ({r0['width']} x "
            f"{r0['width']} pixels of {32 / r0['width']:g} cm{_pixels(r0)}, {r0['spots']} x {r0['spots']} laser "
            f"spots, {r0['exposure_ms']:g} ms per spot, {r0['align']} alignment iterations, {carve}"
            f"{r0['iterations']} iterations in {r0['stages']} stages from "
            f"{100 * r0['cell_m']:g} cm cells), `python bench/bench_fit_mesh.py --width 16 --spots 4`:")
    return head + "\n\n" + "\n".join(rows) + "\n\n" + "; ".join(captures) + "\n"


def fit_mesh_mannequin_para(R) -> str:
    """The paper's mannequin from midpoint-fk's surface within the 5-minute budget, against the issue's targets."""
    from .common import Missing

    recs = [R("fit_mesh_mannequin")]
    for name in ("fit_mesh_mannequin_step2", "fit_mesh_mannequin_step4", "fit_mesh_mannequin_closed"):
        try:  # (further records, where measured)
            recs.append(R(name))
        except Missing:
            pass
    r = recs[0]["result"]
    start, t = r["metrics"][r["start"]], r["targets"]
    rows = ["| | occupancy IoU (>= 0.7) | Chamfer (<= 0.8 cm) | silhouette IoU | depth MAE | triangles | time |",
            "|---|---|---|---|---|---|---|",
            f"| {r['start']} | {_f(start['iou'])} | {_cm(start['chamfer_m'])} "
            f"| {_f(start.get('silhouette_iou'))} | {_cm(start.get('depth_mae_m'))} | | {r['reconstruct_s']:.1f} s |"]
    starts = set()
    for rec in recs:
        q = rec["result"]
        fit, t = q["metrics"]["fit"], q["targets"]
        shape = "closed surface around its voxels" if q.get("start_shape") == "closed" else "front surface"
        sm = q["metrics"].get("start_mesh")
        if sm and shape not in starts:  # (records from 2026-12-05 on score the start mesh too)
            starts.add(shape)
            rows.append(f"| its {shape} (the start) | {_f(sm['iou'])} | {_cm(sm['chamfer_m'])} "
                        f"| {_f(sm.get('silhouette_iou'))} | {_cm(sm.get('depth_mae_m'))} | {q['n_faces']['start']} | |")
        n = q["array"] // _step(q)
        on = _every(_step(q))
        nocarve = ", no carving" if q.get("carve") == 0 else ""
        rows.append(f"| fit:mesh from its {shape}, {on} ({n} x {n}){nocarve}, {q['align']} + {q['iterations']} "
                    f"iterations "
                    f"| {_f(fit['iou'])}: {'met' if t['met']['iou'] else 'not met'} "
                    f"| {_cm(fit['chamfer_m'])}: {'met' if t['met']['chamfer'] else 'not met'} "
                    f"| {_f(fit.get('silhouette_iou'))} | {_cm(fit.get('depth_mae_m'))} "
                    f"| {q['n_faces']['start']} -> {q['n_faces']['fit']} "
                    f"| {q['fit_wall_s']:.0f} s (<= {t['wall_s_max']:.0f} s: {'met' if t['met']['time'] else 'not met'}) |")
    head = (f"The paper scene at {r['array']} x {r['array']} pixels, {r['spots']} x {r['spots']} laser spots, "
            f"{r['exposure_ms']:g} ms per spot (rendered by the quadrature in {r['render_s']:.0f} s), scored on the "
            f"methods study's grid as the leaderboard's rows; the free mesh from {r['start']}'s reconstruction of the "
            f"same counts ({r['fit_bin_width_ps']:g} ps bins; time: the fit's wall time, alignment and iterations "
            f"at the given counts):")
    return (head + "\n\n" + "\n".join(rows) + "\n\n" + " ".join(provenance(rec) for rec in recs) + "\n")


def _capture(r) -> str:
    """How the capture was rendered: its quadrature settings and the rendering-error ratio its detection states."""
    c = r.get("capture")
    if not c or c.get("render_noise_ratio") is None:
        return "the capture rendered by the quadrature"
    st = (c.get("settings_per_spot") or [{}])[0] or {}
    how = (f"to the noise target {c['noise_target']:g}" if c.get("noise_target") is not None
           else "at fixed settings")
    where = (f" ({1000 * st['element_size_m']:.1f} mm elements, {st['patch_cells']} cells per patch side, "
             f"{st['refine_levels']} visibility level{'s' if st['refine_levels'] != 1 else ''})"
             if st.get("element_size_m") else "")
    return (f"the capture rendered by the quadrature {how}{where}, its stated rendering error "
            f"{c['render_noise_ratio']:.2g} x the photon noise")


def _table(rec) -> str:
    r = rec["result"]
    m = r["metrics"]
    t = r["targets"]
    cols = ["fit"] + [c for c in ("carved", "aligned") if c in m] + ["start"]
    names = {"fit": "fit", "carved": ("carved (dark faces dropped, realigned)"
                                      if (r.get("carve_result") or {}).get("realigned") else
                                      "carved (dark faces dropped)"), "aligned": "aligned (affine map and reflectance)",
             "start": "start (backprojection's front surface)"}

    def row(label, key, fmt, bp=True, target=""):
        cells = " | ".join(fmt(m[c][key]) for c in cols)
        return f"| {label} | {cells} | {fmt(m['backprojection'][key]) if bp else ''} | {target} |"

    rows = ["| | " + " | ".join(names[c] for c in cols) + " | backprojection | target (full-size capture) |",
            "|---" * (len(cols) + 3) + "|",
            row("Chamfer, surface to surface", "chamfer_mesh_m", _cm, bp=False,
                target=f"<= {_cm(t['chamfer_mesh_m_max'])}: {'met' if t['met']['chamfer'] else 'not met'}"),
            row("Chamfer (voxels)", "chamfer_m", _cm),
            row("silhouette IoU", "silhouette_iou", _f,
                target=f">= {t['silhouette_iou_min']:g}: {'met' if t['met']['silhouette_iou'] else 'not met'}"),
            row("occupancy IoU", "iou", _f),
            row("depth MAE", "depth_mae_m", _cm)]
    nll = r["poisson_nll"]
    scene = r["scene"].removeprefix("nlos_").replace("_", " ")
    variant = (f", one second moment per vertex, {1000 * r['step_m']:g} mm steps"
               if r.get("moments") == "vertex" else "")
    align = (f"{r['align']} alignment iterations ({r['time_s']['align']:.0f} s), then "
             if r.get("align") else "")
    cr = r.get("carve_result")
    if cr:
        grown = (f"the aligned mesh grown by {r['grow']} ring(s) of faces ({cr['aligned_faces']} -> "
                 f"{cr['grown_faces']}), " if r.get("grow") and "grown_faces" in cr else "")
        align += (f"carving ({grown}{cr['iterations']} per-face reflectance iterations, {r['time_s']['carve']:.0f} s: "
                  f"{cr['kept']} of {cr['subdivided_faces']} faces kept), then ")
        ra = cr.get("realigned")
        if ra:
            align += (f"the carved mesh realigned ({ra['iterations']} alignment iterations, {ra['seconds']:.0f} s), "
                      "then ")
    head = (f"The {scene} at a small configuration ({r['width']} x {r['width']} pixels of {32 / r['width']:g} cm, "
            f"{r['spots']} x {r['spots']} laser spots, the paper's detector for {r['exposure_ms']:g} ms per spot, "
            f"{_capture(r)}); {align}{r['iterations']} iterations in {r['stages']} stages from "
            f"{r['cell_m'] * 100:g} cm cells ({r['n_faces']['start']} -> {r['n_faces']['fit']} triangles){variant}, "
            f"{r['time_s']['fit_wall']:.0f} s (fit, wall):")
    alb = (f"reflectance {r['align_albedo']:.2f} aligned, {r['fit_albedo']:.2f} fitted" if r.get("align")
           else f"fitted reflectance {r['fit_albedo']:.2f}")
    dt = r.get("dead_time_check")
    dead = ""
    if dt:
        def off(x):
            return f"{100 * (x / dt['counts'] - 1):+.1f} %"
        dead = (f"Dead time at the true shape (the capture's own rendered light through the detector layer): "
                f"{dt['counts']:.4g} counts detected; the whole-blind-cycles mean (this fit's) predicts "
                f"{dt['renewal']:.4g} ({off(dt['renewal'])}), the first-order factor (the models' fits') "
                f"{dt['first_order']:.4g} ({off(dt['first_order'])}). ")
    return (head + "\n\n" + "\n".join(rows) + "\n\n"
            f"Poisson NLL of the counts: {nll['start']:.6g} at the start, {nll['fit']:.6g} fitted; {alb}. " + dead
            + provenance(rec))


def fit_mesh_topology_table(R) -> str:
    """The generated shapes of other topology (transient_mi.scenes.topology): start -> aligned -> fit per metric
    and the issue's IoU >= 0.6 target."""
    return _topology_table([R("fit_mesh_chair"), R("fit_mesh_holed_plate")],
                           "at the letter's and tilted plane's configuration and defaults")


#: The shapes of other topology on a larger capture (:func:`fit_mesh_topology_16_table`).
TOPOLOGY_16 = ["fit_mesh_holed_plate_16"]


def fit_mesh_topology_16_table(R) -> str:
    """The shapes of other topology on 16 x 16 pixels, as :func:`fit_mesh_topology_table`."""
    return _topology_table([R(n) for n in TOPOLOGY_16], "on 16 x 16 pixels, at the same defaults")


#: The shapes of other topology from a closed start (:func:`fit_mesh_topology_closed_table`).
TOPOLOGY_CLOSED = ["fit_mesh_chair_closed", "fit_mesh_holed_plate_closed"]


def fit_mesh_topology_closed_table(R) -> str:
    """The shapes of other topology from a closed start (``--start closed``, not carved), as
    :func:`fit_mesh_topology_table`."""
    return _topology_table([R(n) for n in TOPOLOGY_CLOSED],
                           "from a closed surface around the backprojection's occupied voxels (`--start closed`), "
                           "otherwise at the same configuration and defaults")


def _topology_table(recs: list, where: str) -> str:
    """The table of the records ``recs`` (of one configuration, ``where`` it ran), their captures and provenance."""
    names = {"chair": "chair (six boxes)", "holed_plate": "plate with a hole"}
    rows = ["| shape | silhouette IoU | occupancy IoU | Chamfer, surface to surface | triangles | time (fit, wall) "
            "| IoU >= 0.6 |", "|---|---|---|---|---|---|---|"]
    captures = []
    for rec in recs:
        r = rec["result"]
        m, t = r["metrics"], r["targets"]
        met = ", ".join(f"{k.replace('_', ' ')} {'met' if v else 'not met'}" for k, v in t["met"].items())
        rows.append(f"| {names[r['scene']]} | {_arrow(m, 'silhouette_iou', _f)} | {_arrow(m, 'iou', _f)} "
                    f"| {_arrow(m, 'chamfer_mesh_m', _cm)} | {r['n_faces']['start']} -> {r['n_faces']['fit']} "
                    f"| {r['time_s']['fit_wall']:.0f} s | {met} |")
        captures.append(f"{names[r['scene']]}: {_capture(r)}")
    r0 = recs[0]["result"]
    carve = (f"carving ({r0['carve']} iterations), " if r0.get("carve") else "")
    head = (f"Start -> aligned{' -> carved' if carve else ''} -> fit, {where} ({r0['width']} x {r0['width']} pixels "
            f"of {32 / r0['width']:g} cm{_pixels(r0)}, {r0['spots']} x {r0['spots']} laser spots, "
            f"{r0['exposure_ms']:g} ms per spot, {r0['align']} alignment iterations, "
            f"{carve}{r0['iterations']} iterations in "
            f"{r0['stages']} stages from {100 * r0['cell_m']:g} cm cells):")
    closed = recs[-1]["result"]["targets"].get("closed_hole_on_the_grid")
    tail = ""
    if closed:
        tail = (f"The plate's square without the hole, placed exactly, scores silhouette IoU "
                f"{closed['silhouette_iou']:.3f}, occupancy IoU {closed['iou']:.3f} and Chamfer "
                f"{_cm(closed['chamfer_mesh_m'])} on this grid: the silhouette target needs the hole opened. ")
    return (head + "\n\n" + "\n".join(rows) + "\n\n" + "; ".join(captures) + ". " + tail
            + " ".join(provenance(rec) for rec in recs))


#: The growth step's comparison (docs/fit.md): each scene's record without growth (``*_grow0``, ``--grow 0``) against
#: the fit's defaults (two rings where it carves).
GROWTH_PAIRS = [("fit_mesh_letter", "letter, 8 x 8"), ("fit_mesh_tilted_plane", "tilted plane, 8 x 8"),
                ("fit_mesh_chair", "chair, 8 x 8"), ("fit_mesh_holed_plate", "holed plate, 8 x 8")]


def fit_mesh_growth_table(R) -> str:
    """Every free-mesh record without growth (``*_grow0``) against the same at the fit's defaults (two rings): mesh
    Chamfer, silhouette and occupancy IoU of the fit, the faces carving kept, the fit's wall time."""
    rows = ["| scene | Chamfer, surface to surface | silhouette IoU | occupancy IoU | faces kept by carving "
            "| time (fit, wall) |", "|---|---|---|---|---|---|"]
    sources = []
    for name, label in GROWTH_PAIRS:
        before, after = R(f"{name}_grow0"), R(name)
        b, a = before["result"], after["result"]
        mb, ma = b["metrics"]["fit"], a["metrics"]["fit"]
        cb, ca = b.get("carve_result") or {}, a.get("carve_result") or {}
        rows.append(f"| {label} | {_cm(mb['chamfer_mesh_m'])} -> {_cm(ma['chamfer_mesh_m'])} "
                    f"| {_f(mb['silhouette_iou'])} -> {_f(ma['silhouette_iou'])} | {_f(mb['iou'])} -> {_f(ma['iou'])} "
                    f"| {cb.get('kept', '-')} of {cb.get('subdivided_faces', '-')} -> {ca.get('kept', '-')} of "
                    f"{ca.get('subdivided_faces', '-')} | {b['time_s']['fit_wall']:.0f} s -> "
                    f"{a['time_s']['fit_wall']:.0f} s |")
        sources += [provenance(before, short=True), provenance(after, short=True)]
    return ("The fit without growth (`--grow 0`) -> at its defaults (two rings; one machine, one after the other, "
            "see the sources):\n\n" + "\n".join(rows) + "\n\nSources: " + "; ".join(sources)
            + ".\n")


def visibility_memo_para(R) -> str:
    """The letter's small fit with and without the visibility memo: each stage's time range over the runs of each
    mode, and whether every run wrote the same bytes."""
    rec = R("visibility_memo_letter_8")
    r = rec["result"]

    def span(key: str, memo: bool) -> tuple[float, float]:
        xs = [run[key] for run in r["runs"] if run["memo"] is memo]
        return min(xs), max(xs)

    def rng(lo: float, hi: float) -> str:
        return f"{lo:.0f} s" if round(lo) == round(hi) else f"{lo:.0f}-{hi:.0f} s"

    def change(key: str, what: str) -> str:
        off, on = span(key, False), span(key, True)
        mid = lambda x: 0.5 * (x[0] + x[1])  # noqa: E731
        less = 100 * (1 - mid(on) / mid(off))
        return f"{what} {rng(*off)} -> {rng(*on)}" + (f" ({less:.0f} % less)" if less >= 3 else "")

    same = ("every run wrote the same `fitted.ply`, carved mesh and metrics" if r["same_bytes"] else
            "**the runs' outputs differ**")
    return (f"The letter's small fit (its record under \"Any shape\"; {r['width']} x {r['width']} pixels, "
            f"{r['spots']} x {r['spots']} spots, {r['exposure_ms']:g} ms), {r['repeats']} runs without the memo and {r['repeats']} with it, "
            f"alternating in one process (the range of each mode's runs; the change of their midpoints): "
            f"{change('carve_s', 'carving')}, {change('optimisation_s', 'vertex stage')}, "
            f"{change('align_s', 'alignment')}, {change('fit_wall_s', 'the whole fit')}; {same}. {provenance(rec)}\n")


def fit_mesh_pixel_step_inline(R) -> str:
    """The paper mannequin's free-mesh fit on every pixel against every second and every fourth (``--pixel-step``)."""
    recs = [R("fit_mesh_mannequin"), R("fit_mesh_mannequin_step2"), R("fit_mesh_mannequin_step4")]
    q = [rec["result"] for rec in recs]
    m = [r["metrics"]["fit"] for r in q]
    sides = [r["array"] // _step(r) for r in q]
    times = [f"{r['fit_wall_s']:.0f} s" for r in q]
    return (f"on the mannequin below ({' / '.join(f'{n} x {n}' for n in sides)} pixels) {' / '.join(times)}, occupancy "
            f"IoU {' / '.join(_f(x['iou']) for x in m)}, Chamfer {' / '.join(_cm(x['chamfer_m']) for x in m)}, "
            f"silhouette IoU {' / '.join(_f(x.get('silhouette_iou')) for x in m)} "
            f"({'; '.join(provenance(rec, short=True) for rec in recs)})")
