"""The deterministic three-bounce estimator against Monte Carlo, side by side in one run.

Two parts, both on the README's letter (``scenes/nlos_letter.xml``, 512 bins of 16 ps, the paper's
detector with ``--auto-gate``):

* **accuracy** (8 x 8 pixels, 2 spots, no wall return): a fine quadrature (``--ref-element-m``,
  ``--ref-cells``) is the reference; the quadrature at its defaults and Monte Carlo at ``--spp`` are
  rendered through ``transient-mi render``'s pipeline and detected at each exposure; the record holds each
  capture's *stated* ratio (``detect``'s render_noise: the quadrature's error estimate, Monte Carlo's
  variance) and, for the quadrature, the *actual* ratio of its difference from the reference;
* **README capture** (16 x 16 pixels, 4 x 4 spots, wall return on): render time of both and their stated
  ratios; Monte Carlo's spp for a ratio of 0.01 (``detect``'s estimate, variance ~ 1/spp, labelled
  extrapolated).

It also draws ``docs/img/quadrature.png`` from the accuracy capture: one pixel's histogram by both
estimators, with the quadrature's error estimate and Monte Carlo's standard deviation.

    python bench/bench_quadrature.py --save
    python bench/bench_quadrature.py --figure-only   # the figure alone (about 20 s)
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _record  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "nlos_letter.xml"
EXPOSURES_S = (1e-4, 1e-3, 1e-2)
ACCURACY = dict(include_wall_return="false", width="8", height="8", spots_x="2", spots_y="1")
README = {}


def _render(out: Path, defines: dict, spp: int = 0) -> tuple[Path, float]:
    from transient_mi.render_capture import render

    t = time.perf_counter()
    d = render(SCENE, out, defines=defines, spp=spp, seed=1, progress=False)
    return d, time.perf_counter() - t


def _ratios(capture: Path, work: Path) -> dict:
    """``detect``'s stated render_noise ratio at each exposure."""
    from spad_detector import DetectorParams, detect_stack

    out = {}
    for e in EXPOSURES_S:
        o = detect_stack(capture, work / f"counts_{e:g}", DetectorParams(auto_gate=True), exposure_s=e, seed=1,
                         progress=False, warn=lambda *_: None)
        rn = json.loads((o / "manifest.json").read_text())["detector"]["resolved"]["render_noise"]
        out[f"{e * 1e3:g}ms"] = {"ratio": rn["ratio"], "spp_for_threshold": rn.get("spp_for_threshold")}
        shutil.rmtree(o)
    return out


def _actual(capture: Path, reference: Path, work: Path) -> dict:
    """The ratio ``detect`` states when the error files hold |capture - reference| (the actual error)."""
    from transient_core import stack

    dst = work / "actual"
    shutil.copytree(capture, dst)
    m = stack.read_manifest(dst)
    mr = stack.read_manifest(reference)
    for j in range(m["n_files"]):
        e = np.abs(stack.read_spot(dst, j, m).astype(np.float64) - stack.read_spot(reference, j, mr))
        stack.write_variance(dst, j, e, e.sum(axis=2), m)
    r = _ratios(dst, work)
    shutil.rmtree(dst)
    return r


def _figure(q: Path, mc: Path, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from transient_core import stack

    mq, mm = stack.read_manifest(q), stack.read_manifest(mc)
    hq = stack.read_spot(q, 0, mq).astype(np.float64)
    hm = stack.read_spot(mc, 0, mm).astype(np.float64)
    bq = stack.read_variance(q, 0, mq)[0].astype(np.float64)
    sm = np.sqrt(stack.read_variance(mc, 0, mm)[0].astype(np.float64))
    y, x = np.unravel_index(np.argmax(hq.sum(axis=2)), hq.shape[:2])
    t = mq["time"]["t0_ps"] + mq["time"]["bin_width_ps"] * (np.arange(mq["time"]["n_bins"]) + 0.5)
    lit = np.flatnonzero(hq[y, x] > 1e-4 * hq[y, x].max())
    sl = slice(max(0, lit[0] - 5), lit[-1] + 6)
    fig, (a, b) = plt.subplots(2, 1, figsize=(7, 5.2), sharex=True, gridspec_kw={"height_ratios": [2, 1]})
    a.plot(t[sl] / 1e3, hm[y, x, sl], color="0.6", lw=1, label=f"Monte Carlo, {mm['render']['spp']} spp")
    a.plot(t[sl] / 1e3, hq[y, x, sl], color="C0", lw=1.2, label="quadrature (defaults)")
    a.set_ylabel("photons per pulse per bin")
    a.set_title(f"Letter (8 x 8 pixels, wall return off), pixel ({x}, {y}), spot 0: three-bounce light")
    a.legend(frameon=False)
    b.plot(t[sl] / 1e3, sm[y, x, sl], color="0.6", lw=1, label="Monte Carlo standard deviation")
    b.plot(t[sl] / 1e3, bq[y, x, sl], color="C0", lw=1.2, label="quadrature error estimate")
    b.set_yscale("log")
    b.set_xlabel("arrival time (ns)")
    b.set_ylabel("per bin")
    b.legend(frameon=False, fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=4096, help="Monte Carlo samples per pixel (default 4096)")
    ap.add_argument("--ref-element-m", type=float, default=0.004, help="reference quadrature element (m)")
    ap.add_argument("--ref-cells", type=int, default=12,
                    help="reference quadrature cells per patch side (default 12: twice the letter's 6, so the "
                         "capture's own cell error shows)")
    ap.add_argument("--figure", type=Path, default=ROOT / "docs" / "img" / "quadrature.png")
    ap.add_argument("--figure-only", action="store_true",
                    help="only render the accuracy capture by both estimators and draw the figure (no record)")
    _record.add_arguments(ap)
    a = ap.parse_args(argv)
    load_start = list(os.getloadavg())
    import transient_mi  # noqa: F401

    if a.figure_only:
        with tempfile.TemporaryDirectory() as tmp:
            q, _ = _render(Path(tmp) / "q", dict(ACCURACY, estimator="quadrature"))
            mc, _ = _render(Path(tmp) / "mc", dict(ACCURACY, estimator="monte_carlo"), a.spp)
            _figure(q, mc, a.figure)
        return 0

    result = {"scene": "scenes/nlos_letter.xml", "exposures_ms": [e * 1e3 for e in EXPOSURES_S],
              "detector": "paper's defaults, --auto-gate", "spp_mc": a.spp}
    with tempfile.TemporaryDirectory() as tmp:
        w = Path(tmp)
        # ---- accuracy
        ref, t_ref = _render(w / "ref", dict(ACCURACY, estimator="quadrature", element_size_m=str(a.ref_element_m),
                                             patch_cells=str(a.ref_cells)))
        q, t_q = _render(w / "q", dict(ACCURACY, estimator="quadrature"))
        mc, t_mc = _render(w / "mc", dict(ACCURACY, estimator="monte_carlo"), a.spp)
        result["accuracy"] = {
            "config": "8 x 8 pixels, 2 spots, wall return off",
            "reference": {"element_size_m": a.ref_element_m, "patch_cells": a.ref_cells, "time_s": t_ref},
            "quadrature": {"time_s": t_q, "stated": _ratios(q, w), "actual": _actual(q, ref, w)},
            "monte_carlo": {"time_s": t_mc, "stated": _ratios(mc, w)},
        }
        print(json.dumps(result["accuracy"], indent=1), file=sys.stderr)
        # ---- the README's capture
        q2, t_q2 = _render(w / "q2", dict(README, estimator="quadrature"))
        mc2, t_mc2 = _render(w / "mc2", dict(README, estimator="monte_carlo"), a.spp)
        mc_r = _ratios(mc2, w)
        result["readme_capture"] = {
            "config": "16 x 16 pixels, 4 x 4 spots, wall return on (the scene's defaults)",
            "quadrature": {"time_s": t_q2, "stated": _ratios(q2, w)},
            "monte_carlo": {"time_s": t_mc2, "stated": mc_r,
                            "spp_for_0.01_at_10ms_extrapolated": _spp_for(mc_r["10ms"]["ratio"], a.spp, 0.01),
                            "time_for_0.01_at_10ms_extrapolated_s":
                                t_mc2 * _spp_for(mc_r["10ms"]["ratio"], a.spp, 0.01) / a.spp},
        }
        print(json.dumps(result["readme_capture"], indent=1), file=sys.stderr)
        _figure(q, mc, a.figure)
    _record.maybe_save(a, "quadrature", result, load_start=load_start)
    return 0


def _spp_for(ratio: float, spp: int, target: float) -> int:
    """Samples per pixel for ``ratio`` (measured at ``spp``) to reach ``target`` (variance ~ 1/spp)."""
    return int(np.ceil(spp * ratio / target)) if ratio > target else spp


if __name__ == "__main__":
    raise SystemExit(main())
