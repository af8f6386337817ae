"""What the per-bin variance estimate costs: render time and disk, with 8 replicates against 1.

Renders the embedded paper scene (default 16 x 16 array, 2 x 2 spots, 1 ps bins, 11500 bins) with the
integrator's ``variance_replicates`` = 8 (what ``transient-mi render`` uses for NLOS captures) and = 1 (no variance), alternating, ``--rounds``
times each, in one process (both warm: one untimed render of each first compiles the kernels), and
writes both captures to disk to compare their sizes.

    python bench/bench_render_variance.py [--array 16] [--spp 1024] [--rounds 3]

Writes ``bench/results/render_variance_cost.json`` (every repeat, wall and process CPU time).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _dir_bytes(d: Path) -> int:
    return sum(p.stat().st_size for p in d.rglob("*") if p.is_file())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--array", type=int, default=16)
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "render_variance_cost.json")
    a = ap.parse_args(argv)

    import transient_mi  # first: it sets up LLVM before drjit loads
    import mitsuba as mi
    from transient_core import stack
    from transient_mi.experiment import PaperConfig, scene_file
    from transient_mi.render_capture import prepare_render, run_render

    cfg = PaperConfig(array=a.array, spp=a.spp, estimator="monte_carlo")
    runs = {8: [], 1: []}
    sizes = {}
    with tempfile.TemporaryDirectory() as td:
        jobs = {}
        for R in (8, 1):
            job = prepare_render(scene_file(), Path(td) / f"r{R}", defines=cfg.defines(), spp=a.spp, seed=0)
            job.integrator.variance_replicates = R
            job.manifest["variance"]["directory"] = stack.VARIANCE_DIR if R > 1 else None
            jobs[R] = job
        sensor = jobs[8].sensor
        groups = sensor.spot_groups(jobs[8].scene, a.spp)
        for R in (8, 1):  # warm-up: compile the kernels of both
            jobs[R].integrator.render_transient(jobs[R].scene, jobs[R].sensor, seed=0, spp=a.spp, spots=groups[0])
        for i in range(a.rounds):
            for R in (8, 1):
                job = jobs[R]
                c0, t0 = time.process_time(), time.perf_counter()
                for g in groups:
                    job.integrator.render_transient(job.scene, job.sensor, seed=i + 1, spp=a.spp, spots=g)
                runs[R].append({"wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0})
        for R in (8, 1):
            job = prepare_render(scene_file(), Path(td) / f"disk{R}", defines=cfg.defines(), spp=a.spp, seed=0)
            job.integrator.variance_replicates = R
            job.manifest["variance"] = dict(job.manifest["variance"], replicates=R,
                                            directory=stack.VARIANCE_DIR if R > 1 else None)
            run_render(job, progress=False, log=lambda line: None)
            sizes[R] = _dir_bytes(Path(td) / f"disk{R}")

    def med(xs, k):
        v = sorted(x[k] for x in xs)
        return v[len(v) // 2]

    result = {
        "benchmark": "render_variance_cost",
        "command": "python bench/bench_render_variance.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "machine": {"cpu": platform.processor() or platform.machine(), "cores": os.cpu_count(),
                    "python": platform.python_version(), "load_average_at_end": os.getloadavg()},
        "versions": {"transient_mi": transient_mi.__version__, "mitsuba": mi.__version__},
        "scene": f"paper_mannequin array={a.array} spots=2 spp={a.spp} 11500 x 1 ps bins",
        "policy": "same process, both warm (one untimed render of each first), alternating rounds",
        "runs": {"replicates_8": runs[8], "replicates_1": runs[1]},
        "median_wall_s": {"replicates_8": med(runs[8], "wall_s"), "replicates_1": med(runs[1], "wall_s")},
        "median_cpu_s": {"replicates_8": med(runs[8], "cpu_s"), "replicates_1": med(runs[1], "cpu_s")},
        "time_overhead_cpu": med(runs[8], "cpu_s") / med(runs[1], "cpu_s") - 1.0,
        "disk_bytes": {"replicates_8": sizes[8], "replicates_1": sizes[1]},
        "disk_ratio": sizes[8] / sizes[1],
    }
    a.out.parent.mkdir(parents=True, exist_ok=True)
    sys.path.insert(0, str(ROOT / "bench"))
    import _record

    a.out.write_text(json.dumps(_record.as_record(a.out.stem, result), indent=1) + "\n")
    print(json.dumps({k: result[k] for k in ("median_wall_s", "median_cpu_s", "time_overhead_cpu", "disk_ratio")},
                     indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
