#!/usr/bin/env python3
"""Benchmark: ``transient-mi demo`` end to end (wall time, peak memory, the demo's own step timings and metrics).

Runs the demo command line in a fresh child process (``python -m transient_mi
demo -o TMP``; ``--quick`` adds ``--quick``), ``--repeats`` times, and prints
one JSON object: per run the wall time of the whole command (Python start-up
included), the child's peak resident set (``VmHWM``), and from the demo's
``metrics.json`` the render / detect / reconstruct time of every array size
and the metrics table (Chamfer distance etc.; the same for every run: seeded).
``figures_and_rest_s`` is the wall time minus the per-array steps.

    python bench/bench_demo.py                 # the full demo (4x4 .. 32x32)
    python bench/bench_demo.py --quick         # demo --quick
    python bench/bench_demo.py --small         # CI: demo --quick --arrays 4
    python bench/bench_demo.py --exposure-ms 1000 --save   # demo --exposure-ms 1000 -> bench/results/demo_e1000ms.json
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _record  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def one_run(args: list[str], work: Path, i: int) -> dict:
    out = work / f"demo_{i}"
    log = work / f"demo_{i}.log"
    env = dict(os.environ, TRANSIENT_MI_PROGRESS="0")
    r = _record.run_measured(["transient_mi", "demo", *args, "-o", str(out)], cwd=ROOT, env=env, log=log)
    run = {"wall_s": round(r["wall_s"], 2), "status": "ok" if r["returncode"] == 0 else "failed"}
    if r["returncode"] != 0:
        return dict(run, output=log.read_text()[-2000:])
    run["peak_rss_mb"] = round(r["peak_rss_mb"], 1)
    rows = json.loads((out / "metrics.json").read_text())["rows"]
    steps = {k: round(sum(row[f"{k}_s"] for row in rows), 2) for k in ("render", "detect", "reconstruct")}
    run["step_sums_s"] = steps
    run["figures_and_rest_s"] = round(r["wall_s"] - sum(steps.values()), 2)
    run["rows"] = rows
    return run


def markdown_metrics(result: dict) -> str:
    """The demo's metrics table (first successful run; the demo is seeded, every run gives the same)."""
    sys.path.insert(0, str(ROOT))
    from transient_mi.demo import metrics_table_markdown

    run = next(r for r in result["runs"] if r["status"] == "ok")
    return metrics_table_markdown(run["rows"])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="time `demo --quick`")
    ap.add_argument("--small", action="store_true", help="CI: `demo --quick --arrays 4`, one run")
    ap.add_argument("--repeats", type=int, default=1, help="runs of the command (each in a fresh process)")
    ap.add_argument("--exposure-ms", type=float, default=None,
                    help="demo --exposure-ms (default: the demo's 10 ms); the record is demo_e<ms>ms")
    ap.add_argument("--arrays", default=None, help="demo --arrays (default: the demo's 4,8,16,32)")
    ap.add_argument("--noise-target", default=None,
                    help="demo --noise-target (default: the demo's auto); the record is <name>_nt<R>")
    _record.add_arguments(ap)
    a = ap.parse_args(argv)
    load_start = list(os.getloadavg())
    args = ["--quick", "--arrays", "4"] if a.small else (["--quick"] if a.quick else [])
    if a.exposure_ms is not None:
        args += ["--exposure-ms", f"{a.exposure_ms:g}"]
    if a.arrays is not None and not a.small:
        args += ["--arrays", a.arrays]
    if a.noise_target is not None:
        args += ["--noise-target", a.noise_target]
    with tempfile.TemporaryDirectory(prefix="bench-demo-") as td:
        runs = [one_run(args, Path(td), i) for i in range(1 if a.small else max(1, a.repeats))]
    ok = [r for r in runs if r["status"] == "ok"]
    result = {"benchmark": "demo", "small": a.small, "quick": a.quick or a.small, "exposure_ms": a.exposure_ms,
              "noise_target": a.noise_target or "auto",
              "command": "transient-mi demo " + " ".join(args + ["-o", "OUT"]), "cpu_count": os.cpu_count(),
              "runs": runs}
    if ok:
        best = min(ok, key=lambda r: r["wall_s"])
        result["fastest"] = {k: best[k] for k in ("wall_s", "peak_rss_mb", "step_sums_s", "figures_and_rest_s")}
    print(json.dumps(result, indent=1))
    name = "demo_small" if a.small else ("demo_quick" if a.quick else "demo")
    if a.exposure_ms is not None:
        name += f"_e{a.exposure_ms:g}ms"
    if a.arrays is not None and not a.small:
        name += "_a" + a.arrays.replace(",", "-")
    if a.noise_target is not None:
        name += f"_nt{a.noise_target}"
    _record.maybe_save(a, name, result, load_start=load_start)
    return 0 if len(ok) == len(runs) else 1


if __name__ == "__main__":
    sys.exit(main())
