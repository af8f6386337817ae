"""The free-mesh fit with and without its visibility memo (``transient_mi._visibility_memo``):
stage times and whether the outputs are the same bytes.

The fit of ``bench_fit_mesh.py``'s capture and defaults (the letter, 8 x 8 pixels, 2 x 2 spots, 10 ms per spot)
runs ``--repeats`` times in each mode, alternating (off, on, off, on, ...: both modes see the same warm kernel
cache after the first run), in one process. "Off" replaces the capture model's memo context with a no-op, so
every render traces its visibility rays as before the memo. The record holds each run's stage times (alignment,
carving, the vertex stage, the fit's wall time) and a digest of ``fitted.ply``, ``carve.json``'s mesh and
``fit.json``'s metrics per run.

    python bench/bench_visibility_memo.py --save
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import os
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _record  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def _digests(out: Path) -> dict:
    carve = json.loads((out / "carve.json").read_text())
    fit = json.loads((out / "fit.json").read_text())
    h = lambda b: hashlib.sha256(b).hexdigest()[:16]  # noqa: E731
    return {"fitted_ply": h((out / "fitted.ply").read_bytes()),
            "carved_mesh": h(json.dumps([carve["vertices"], carve["faces"]]).encode()),
            "metrics": h(json.dumps(fit["metrics"], sort_keys=True).encode())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="nlos_letter")
    ap.add_argument("--width", type=int, default=8)
    ap.add_argument("--spots", type=int, default=2)
    ap.add_argument("--exposure-ms", type=float, default=10.0)
    ap.add_argument("--repeats", type=int, default=2, help="runs in each mode")
    ap.add_argument("--work", type=Path, default=ROOT / "out" / "bench_visibility_memo")
    _record.add_arguments(ap)
    a = ap.parse_args()
    load_start = list(os.getloadavg())
    import transient_mi  # noqa: F401
    from bench_fit_mesh import _capture
    from transient_mi.fit import FitSettings, fit_capture
    from transient_mi.fit.capture_model import CaptureModel
    from transient_mi.fit.mesh_fit import MeshSettings

    counts = _capture(a.work, a.scene, a.width, a.spots, 1e-3 * a.exposure_ms, 0.1)
    held = CaptureModel._held_geometry
    runs = []
    for k in range(2 * a.repeats):
        memo = k % 2 == 1
        CaptureModel._held_geometry = held if memo else (lambda self: contextlib.nullcontext())
        out = a.work / f"fit_{k}"
        t0 = time.perf_counter()
        res = fit_capture(counts, out, model="mesh", bin_width_ps=16.0, overwrite=True,
                          settings=FitSettings(iterations=40, sigma_start_ps=150.0, element_size_m=0.03),
                          mesh=MeshSettings(cell_m=0.04, stages=2, step_m=0.003, align=8), progress=False)
        wall = time.perf_counter() - t0
        row = {"memo": memo, "fit_wall_s": wall, "align_s": res["time_s"]["align"],
               "carve_s": res["time_s"].get("carve"), "optimisation_s": res["time_s"]["optimisation"],
               "digests": _digests(out)}
        runs.append(row)
        print(f"memo {'on ' if memo else 'off'}: {wall:.0f} s (align {row['align_s']:.0f} s, carve "
              f"{row['carve_s']:.0f} s, vertex stage {row['optimisation_s']:.0f} s) {row['digests']['fitted_ply']}")
    CaptureModel._held_geometry = held
    med = {}
    for memo in (False, True):
        rs = [r for r in runs if r["memo"] is memo]
        med["on" if memo else "off"] = {key: statistics.median(r[key] for r in rs) for key in
                                        ("fit_wall_s", "align_s", "carve_s", "optimisation_s")}
    same = len({json.dumps(r["digests"], sort_keys=True) for r in runs}) == 1
    result = {"scene": a.scene, "width": a.width, "spots": a.spots, "exposure_ms": a.exposure_ms,
              "repeats": a.repeats, "runs": runs, "median": med, "same_bytes": same}
    print(f"median off {med['off']['fit_wall_s']:.0f} s, on {med['on']['fit_wall_s']:.0f} s; same bytes: {same}")
    _record.maybe_save(a, f"visibility_memo_{a.scene.removeprefix('nlos_')}_{a.width}", result,
                       load_start=load_start)


if __name__ == "__main__":
    main()
