#!/usr/bin/env python3
"""The quadrature's work arrays kept between the groups of a capture, measured: the same capture rendered group by
group with the arrays kept (``integrators._work_arrays.reuse_work_arrays``, what ``transient-mi render`` does) and
allocated afresh for every group, alternating, in one process.

The capture is bench_nlos_quadrature's array configuration at its selected setting (the letter F, 32 x 32 pixels x
32 x 32 spots in 16 groups of 64, 400 bins, ``pixel_sampling=center``, 80 mm elements): the one whose speed-up
against mitransient it measures. One untimed pass compiles; then ``--repeats`` pairs of timed passes, the order
within a pair alternating. Both ways give the same bytes (``tests/test_work_arrays.py``); this times them.

    python bench/bench_work_arrays.py --save
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _record  # noqa: E402

CONFIG = "array_32x32px_32x32spots_400bins"
ELEMENT_SIZE_M = 0.08


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3, help="timed pairs (default 3)")
    _record.add_arguments(ap)
    args = ap.parse_args(argv)
    load_start = list(os.getloadavg())

    import transient_mi  # noqa: F401  (first: it points drjit at an LLVM >= 17)
    import bench_nlos_quadrature as bq
    from _nlos_scene import configs

    cfg = dict([c for c in configs(False) if c["name"] == CONFIG][0], pixel_sampling="center")
    scene = bq._scene(cfg, ELEMENT_SIZE_M, 1)
    groups = scene.sensors()[0].spot_groups(scene, 1)

    def capture(keep: bool) -> float:
        t0 = time.perf_counter()
        bq.render_whole(scene, groups, keep_work_arrays=keep)
        return time.perf_counter() - t0

    capture(True)  # (compiles; untimed)
    times = {"kept": [], "fresh": []}
    for i in range(args.repeats):
        for keep in ((True, False) if i % 2 == 0 else (False, True)):
            times["kept" if keep else "fresh"].append(round(capture(keep), 3))
            print(f"{'kept' if keep else 'fresh'}: {times['kept' if keep else 'fresh'][-1]:.2f} s", flush=True)
    med = {k: statistics.median(v) for k, v in times.items()}
    report = {"config": CONFIG, "element_size_m": ELEMENT_SIZE_M, "groups": len(groups),
              "spots_per_group": len(groups[0]), "times_s": times, "median_s": med,
              "fresh_over_kept": round(med["fresh"] / med["kept"], 3)}
    print(report)
    _record.maybe_save(args, "work_arrays", report, load_start=load_start)
    return report


if __name__ == "__main__":
    main()
