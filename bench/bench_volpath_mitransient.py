#!/usr/bin/env python3
"""Benchmark and cross-check: ``transient_volpath`` vs mitransient's ``transient_prbvolpath``, side by side.

One scene for both (built from the same dictionary, see :func:`scene_dict`): a camera outside a
``null``-bounded cube of homogeneous medium (sigma_t = 2 /m, albedo 0.8, Henyey-Greenstein g = 0.5)
standing on a diffuse floor, lit by a rectangular area light above; unlimited depth (Russian
roulette from depth 5 in both), box pixel filter, the same time bins (``bin_width_ps`` and ``t0_ps``
for ours; ``bin_width_opl`` and ``start_opl`` in metres for mitransient). The camera's near clip is
1e-4 m, so mitransient's time origin (the start of the camera ray, on the near-clip plane) and ours
(the centre of projection) differ by at most 0.1 mm of path (0.3 ps), far below a bin. mitransient
cannot start camera rays inside a medium (its integrator's own "TODO"), hence a medium in a shape
rather than global fog.

Each renderer runs in its own process (ours: this venv; mitransient: its own venv, as
``bench/bench_nlos.py`` makes it), with the same policy: for each of ``--spp-lo`` and ``--spp-hi``
one untimed render compiles the kernels, then ``--repeats`` renders are timed; ``--rounds`` rounds alternate the two renderers' processes (load on
a shared machine then hurts both alike) and the best time of each is kept. In the first round,
``--replicates`` independent renders at ``--spp-hi`` (seeds 1..R) give the mean and its standard error. Peak memory is
each worker's own ``VmHWM`` (the peer's process alone).

* **Cross-check (means within Monte Carlo error):** the replicate means of the two renderers are
  compared on the time-integrated image mean and on the pixel-summed time profile in groups of
  ``--group`` bins: Welch t per comparison, Bonferroni over all comparisons at a family-wise
  false-failure rate of 1e-3; the JSON holds every t and the bound.
* **Time to equal error:** per renderer, the per-sample variance ``a`` (summed over every pixel and
  bin) from the replicates; the relative RMS error of one render at ``spp`` samples is
  ``sqrt(a / spp) / ||mean||`` (both unbiased: no bias term), the render time is fitted as
  ``t0 + t1 spp`` from the two timed sample counts, and the time to reach a relative error ``eps`` is
  ``t0 + t1 a / (eps^2 ||mean||^2)``. Ours is listed first.

Usage::

    python bench/bench_volpath_mitransient.py --save      # 128x128, 400 bins of 50 ps, 32 and 128 spp
    python bench/bench_volpath_mitransient.py --small     # a quick check of the plumbing
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))
from _rss import peak_rss_mb  # noqa: E402  (standard library only: the mitransient worker imports it too)

C_M_PER_PS = 299792458.0 * 1e-12
#: relative errors at which the time to equal error is reported
EPS = (0.05, 0.02)


def scene_dict(mi, film: dict, integrator: dict) -> dict:
    """The benchmark scene (metres) with the given film and integrator dictionaries."""
    T = mi.ScalarTransform4f
    return {
        "type": "scene",
        "integrator": integrator,
        "sensor": {"type": "perspective", "fov": 40.0, "near_clip": 1e-4, "far_clip": 100.0,
                   "to_world": T().look_at(origin=[0.0, 1.2, 4.0], target=[0.0, 0.5, 0.0], up=[0, 1, 0]),
                   "sampler": {"type": "independent", "sample_count": 4}, "film": film},
        "floor": {"type": "rectangle", "to_world": T().rotate([1, 0, 0], -90.0) @ T().scale(3.0),
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.5, 0.5, 0.5]}}},
        "cube": {"type": "cube", "to_world": T().translate([0.0, 0.5, 0.0]) @ T().scale(0.5),
                 "bsdf": {"type": "null"},
                 "interior": {"type": "homogeneous", "sigma_t": 2.0, "albedo": 0.8,
                              "phase": {"type": "hg", "g": 0.5}}},
        "lamp": {"type": "rectangle",
                 "to_world": T().translate([0.0, 2.5, 0.0]) @ T().rotate([1, 0, 0], 90.0) @ T().scale(0.5),
                 "emitter": {"type": "area", "radiance": {"type": "rgb", "value": [10.0, 10.0, 10.0]}}},
    }


def worker(cfg_path: str) -> None:
    """Render in this process (``cfg['side']``: ``ours`` or ``mitransient``) and write the result JSON."""
    cfg = json.loads(Path(cfg_path).read_text())
    side, W, n_bins, bw_ps, t0_ps = cfg["side"], cfg["size"], cfg["n_bins"], cfg["bin_width_ps"], cfg["t0_ps"]
    if side == "ours":
        import transient_mi  # noqa: F401  (first: LLVM, variant, plug-ins)
        import drjit as dr
        import mitsuba as mi

        film = {"type": "transient_film", "width": W, "height": W, "n_bins": n_bins, "bin_width_ps": bw_ps,
                "t0_ps": t0_ps, "rfilter": {"type": "box"}}
        integrator = {"type": "transient_volpath", "max_depth": -1, "rr_depth": 5}
    else:
        import drjit as dr
        import mitsuba as mi

        mi.set_variant("llvm_ad_mono")
        import mitransient  # noqa: F401

        film = {"type": "transient_hdr_film", "width": W, "height": W, "temporal_bins": n_bins,
                "bin_width_opl": bw_ps * C_M_PER_PS, "start_opl": t0_ps * C_M_PER_PS, "rfilter": {"type": "box"}}
        integrator = {"type": "transient_prbvolpath", "max_depth": -1, "rr_depth": 5}
    scene = mi.load_dict(scene_dict(mi, film, integrator))

    def render(spp: int, seed: int) -> np.ndarray:
        out = mi.render(scene, spp=spp, seed=seed)
        if side != "ours":
            out = out[1]  # (steady, transient)
        dr.eval(out)
        a = np.array(out, dtype=np.float32)
        return a.reshape(W, W, n_bins, -1)[..., 0]

    timings = {}
    for spp in (cfg["spp_lo"], cfg["spp_hi"]):
        render(spp, 1000)  # compiles (a kernel may depend on the number of samples)
        ts = []
        for r in range(cfg["repeats"]):
            t = time.perf_counter()
            render(spp, 2000 + r)
            ts.append(time.perf_counter() - t)
        timings[str(spp)] = ts
    if cfg["replicates"]:
        reps = np.stack([render(cfg["spp_hi"], 1 + r) for r in range(cfg["replicates"])])
        np.save(cfg["out_npy"], reps.astype(np.float32))
    else:
        reps = np.zeros((0,))
    Path(cfg["result"]).write_text(json.dumps({"timings_s": timings, "peak_rss_mb": peak_rss_mb(),
                                               "shape": list(reps.shape)}))


def _run_side(side: str, cfg: dict, tmp: Path, python: str, env: dict) -> tuple[dict, np.ndarray | None]:
    c = dict(cfg, side=side, result=str(tmp / f"{side}.json"), out_npy=str(tmp / f"{side}.npy"))
    (tmp / f"{side}_cfg.json").write_text(json.dumps(c))
    r = subprocess.run([python, str(Path(__file__).resolve()), "--worker", str(tmp / f"{side}_cfg.json")],
                       capture_output=True, text=True, env=env)
    if r.returncode != 0:
        raise RuntimeError(f"{side} worker failed:\n{r.stderr[-4000:]}")
    reps = np.load(c["out_npy"]).astype(np.float64) if cfg["replicates"] else None
    return json.loads(Path(c["result"]).read_text()), reps


def _merge_timings(infos: list[dict]) -> dict:
    """Every round's timings together (the analysis takes the best), peak RSS the largest."""
    out = {"timings_s": {}, "peak_rss_mb": max(i["peak_rss_mb"] for i in infos)}
    for i in infos:
        for spp, ts in i["timings_s"].items():
            out["timings_s"].setdefault(spp, []).extend(ts)
    return out


def _efficiency(info: dict, reps: np.ndarray, spp_lo: int, spp_hi: int) -> dict:
    """Per-sample variance, timing fit and time to each relative error in :data:`EPS`."""
    R = reps.shape[0]
    mean = reps.mean(axis=0)
    a = float(((reps - mean) ** 2).sum(axis=0).sum() / (R - 1)) * spp_hi  # summed per-sample variance
    norm2 = float((mean ** 2).sum())
    t_lo, t_hi = min(info["timings_s"][str(spp_lo)]), min(info["timings_s"][str(spp_hi)])
    t1 = (t_hi - t_lo) / (spp_hi - spp_lo)
    t0 = max(t_lo - t1 * spp_lo, 0.0)
    return {"time_s": {str(spp_lo): t_lo, str(spp_hi): t_hi}, "seconds_per_spp": t1, "overhead_s": t0,
            "relative_rmse_at_spp_hi": math.sqrt(a / spp_hi / norm2),
            "time_to_relative_error_s": {str(e): t0 + t1 * a / (e * e * norm2) for e in EPS},
            "peak_rss_mb": round(info["peak_rss_mb"], 1)}


def _cross_check(ours: np.ndarray, mt: np.ndarray, group: int) -> dict:
    """Welch t of the replicate means: the image mean and the pixel-summed profile in groups of bins."""
    from scipy import stats

    def feats(x):
        prof = x.sum(axis=(1, 2))  # [R, T]
        T = prof.shape[1] // group * group
        return np.concatenate([x.mean(axis=(1, 2, 3))[:, None] * x.shape[3],
                               prof[:, :T].reshape(len(x), -1, group).sum(axis=2)], axis=1)

    a, b = feats(ours), feats(mt)
    ma, mb = a.mean(0), b.mean(0)
    va, vb = a.var(0, ddof=1) / len(a), b.var(0, ddof=1) / len(b)
    keep = (va + vb) > 0
    t = (ma - mb)[keep] / np.sqrt((va + vb)[keep])
    df = ((va + vb) ** 2 / (va ** 2 / (len(a) - 1) + vb ** 2 / (len(b) - 1)))[keep]
    k = int(keep.sum())
    bound = stats.t.isf(1e-3 / (2 * k), df)
    return {"comparisons": k, "family_false_failure_rate": 1e-3,
            "image_total_ours": float(ma[0]), "image_total_mitransient": float(mb[0]),
            "image_total_relative_difference": float((ma[0] - mb[0]) / mb[0]),
            "image_total_t": float(t[0]), "max_abs_t": float(np.abs(t).max()),
            "max_abs_t_over_bound": float((np.abs(t) / bound).max()),
            "agree": bool(np.all(np.abs(t) < bound))}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--bins", type=int, default=400)
    ap.add_argument("--bin-width-ps", type=float, default=50.0)
    ap.add_argument("--spp-lo", type=int, default=32)
    ap.add_argument("--spp-hi", type=int, default=128)
    ap.add_argument("--replicates", type=int, default=8)
    ap.add_argument("--repeats", type=int, default=2, help="timed renders per sample count and round")
    ap.add_argument("--rounds", type=int, default=3, help="alternating rounds of the two renderers' processes")
    ap.add_argument("--group", type=int, default=20, help="bins per group of the profile cross-check")
    ap.add_argument("--small", action="store_true")
    ap.add_argument("--mitransient", choices=("auto", "install"), default="auto")
    sys.path.insert(0, str(HERE))
    import _record

    _record.add_arguments(ap)
    a = ap.parse_args(argv)
    if a.worker:
        worker(a.worker)
        return {}
    if a.small:
        a.size, a.spp_lo, a.spp_hi, a.replicates, a.repeats, a.rounds = 16, 4, 8, 4, 1, 1
    import _peers

    py = _peers.mitransient_python(a.mitransient)
    if py is None:
        sys.exit("mitransient is not installed: run with --mitransient install")
    load_start = list(os.getloadavg())
    cfg = {"size": a.size, "n_bins": a.bins, "bin_width_ps": a.bin_width_ps, "t0_ps": 5.0 / C_M_PER_PS,
           "spp_lo": a.spp_lo, "spp_hi": a.spp_hi, "replicates": a.replicates, "repeats": a.repeats}
    ours_env, mt_env = dict(os.environ, PYTHONPATH=str(ROOT)), _peers.mt_env()
    infos = {"ours": [], "mitransient": []}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        # rounds alternate the two renderers (load on a shared machine then hurts both alike); the first
        # round also renders the replicates
        for rnd in range(a.rounds):
            c = cfg if rnd == 0 else dict(cfg, replicates=0)
            info, reps = _run_side("ours", c, tmp, sys.executable, ours_env)
            infos["ours"].append(info)
            ours = reps if rnd == 0 else ours
            info, reps = _run_side("mitransient", c, tmp, str(py), mt_env)
            infos["mitransient"].append(info)
            mt = reps if rnd == 0 else mt
    ours_info, mt_info = _merge_timings(infos["ours"]), _merge_timings(infos["mitransient"])
    eff = {"transient-mi": _efficiency(ours_info, ours, a.spp_lo, a.spp_hi),
           "mitransient": _efficiency(mt_info, mt, a.spp_lo, a.spp_hi)}
    speed = {str(e): eff["mitransient"]["time_to_relative_error_s"][str(e)] /
             eff["transient-mi"]["time_to_relative_error_s"][str(e)] for e in EPS}
    result = {
        "scene": "camera outside a null cube of homogeneous HG medium (sigma_t 2/m, albedo 0.8, g 0.5) on a "
                 "diffuse floor, area light above; unlimited depth, rr_depth 5, box filter",
        "size": a.size, "n_bins": a.bins, "bin_width_ps": a.bin_width_ps, "t0_ps": cfg["t0_ps"],
        "spp_lo": a.spp_lo, "spp_hi": a.spp_hi, "replicates": a.replicates, "rounds": a.rounds,
        "repeats": a.repeats,
        "policy": "each renderer in its own process, --rounds rounds alternating the two; per sample count one "
                  "untimed render compiles, then the best of all timed renders; peak RSS of each worker process "
                  "alone",
        "efficiency": eff, "speedup_at_equal_error": speed,
        "cross_check": _cross_check(ours, mt, a.group),
    }
    print(json.dumps(result, indent=1))
    _record.maybe_save(a, "volpath_mitransient_small" if a.small else "volpath_mitransient", result,
                       load_start=load_start, peers={"mitransient": _peers.MT_VERSION})
    return result


if __name__ == "__main__":
    main()
