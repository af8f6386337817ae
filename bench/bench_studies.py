"""Wall-clock time and peak memory of ``transient-mi study photon-budget`` and ``study array-size``.

Cases (each runs the command line in a fresh child process, so the peak
resident set is per case):

================  ==========================================================================
case              command
================  ==========================================================================
photon_quick      ``study photon-budget --quick`` (default grid: 5 exposures x 3 dark-count
                  rates x 2 dead times x 3 seeds = 90 detections, 16x16 array, 8 ps bins)
array_quick       ``study array-size --quick`` (4x4 .. 64x64, 8 ps bins, 256 spp)
photon_default    ``study photon-budget`` (1 ps bins, 1024 spp; with ``--full``)
array_default     ``study array-size`` (1 ps bins, 1024 spp; with ``--full``)
================  ==========================================================================

``--small`` runs both studies on tiny settings (CI: checks that the script
works, not how fast). Per case: ``wall_s`` (the whole command, Python start-up
included), ``peak_rss_mb`` and the study's own per-step sums from
``timings.json``. Prints one JSON document on stdout.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _record  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

SMALL = {
    "photon_small": ["photon-budget", "-D", "array=4", "-D", "spp=16", "--exposures-ms", "1e-3",
                     "--dark-count-rates-cps", "25", "--dead-times-ns", "10", "--seeds", "2", "--voxels", "16",
                     "--quick"],
    "array_small": ["array-size", "--arrays", "4", "-D", "spp=16", "--exposure-ms", "1", "--voxels", "16", "--quick"],
}
QUICK = {"photon_quick": ["photon-budget", "--quick"], "array_quick": ["array-size", "--quick"]}
FULL = {"photon_default": ["photon-budget"], "array_default": ["array-size"]}


def run_case(name: str, args: list[str], work: Path) -> dict:
    out = work / name
    env = dict(os.environ, TRANSIENT_MI_PROGRESS="0")
    log = work / f"{name}.log"
    # the study's own process: wall time and its VmHWM (not ru_maxrss, which carries our peak over fork + exec)
    r = _record.run_measured(["transient_mi", "study", *args, "-o", str(out)], cwd=ROOT, env=env, log=log)
    case = {"case": name, "command": "transient-mi study " + " ".join(args) + " -o OUT", "status": "ok",
            "wall_s": round(r["wall_s"], 2)}
    if r["returncode"] != 0:
        return dict(case, status="failed", output=log.read_text()[-2000:])
    case["peak_rss_mb"] = round(r["peak_rss_mb"], 1)
    t = json.loads((out / "timings.json").read_text())
    rows = t["rows"]
    sums = {k: round(sum(x[k] for x in rows), 2) for k in rows[0] if k.endswith("_s") and k != "exposure_s"}
    case.update(runs=len(rows), study_total_s=round(t["total_s"], 2), step_sums_s=sums)
    if "render_s" in t:
        case["render_s"] = round(t["render_s"], 2)
    if "array" in rows[0]:
        case["per_array"] = [{k: (round(v, 2) if isinstance(v, float) else v) for k, v in x.items()} for x in rows]
    return case


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--small", action="store_true", help="tiny settings (CI)")
    ap.add_argument("--full", action="store_true", help="also the default (non-quick) studies (minutes)")
    ap.add_argument("--keep", type=Path, default=None, help="write the study outputs here (default: a temp dir)")
    _record.add_arguments(ap)
    a = ap.parse_args(argv)
    load_start = list(os.getloadavg())
    cases = dict(SMALL) if a.small else dict(QUICK, **(FULL if a.full else {}))
    with tempfile.TemporaryDirectory(prefix="bench-studies-") as td:
        work = a.keep or Path(td)
        work.mkdir(parents=True, exist_ok=True)
        results = [run_case(n, args, work) for n, args in cases.items()]
    result = {"benchmark": "studies", "small": a.small, "cpu_count": os.cpu_count(),
              "load_avg_1min": round(os.getloadavg()[0], 2), "python": platform.python_version(),
              "cases": results}
    print(json.dumps(result, indent=1))
    _record.maybe_save(a, "studies_small" if a.small else "studies", result, load_start=load_start)
    return 0 if all(c["status"] == "ok" for c in results) else 1


if __name__ == "__main__":
    sys.exit(main())
