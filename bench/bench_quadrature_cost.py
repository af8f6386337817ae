"""How the quadrature's render time grows with elements, pixels, spots and bins (the letter, one factor at a time).

From a base capture (the letter, 4 x 4 pixels, 2 spots, 512 bins of 16 ps, 2 cm elements, 4 cells per patch
side), each factor is multiplied by 4 alone (elements by halving ``element_size_m``); the record holds
each render's time (the median of ``--repeat`` warm renders, after one warm-up) and the ratio to the
base. Linear cost would give 4.

    python bench/bench_quadrature_cost.py --save
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

ROOT = Path(__file__).resolve().parents[1]
BASE = dict(width="4", height="4", spots_x="2", spots_y="1", n_bins="512", bin_width_ps="16",
            estimator="quadrature", element_size_m="0.02", patch_cells="4")
FACTORS = {
    "base": {},
    "elements x4": {"element_size_m": "0.01"},
    "pixels x4": {"width": "8", "height": "8"},
    "spots x4": {"spots_x": "4", "spots_y": "2"},
    "bins x4": {"n_bins": "2048", "bin_width_ps": "4"},
}


def _time(defines: dict, repeat: int) -> tuple[float, dict]:
    from transient_mi.scene_io import load_scene

    s = load_scene(ROOT / "scenes" / "nlos_letter.xml", defines)
    integ, sensor = s.integrator(), s.sensors()[0]
    n = sensor.nlos_setup(s).n_spots
    integ.render_transient(s, sensor, seed=0, spp=1, spots=list(range(n)))  # warm-up (kernels compiled)
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        r = integ.render_transient(s, sensor, seed=0, spp=1, spots=list(range(n)))
        times.append(time.perf_counter() - t)
    return statistics.median(times), dict(r[0].estimator_info)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    _record.add_arguments(ap)
    a = ap.parse_args(argv)
    load_start = list(os.getloadavg())
    import transient_mi  # noqa: F401

    rows = {}
    for name, change in FACTORS.items():
        t, info = _time(dict(BASE, **change), a.repeat)
        rows[name] = {"defines": change, "time_s": t, "elements": info["elements"], "pairs": info["pairs"]}
        print(f"{name}: {t:.2f} s ({info['elements']} elements, {info['pairs']} pairs)", file=sys.stderr)
    base = rows["base"]["time_s"]
    for r in rows.values():
        r["ratio_to_base"] = r["time_s"] / base
    _record.maybe_save(a, "quadrature_cost", {"scene": "scenes/nlos_letter.xml", "base": BASE, "rows": rows,
                                              "repeat": a.repeat}, load_start=load_start)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
