"""NLOS capture benchmark: transient-mi vs mitransient, time to equal error and peak memory.

Prints one JSON document (also written to ``--out``). For each configuration

* confocal 32 x 32 pixels, 400 bins;
* confocal 64 x 64 pixels, 2048 bins;
* array capture 32 x 32 pixels x 32 x 32 laser spots, 400 bins;

both renderers render the same scene (a 1 m x 1 m Lambertian relay wall,
the letter F of three coplanar rectangles 0.5 m in front of it, laser and
detector 1.5 m away, three-bounce light, first/last segments excluded,
the wall's direct return excluded) at increasing samples per pixel. Each
run is compared with a high-spp reference *of the same renderer*: the
relative error ``||x - ref|| / ||ref||`` over all (spot, pixel, bin) values
(array: over a fixed subset of spots, the same for both). Since both
estimators are unbiased, ``E||x - ref||^2 = a (1/spp + 1/spp_ref)``; ``a``
is fitted from the runs, the render time is fitted as ``t0 + t1 spp``, and
the time to reach a relative RMSE ``eps`` is ``t1 a / eps^2`` (plus ``t0``).
The speed-up at equal error is the ratio of these times.

Timings exclude JIT compilation (every setting is rendered twice; the second
call is timed) and process start-up. Peak RSS is each worker process's
``ru_maxrss``. transient-mi's array capture is also run end to end through
the render pipeline (one EXR file per spot) to measure its peak RSS and its
independence of the number of spots.

The two renderers define the measurement differently (mitransient: the
radiance at each pixel's patch centre for a laser of unit projector
intensity; transient-mi: photons per pulse integrated over the patch and the
aperture), so their means are compared after dividing out the known
per-pixel and per-spot geometric factors (``mean_agreement``).

mitransient lives in its own virtual environment
(``~/.cache/transient-mi-bench/mitransient`` by default, created on demand
with ``pip install mitransient``; it is never a dependency of transient-mi)
and runs in a subprocess with ``DRJIT_LIBLLVM_PATH`` pointing at an
LLVM >= 17.

Usage::

    python bench/bench_nlos.py [--small] [--mitransient auto|install|skip] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _record  # noqa: E402
from _rss import peak_rss_mb, reset_peak_rss  # noqa: E402
from _nlos_scene import (APERTURE_DIAMETER_M, DETECTOR, EPS, LASER, LETTER_SIZE, LETTER_Z, PULSE_ENERGY_J,  # noqa: E402,F401
                         RECTANGLES, START_OPL, WALL, WAVELENGTH_NM, configs, mean_agreement, ours_scene_dict,
                         ours_scene_xml,
                         time_axis)
from _peers import MT_VENV, MT_VERSION, mitransient_python, mt_env as _mt_env, run as _run  # noqa: E402,F401

ROOT = Path(__file__).resolve().parents[1]
C_M_PER_PS = 299792458.0 * 1e-12

def ours_worker(cfg_path: str) -> None:
    """Render the runs of one configuration with transient-mi (this process)."""
    job = json.load(open(cfg_path))
    cfg = job["cfg"]
    if job.get("pipeline"):
        from transient_mi.render_capture import render

        t0 = time.perf_counter()
        render(job["scene"], job["out_dir"], spp=job["spp"], seed=1, progress=False)
        res = {"time_s": time.perf_counter() - t0,
               "max_rss_mb": peak_rss_mb()}
        json.dump(res, open(job["result"], "w"))
        return
    import transient_mi  # noqa: F401  (first: it points drjit at an LLVM >= 17)

    import mitsuba as mi

    scene = mi.load_dict(ours_scene_dict(cfg), optimize=False)
    sensor = scene.sensors()[0]
    integ = scene.integrator()
    if cfg["capture"] == "array":
        # the group of spots the render pipeline renders together, from the middle of the scan
        groups = sensor.spot_groups(scene, int(job["runs"][-1][0]))
        spots = groups[len(groups) // 2]
    else:
        spots = [0]
    out = []
    for i, (spp, seed, save) in enumerate(job["runs"]):
        timings = []
        ref = job.get("ref_last") and i == len(job["runs"]) - 1
        data = None
        reset_peak_rss()  # every run reports its own peak
        for rep in range(1 if ref else 1 + job.get("repeats", 2)):  # first call compiles; min of the others
            data = None
            t0 = time.perf_counter()
            if cfg["capture"] == "array":
                data = np.stack([r.histogram for r in integ.render_transient(scene, sensor, seed=seed, spp=spp,
                                                                             spots=spots)])
            else:
                data = integ.render_transient(scene, sensor, seed=seed, spp=spp).histogram[None]
            timings.append(time.perf_counter() - t0)
        if save:
            np.save(save, data)
        out.append({"spp": spp, "seed": seed, "time_s": min(timings[1:] or timings), "first_call_s": timings[0],
                    "times_s": timings, "spots": spots,
                    "max_rss_mb": peak_rss_mb(),
                    "shape": list(data.shape), "sum": float(data.sum(dtype=np.float64))})
        print(json.dumps(out[-1]), file=sys.stderr, flush=True)
    json.dump(out, open(job["result"], "w"))


# --------------------------------------------------------------- mitransient


# ------------------------------------------------------------------ analysis


def _invoke(side: str, cfg: dict, tmp: Path, py: Path | None, runs: list, tag: str) -> list:
    result = tmp / f"{side}_{tag}_result.json"
    if side == "ours":
        job = {"cfg": cfg, "runs": runs, "result": str(result), "repeats": cfg.get("repeats", 3),
               "ref_last": tag == "a"}
        (tmp / f"ours_{tag}_job.json").write_text(json.dumps(job))
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        _run([sys.executable, __file__, "--worker", str(tmp / f"ours_{tag}_job.json")], env=env)
    else:
        bw, start = time_axis(cfg)
        mcfg = {"capture": cfg["capture"], "width": cfg["size"], "height": cfg["size"], "n_bins": cfg["n_bins"],
                "bin_width_opl": bw, "start_opl": start, "wall": WALL, "detector": DETECTOR, "laser": LASER,
                "max_depth": -1, "rectangles": RECTANGLES, "runs": runs, "result": str(result),
                "repeats": cfg.get("repeats", 3), "ref_last": tag == "a"}
        (tmp / f"mt_{tag}_job.json").write_text(json.dumps(mcfg))
        _run([str(py), str(ROOT / "bench" / "_mitransient_worker.py"), str(tmp / f"mt_{tag}_job.json")],
             env=_mt_env())
    return json.loads(result.read_text())


def _runs(side, cfg, tmp):
    spp_list = cfg["spp"] if side == "ours" else cfg["mt_spp"]
    spp_ref = cfg["spp_ref"] if side == "ours" else cfg["mt_spp_ref"]
    runs = [[int(s), 10 + i, str(tmp / f"{side}_{i}.npy")] for i, s in enumerate(spp_list)]
    runs.append([int(spp_ref), 999, str(tmp / f"{side}_ref.npy")])
    return runs


def fit_error_model(spp, mse, spp_ref) -> tuple[float, float]:
    """Fit ``mse = A (spp^-beta + spp_ref^-beta)`` (independent reference) in log space; returns (A, beta)."""
    spp = np.asarray(spp, dtype=float)
    lm = np.log(np.asarray(mse, dtype=float))
    best = None
    for beta in np.linspace(0.5, 2.5, 401):
        basis = np.log(spp ** -beta + spp_ref ** -beta)
        log_a = float(np.mean(lm - basis))
        err = float(np.sum((lm - basis - log_a) ** 2))
        if best is None or err < best[0]:
            best = (err, math.exp(log_a), float(beta))
    return best[1], best[2]


def _analyse(side, cfg, runs, info, spots) -> dict:
    spp_ref = runs[-1][0]
    ref = np.load(runs[-1][2], mmap_mode="r")
    if side == "mitransient" and cfg["capture"] == "array":
        ref = ref[spots]
    ref = np.asarray(ref, dtype=np.float64)
    ref_norm2 = float((ref ** 2).mean())
    rows = []
    for (spp, seed, path), inf in zip(runs[:-1], info[:-1]):
        x = np.load(path, mmap_mode="r")
        if side == "mitransient" and cfg["capture"] == "array":
            x = x[spots]
        x = np.asarray(x, dtype=np.float64)
        mse_rel = float(((x - ref) ** 2).mean()) / ref_norm2
        row = {"spp": spp, "time_s": inf["time_s"], "first_call_s": inf["first_call_s"],
               "times_s": inf.get("times_s"), "rel_rmse": math.sqrt(mse_rel), "max_rss_mb": inf["max_rss_mb"]}
        if "render_rss_mb" in inf:
            row["render_rss_mb"] = inf["render_rss_mb"]
        rows.append(row)
    del ref
    s = np.array([r["spp"] for r in rows], dtype=float)
    t = np.array([r["time_s"] for r in rows])
    mse = np.array([r["rel_rmse"] ** 2 for r in rows])
    scale = 1.0
    if cfg["capture"] == "array" and side == "ours":  # a group of spots was rendered: time the whole capture
        scale = cfg["size"] ** 2 / len(spots)
    t = t * scale
    for r in rows:
        r["time_full_capture_s"] = r["time_s"] * scale
    t1, t0 = np.polyfit(s, t, 1) if len(s) > 1 else (t[0] / s[0], 0.0)
    t1 = max(float(t1), float((t / s).min()) * 0.25)
    t0 = max(float(t0), 0.0)
    A, beta = fit_error_model(s, mse, spp_ref)
    out = {"runs": rows, "spp_ref": spp_ref, "ref_time_s": info[-1]["time_s"] * scale,
           "projector_intensity": info[-1].get("projector_intensity"),
           "time_model_s": {"t0": t0, "per_spp": t1},
           "error_model": {"A": A, "beta": beta, "rel_rmse": "sqrt(A) * spp^(-beta/2)"},
           "time_to_rel_rmse_s": {str(eps): t0 + t1 * (eps ** 2 / A) ** (-1.0 / beta) for eps in EPS},
           # measured: the runs bracket eps (the fit interpolates); extrapolated: no run reached eps
           "time_to_rel_rmse_basis": {str(eps): ("measured" if min(r["rel_rmse"] for r in rows) <= eps <=
                                                 max(r["rel_rmse"] for r in rows) else "extrapolated")
                                      for eps in EPS},
           # each run's own peak (VmHWM reset before it), reference run excluded
           "peak_rss_per_run_mb": [r["max_rss_mb"] for r in rows],
           "peak_rss_mb": max(r["max_rss_mb"] for r in rows),
           "peak_rss_reference_run_mb": info[-1]["max_rss_mb"]}
    if all("render_rss_mb" in r for r in rows):
        out["render_rss_per_run_mb"] = [r["render_rss_mb"] for r in rows]
    if scale != 1.0:
        out["note"] = (f"rendered one group of {len(spots)} of the {cfg['size'] ** 2} spots per run (the group the "
                       f"pipeline renders together); times scaled by {scale:g} to the whole capture")
    return out


def _compare(cfg, tmp, py) -> dict:
    """Both renderers: spp series and references (saved), then a second timing-only pass, interleaved."""
    r_ours, r_mt = _runs("ours", cfg, tmp), _runs("mitransient", cfg, tmp)
    info_o = _invoke("ours", cfg, tmp, None, r_ours, "a")
    info_m = _invoke("mitransient", cfg, tmp, py, r_mt, "a") if py is not None else None
    # second pass, timing only (machines shared with other work: keep the faster of two passes)
    info_o2 = _invoke("ours", cfg, tmp, None, [[s, 77, None] for s, _, _ in r_ours[:-1]], "b")
    for a, b in zip(info_o, info_o2):
        a["time_s"] = min(a["time_s"], b["time_s"])
    if py is not None:
        info_m2 = _invoke("mitransient", cfg, tmp, py, [[s, 77, None] for s, _, _ in r_mt[:-1]], "b")
        for a, b in zip(info_m, info_m2):
            a["time_s"] = min(a["time_s"], b["time_s"])
    spots = info_o[-1].get("spots", [0])
    entry = {"ours": _analyse("ours", cfg, r_ours, info_o, spots), "error_spots": spots}
    if py is not None:
        entry["mitransient"] = _analyse("mitransient", cfg, r_mt, info_m, spots)
        o, m = entry["ours"], entry["mitransient"]
        entry["speedup_time_to_equal_error"] = {
            eps: m["time_to_rel_rmse_s"][eps] / o["time_to_rel_rmse_s"][eps] for eps in o["time_to_rel_rmse_s"]}
        entry["speedup_basis"] = {
            eps: ("measured" if o["time_to_rel_rmse_basis"][eps] == m["time_to_rel_rmse_basis"][eps] == "measured"
                  else "extrapolated") for eps in o["time_to_rel_rmse_s"]}
        entry["mean_agreement"] = mean_agreement(cfg, np.load(r_ours[-1][2]), np.load(r_mt[-1][2], mmap_mode="r"),
                                                 spots)
        # mitransient's spot irradiance is I cos / d^2 for a projector of axial intensity I, ours puts all N
        # photons at the spot: the normalised totals then differ by the factor 1 / I
        entry["mean_agreement"]["expected_scale"] = 1.0 / m["projector_intensity"]
    else:
        entry["mitransient"] = None
    return entry


def _pipeline(cfg, tmp: Path) -> dict:
    """transient-mi end to end (one EXR per spot): peak RSS for growing numbers of spots."""
    out = {}
    for n in cfg.get("pipeline_spots", []):
        scene = tmp / f"array_{n}.xml"
        scene.write_text(ours_scene_xml(cfg, n))
        od = tmp / f"cap_{n}"
        res = tmp / f"pipe_{n}.json"
        job = {"cfg": cfg, "pipeline": True, "scene": str(scene), "out_dir": str(od), "spp": 4,
               "result": str(res)}
        (tmp / f"pipe_{n}_job.json").write_text(json.dumps(job))
        _run([sys.executable, __file__, "--worker", str(tmp / f"pipe_{n}_job.json")],
             env=dict(os.environ, PYTHONPATH=str(ROOT), TRANSIENT_MI_PROGRESS="0"))
        r = json.loads(res.read_text())
        out[f"{n}x{n}_spots"] = {"time_s": r["time_s"], "peak_rss_mb": r["max_rss_mb"],
                                 "files": len(list(od.glob("spot_*.exr")))}
        shutil.rmtree(od, ignore_errors=True)
    return out


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--small", action="store_true", help="tiny sizes (CI)")
    ap.add_argument("--mitransient", choices=("auto", "install", "skip"), default="install",
                    help="auto: use mitransient's venv if present; install: create it if missing; skip")
    ap.add_argument("--only", default=None, help="run only configurations whose name contains this")
    ap.add_argument("--out", default=None, help="also write the JSON here")
    ap.add_argument("--pixel-sampling", default="center", choices=("center", "area"),
                    help="transient-mi's pixel_sampling for the comparison (center = mitransient's estimand)")
    ap.add_argument("--hidden-geometry-prob", type=float, default=1.0,
                    help="transient-mi's hidden_geometry_prob (1 is unbiased on a planar relay wall)")
    ap.add_argument("--table", default=None, metavar="JSON", help="print the markdown table of a saved report")
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    _record.add_arguments(ap)
    args = ap.parse_args(argv)
    if args.table:
        from docgen.nlos import markdown_table

        print(markdown_table(json.loads(Path(args.table).read_text())))
        return {}
    if args.worker:
        ours_worker(args.worker)
        return {}
    load_start = list(os.getloadavg())
    py = mitransient_python(args.mitransient)
    report = {"benchmark": "nlos", "small": args.small,
              "machine": {"python": platform.python_version(), "cpus": os.cpu_count(), "platform": platform.platform()},
              "mitransient": {"available": py is not None, "version": MT_VERSION if py else None,
                              "venv": str(MT_VENV) if py else None},
              "configs": []}
    tmp = Path(tempfile.mkdtemp(prefix="bench_nlos_"))
    try:
        for cfg in configs(args.small):
            if args.only and args.only not in cfg["name"]:
                continue
            cfg["pixel_sampling"] = args.pixel_sampling
            cfg["hidden_geometry_prob"] = args.hidden_geometry_prob
            t_cfg = tmp / cfg["name"]
            t_cfg.mkdir()
            entry = {"name": cfg["name"], "capture": cfg["capture"], "pixels": [cfg["size"]] * 2,
                     "spots": cfg["size"] ** 2, "n_bins": cfg["n_bins"],
                     "ours_settings": {"pixel_sampling": cfg["pixel_sampling"],
                                       "hidden_geometry_prob": cfg["hidden_geometry_prob"], "max_depth": 4}}
            entry.update(_compare(cfg, t_cfg, py))
            if cfg["capture"] == "array":
                entry["ours_pipeline"] = _pipeline(cfg, t_cfg)
            report["configs"].append(entry)
            shutil.rmtree(t_cfg, ignore_errors=True)
            print(f"[bench] {cfg['name']} done", file=sys.stderr, flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    text = json.dumps(report, indent=1)
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")
    _record.maybe_save(args, "nlos_small" if args.small else "nlos", report, load_start=load_start,
                       peers={"mitransient": MT_VERSION if py is not None else None})
    return report


if __name__ == "__main__":
    main()
