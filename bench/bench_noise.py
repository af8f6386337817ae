"""Rendering noise at the paper's budget: what the demo costs at a noise target, and what each variance
reduction technique of the NLOS estimator is worth.

1. ``demo``: runs ``transient-mi demo`` (every array rendered to a noise target of 0.1 at 10 ms per spot)
   and records, per array, the pilot's ratio, the spp chosen, the ratio reached, and the render, detect and
   reconstruct times, plus the whole run's wall and CPU time.
2. ``techniques``: renders the paper scene (8x8 array, 2x2 spots, 1 ps bins) at a fixed spp with each
   technique switched off in turn -- randomised QMC (``rqmc=false``: plain Monte Carlo) and
   hidden-geometry sampling (``hidden_geometry_prob=0``: BSDF sampling alone) -- and records the noise ratio
   at the demo's budget. The variance reduction factor of a technique is ratio(off) / ratio(on) at equal spp
   (both are estimated from 8 replicates per render; the render time per sample is recorded too).

    python bench/bench_noise.py [--skip-demo] [--spp 1024]

Writes ``bench/results/noise_target.json`` (command, machine, date, versions, every run).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _machine() -> dict:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(),
            "load_average_1_5_15": list(os.getloadavg())}


def run_demo(out: Path) -> dict:
    t0 = time.perf_counter()
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    env = dict(os.environ, TRANSIENT_MI_PROGRESS="0")
    p = subprocess.run([sys.executable, "-m", "transient_mi", "demo", "-o", str(out), "--overwrite"], cwd=ROOT,
                       env=env, capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"demo failed:\n{p.stderr[-2000:]}")
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    wall = time.perf_counter() - t0
    rows = []
    metrics = json.loads((out / "metrics.json").read_text())["rows"]
    for row in metrics:
        n = int(row["array"].split("x")[0])
        ideal = json.loads((out / "captures" / f"array_{n:02d}" / "ideal" / "manifest.json").read_text())
        nt = ideal["render"]["noise_target"]
        rows.append({"array": n, "spp": row["spp"], "pilot_spp": nt["spots"][0]["pilot_spp"],
                     "pilot_ratio_worst_spot": max(s["pilot_ratio"] for s in nt["spots"]),
                     "ratio_worst_spot_render": max(s["ratio"] for s in nt["spots"]), "target_met": nt["met"],
                     "ratio_detect_bins": row["render_noise_ratio"],
                     "ratio_detect_pixel_totals": row["render_noise_ratio_pixel_totals"],
                     "render_s": row["render_s"], "detect_s": row["detect_s"], "reconstruct_s": row["reconstruct_s"],
                     "chamfer_m": row.get("chamfer_m"), "iou": row.get("iou")})
    return {"wall_s": wall, "cpu_s": (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime), "arrays": rows,
            "stderr_tail": p.stderr[-1500:]}


def run_techniques(spp: int) -> list[dict]:
    import transient_mi  # noqa: F401
    from transient_core import stack
    from spad_detector import detect_stack
    from transient_mi.experiment import PaperConfig, paper_detector, scene_file
    from transient_mi.render_capture import prepare_render, run_render

    cfg = PaperConfig(array=8, spots=2, spp=spp, estimator="monte_carlo")
    out = []
    variants = [("all on (default)", {}), ("rqmc off (plain Monte Carlo)", {"rqmc": False}),
                ("hidden-geometry sampling off (BSDF sampling only)", {"hidden_geometry_prob": 0.0})]
    with tempfile.TemporaryDirectory() as td:
        for name, opts in variants:
            job = prepare_render(scene_file(), Path(td) / f"r{len(out)}", defines=cfg.defines(), spp=spp, seed=11)
            job.integrator.nlos_options.update(opts)
            c0, t0 = time.process_time(), time.perf_counter()
            ideal = run_render(job, progress=False, log=lambda line: None)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            counts = detect_stack(ideal, Path(td) / f"c{len(out)}", paper_detector(), exposure_s=0.01, seed=0,
                                  progress=False, warn=lambda line: None)
            rn = stack.read_manifest(counts)["detector"]["resolved"]["render_noise"]
            out.append({"technique": name, "options": opts, "spp": spp, "ratio_bins": rn["ratio"],
                        "ratio_pixel_totals": rn["pixel_totals"]["ratio_pooled"], "render_wall_s": wall,
                        "render_cpu_s": cpu})
    base = out[0]
    for r in out[1:]:
        r["variance_reduction_factor_bins"] = r["ratio_bins"] / base["ratio_bins"]
        r["variance_reduction_factor_pixel_totals"] = r["ratio_pixel_totals"] / base["ratio_pixel_totals"]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--skip-demo", action="store_true")
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "noise_target.json")
    a = ap.parse_args(argv)
    import transient_mi  # first: it sets up LLVM before drjit loads
    import mitsuba as mi

    result = {"benchmark": "noise_target",
              "command": "python bench/bench_noise.py " + " ".join(argv if argv is not None else sys.argv[1:]),
              "date": datetime.now(timezone.utc).isoformat(timespec="seconds"), "machine": _machine(),
              "versions": {"transient_mi": transient_mi.__version__, "mitsuba": mi.__version__},
              "note": "timings on the machine named; load average recorded at the start and end"}
    if a.out.exists():
        sys.path.insert(0, str(ROOT / "bench"))
        import _record

        old = _record.payload(json.loads(a.out.read_text()))
        if a.skip_demo and "demo" in old:
            result["demo"] = old["demo"]
    if not a.skip_demo:
        with tempfile.TemporaryDirectory() as td:
            result["demo"] = run_demo(Path(td) / "demo")
    result["techniques"] = run_techniques(a.spp)
    result["machine"]["load_average_at_end"] = list(os.getloadavg())
    a.out.parent.mkdir(parents=True, exist_ok=True)
    sys.path.insert(0, str(ROOT / "bench"))
    import _record

    a.out.write_text(json.dumps(_record.as_record(a.out.stem, result), indent=1) + "\n")
    print(json.dumps({"demo": {k: v for k, v in result.get("demo", {}).items() if k != "stderr_tail"},
                      "techniques": result["techniques"]}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
