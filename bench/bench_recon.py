"""Benchmark of recon's reconstructions (time and peak memory), optionally side by side with y-tal.

Cases (full size; ``--small`` shrinks everything for CI):

====================  =====================================================  =============================
case                  capture -> volume                                      goal on 2 cores
====================  =====================================================  =============================
bp64                  single spot, 32x32 pixels, 1024 bins -> 64^3            <= 0.5 s, <= 0.5 GB
bp128                 same capture -> 128^3                                   <= 5 s, <= 1 GB
phasor64              same capture -> 64^3                                    <= 10 s, <= 2 GB
lct64                 confocal 64x64 pixels, 512 bins -> 64^3                 <= 0.5 s
fk64                  same confocal capture -> 64^3                           <= 1 s
bp64_confocal         same confocal capture -> 64^3                           (y-tal comparison)
====================  =====================================================  =============================

Every case runs in a fresh child process that reads the capture from the
same y-tal HDF5 file (written once with :func:`recon.io.ytal.write_ytal`), so
peak memory is per case. Both sides follow one warm/cold policy: in its own
process each first reconstructs a tiny capture of the same kind (4x4 pixels,
64 bins, written to its own HDF5 file) with the same method (imports, numba
kernels, FFT plans, worker pools: ``warmup_s``), then times up to
``--repeat`` calls on the real capture (every one is recorded in
``times_s``; ``time_s`` is the fastest), stopping early once the timed calls
exceed ``--repeat-budget-s`` (the same rule for both). Memory is
``VmHWM`` from ``/proc/self/status`` (the process's own peak resident set,
Python and libraries included; not inherited over fork + exec), reset to the
current resident set after the warm-up and read back after each call
(``peak_rss_mb`` is the largest of those; ``rss_before_mb`` is the resident
set before the first timed call).

``--with-ytal`` also runs y-tal 0.20.0 (GPL; installed on demand in its own
virtual environment, default ``~/.cache/transient-mi-bench/ytal``) on the same
HDF5 file and the same voxel centres, with
``tal.set_resources(cpu_processes=2, downscale=16)`` (y-tal's knob to process
the data in chunks and bound its memory; ``--ytal-downscale``) and an
address-space limit (``--ytal-memory-gb``, default 14) so that it fails
instead of swapping. y-tal's f-k reconstructs on its own grid (one voxel per
pixel and per time bin); recon's f-k is then run on a grid of the same shape
over the same extent, so both produce outputs of the same size. y-tal 0.20.0
has no LCT. (y-tal's ``cpu_processes`` are threads of its one process, so its
``VmHWM`` covers them.)

Prints one JSON document on stdout.
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
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _record  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
YTAL_VENV = Path.home() / ".cache" / "transient-mi-bench" / "ytal"
POINTS = [[0.1, -0.05, 0.5], [-0.2, 0.2, 0.4], [0.0, 0.0, 0.7], [0.25, 0.15, 0.6]]

GOALS = {"bp64": {"time_s": 0.5, "peak_rss_gb": 0.5}, "bp128": {"time_s": 5.0, "peak_rss_gb": 1.0},
         "phasor64": {"time_s": 10.0, "peak_rss_gb": 2.0}, "lct64": {"time_s": 0.5}, "fk64": {"time_s": 1.0}}


def sizes(small: bool) -> dict:
    if small:
        return {"pixels": 8, "bins": 128, "bin_ps": 64.0, "conf_pixels": 8, "conf_bins": 128, "conf_bin_ps": 64.0,
                "n": 16, "n_big": 24}
    return {"pixels": 32, "bins": 1024, "bin_ps": 8.0, "conf_pixels": 64, "conf_bins": 512, "conf_bin_ps": 16.0,
            "n": 64, "n_big": 128}


CASES = {
    # name: (capture, method, voxels key)
    "bp64": ("single", "bp", "n"),
    "bp128": ("single", "bp", "n_big"),
    "phasor64": ("single", "phasor", "n"),
    "lct64": ("confocal", "lct", "n"),
    "fk64": ("confocal", "fk", "n"),
    "bp64_confocal": ("confocal", "bp", "n"),
}
BOUNDS = (-0.5, 0.5, -0.5, 0.5, 0.1, 1.1)


def timed_calls(fn, repeat: int, budget_s: float) -> tuple[list[float], list[float], object]:
    """Call ``fn`` up to ``repeat`` times (stop once the calls took ``budget_s`` in total).

    Returns the times (s), the peak resident set after each call (MiB, VmHWM
    reset before the first call) and the last result. The rule is the same
    for recon and y-tal (``_ytal_runner.py`` applies it in y-tal's environment, with the same memory
    measure, ``bench/_rss.py``, and nothing else of this project).
    """
    from _record import peak_rss_mb, reset_peak_rss

    reset_peak_rss()
    times, peaks, out = [], [], None
    for _ in range(max(1, repeat)):
        out = None
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
        peaks.append(peak_rss_mb())
        if sum(times) >= budget_s:
            break
    return times, peaks, out


# ----------------------------------------------------------------------------- child (ours)


def child(case: str, h5: str, n: int | list[int], repeat: int = 1, warm_h5: str | None = None,
          budget_s: float = 60.0) -> dict:
    sys.path.insert(0, str(ROOT))
    sys.path.insert(0, str(ROOT / "bench"))

    from _record import rss_mb
    from recon import load_capture
    from recon.grid import VoxelGrid
    from recon.pipeline import reconstruct

    method = CASES[case][1]
    # warm-up: same method on the tiny capture of the same kind (numba kernels compiled or loaded, FFT plans)
    t = time.perf_counter()
    if warm_h5:
        reconstruct(load_capture(warm_h5), method, VoxelGrid.from_bounds(BOUNDS, voxels=4), filter="none")
    warm = time.perf_counter() - t
    cap = load_capture(h5)
    grid = VoxelGrid.from_bounds(BOUNDS, voxels=n)
    before = rss_mb()
    times, peaks, rec = timed_calls(lambda: reconstruct(cap, method, grid, filter="none"), repeat, budget_s)
    t = time.perf_counter()
    from recon.filters import paper_filter

    paper_filter(rec, threshold="rel:0.3")
    t_filter = time.perf_counter() - t
    return {"status": "ok", "time_s": min(times), "median_s": float(sorted(times)[len(times) // 2]),
            "times_s": times, "paper_filter_s": t_filter, "warmup_s": warm, "first_call_s": warm,
            "peak_rss_mb": max(peaks), "peak_rss_per_call_mb": peaks, "rss_before_mb": before,
            "shape_zyx": list(rec.raw.shape), "output_voxels": int(rec.raw.size),
            "argmax_m": [round(float(v), 4) for v in rec.argmax_m("raw")], "params": rec.params}


# ----------------------------------------------------------------------------- parent


def make_inputs(tmp: Path, small: bool) -> dict:
    sys.path.insert(0, str(ROOT))
    from recon.io.ytal import write_ytal
    from recon.synthetic import point_capture

    s = sizes(small)
    single = point_capture(POINTS, pixels=s["pixels"], t0_ps=0.0, n_bins=s["bins"], bin_width_ps=s["bin_ps"],
                           sigma_ps=20.0)
    conf = point_capture(POINTS, mode="confocal", pixels=s["conf_pixels"], t0_ps=0.0, n_bins=s["conf_bins"],
                         bin_width_ps=s["conf_bin_ps"], sigma_ps=20.0)
    paths = {"single": tmp / "single.h5", "confocal": tmp / "confocal.h5"}
    write_ytal(single, paths["single"])
    write_ytal(conf, paths["confocal"])
    # the warm-up captures (same kind, tiny): both sides warm up on these files
    warm = {"single": tmp / "warm_single.h5", "confocal": tmp / "warm_confocal.h5"}
    write_ytal(point_capture(POINTS[:1], pixels=4, t0_ps=0.0, n_bins=64, bin_width_ps=32.0, sigma_ps=40.0),
               warm["single"])
    write_ytal(point_capture(POINTS[:1], mode="confocal", pixels=4, t0_ps=0.0, n_bins=64, bin_width_ps=32.0,
                             sigma_ps=40.0), warm["confocal"])
    return {"paths": paths, "warm": warm, "describe": {"single": single.describe(), "confocal": conf.describe()},
            "pitch": {"single": single.pixel_pitch_m()[0], "confocal": conf.pixel_pitch_m()[0]}}


def run_ours(case: str, h5: Path, n: int | list[int], timeout: int, repeat: int, warm_h5: Path,
             budget_s: float) -> dict:
    nn = ",".join(map(str, n)) if isinstance(n, (list, tuple)) else str(n)
    cmd = [sys.executable, str(Path(__file__).resolve()), "--child", case, "--h5", str(h5), "--n", nn,
           "--repeat", str(repeat), "--warm-h5", str(warm_h5), "--repeat-budget-s", str(budget_s)]
    env = dict(os.environ, TRANSIENT_MI_PROGRESS="0", PYTHONPATH=str(ROOT))
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)
    except subprocess.TimeoutExpired:
        return {"status": "timeout", "timeout_s": timeout}
    if r.returncode != 0:
        return {"status": "failed", "stderr": r.stderr[-2000:]}
    return json.loads(r.stdout.strip().splitlines()[-1])


def ensure_ytal(venv: Path) -> Path:
    py = venv / "bin" / "python"
    if py.exists() and subprocess.run([str(py), "-c", "import tal"], capture_output=True).returncode == 0:
        return py
    print(f"[bench] creating y-tal environment {venv} (pip install y-tal==0.20.0)", file=sys.stderr)
    venv.parent.mkdir(parents=True, exist_ok=True)
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    subprocess.run([str(py), "-m", "pip", "install", "--quiet", "y-tal==0.20.0"], check=True)
    return py


def run_ytal(py: Path, case: str, h5: Path, n: int, pitch: float, bin_m: float, tmp: Path, timeout: int,
             memory_gb: float, downscale: int, warm_h5: Path, repeat: int, budget_s: float) -> dict:
    sys.path.insert(0, str(ROOT))
    from recon.grid import VoxelGrid

    grid = VoxelGrid.from_bounds(BOUNDS, voxels=n)
    lam = max(4 * pitch, 4 * bin_m)   # recon.phasor.default_wavelength_m: the same virtual wave for both
    spec = {"method": CASES[case][1], "x_m": grid.x_m.tolist(), "y_m": grid.y_m.tolist(), "z_m": grid.z_m.tolist(),
            "wavelength_m": lam, "pulse_sigma_m": lam, "cpu_processes": 2, "downscale": downscale,
            "warm_h5": str(warm_h5), "repeat": repeat, "repeat_budget_s": budget_s}
    sp = tmp / f"{case}.json"
    sp.write_text(json.dumps(spec))
    limit = int(memory_gb * 2 ** 30)

    def preexec():
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    home = tmp / "ytal-home"  # y-tal writes ~/.tal.conf on first use
    home.mkdir(exist_ok=True)
    env = dict(os.environ, HOME=str(home), OMP_NUM_THREADS="2", NUMBA_NUM_THREADS="2")
    try:
        r = subprocess.run([str(py), str(ROOT / "bench" / "_ytal_runner.py"), case, str(h5), str(sp)],
                           capture_output=True, text=True, timeout=timeout, env=env, preexec_fn=preexec)
    except subprocess.TimeoutExpired:
        return {"status": "timeout", "timeout_s": timeout}
    if r.returncode != 0:
        oom = "MemoryError" in r.stderr or "Unable to allocate" in r.stderr or r.returncode in (-9, 137)
        return {"status": "out of memory" if oom else "failed", "memory_limit_gb": memory_gb,
                "stderr": r.stderr[-1500:]}
    return json.loads(r.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--small", action="store_true", help="tiny sizes (CI)")
    ap.add_argument("--with-ytal", action="store_true", help="also run y-tal 0.20.0 (own virtual environment)")
    ap.add_argument("--ytal-venv", type=Path, default=YTAL_VENV)
    ap.add_argument("--ytal-memory-gb", type=float, default=14.0,
                    help="address-space limit of the y-tal process (GB)")
    ap.add_argument("--ytal-downscale", type=int, default=16,
                    help="y-tal's tal.set_resources(downscale=...): process the data in this many chunks")
    ap.add_argument("--cases", default=",".join(CASES), help="comma-separated subset of " + ",".join(CASES))
    ap.add_argument("--timeout", type=int, default=1800, help="seconds per case and implementation")
    ap.add_argument("--repeat", type=int, default=3,
                    help="timed calls per case and side after the warm-up (time_s is the fastest; all are recorded)")
    ap.add_argument("--repeat-budget-s", type=float, default=60.0,
                    help="stop repeating once the timed calls of a case took this long (same rule for both sides)")
    ap.add_argument("--table", type=Path, metavar="JSON",
                    help="print a Markdown table of a saved result (this script's output) and exit")
    _record.add_arguments(ap)
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--h5", help=argparse.SUPPRESS)
    ap.add_argument("--warm-h5", help=argparse.SUPPRESS)
    ap.add_argument("--n", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child:
        n = [int(v) for v in a.n.split(",")]
        print(json.dumps(child(a.child, a.h5, n[0] if len(n) == 1 else n, a.repeat, a.warm_h5,
                               a.repeat_budget_s)))
        return 0
    if a.table:
        from docgen.recon import markdown_table

        print(markdown_table(json.loads(a.table.read_text())))
        return 0
    cases = [c for c in a.cases.split(",") if c]
    bad = [c for c in cases if c not in CASES]
    if bad:
        ap.error(f"unknown case(s) {bad}; choose from {', '.join(CASES)}")
    s = sizes(a.small)
    ytal_py = ensure_ytal(a.ytal_venv) if a.with_ytal else None
    repeat = 1 if a.small else a.repeat
    import numba
    import numpy
    import scipy

    load_start = list(os.getloadavg())
    out = {"benchmark": "recon", "small": a.small, "load_average_start": load_start,
           "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "numpy": numpy.__version__,
                       "scipy": scipy.__version__, "numba": numba.__version__, "platform": platform.platform()},
           "policy": {"warm_up": "one call of the same method on a tiny capture of the same kind (4x4 pixels, "
                                 "64 bins), in the same process, before the timed calls; same for recon and y-tal",
                      "repeat": repeat, "repeat_budget_s": a.repeat_budget_s,
                      "time_s": "fastest timed call", "memory": "VmHWM of the process, reset after the warm-up"},
           "cases": []}
    ytal_version = None
    with tempfile.TemporaryDirectory(prefix="bench-recon-") as td:
        tmp = Path(td)
        inputs = make_inputs(tmp, a.small)
        out["captures"] = inputs["describe"]
        for case in cases:
            cap_name, method, nkey = CASES[case]
            n = s[nkey]
            h5, warm = inputs["paths"][cap_name], inputs["warm"][cap_name]
            row = {"case": case, "method": method, "capture": cap_name, "voxels": [n, n, n]}
            if ytal_py is not None:
                print(f"[bench] {case}: y-tal", file=sys.stderr)
                from transient_core.units import C_M_PER_PS

                bin_ps = s["bin_ps"] if cap_name == "single" else s["conf_bin_ps"]
                row["ytal"] = run_ytal(ytal_py, case, h5, n, inputs["pitch"][cap_name], bin_ps * C_M_PER_PS, tmp,
                                       a.timeout, a.ytal_memory_gb, a.ytal_downscale, warm, repeat,
                                       a.repeat_budget_s)
                ytal_version = row["ytal"].get("version", ytal_version)
                if method == "fk" and row["ytal"].get("status") == "ok":
                    # y-tal's f-k has its own grid: reconstruct ours on a grid of the same shape (x, y, z)
                    row["voxels"] = [int(v) for v in row["ytal"]["shape_xyz"]]
                    row["voxels_note"] = "recon's grid set to the shape of y-tal's f-k output (same output size)"
            print(f"[bench] {case}: ours", file=sys.stderr)
            vox = row["voxels"] if len(set(row["voxels"])) > 1 else n
            row["ours"] = run_ours(case, h5, vox, a.timeout, repeat, warm, a.repeat_budget_s)
            goal = GOALS.get(case)
            if goal and not a.small:
                row["goal"] = goal
                o = row["ours"]
                row["meets_goal"] = o.get("status") == "ok" and o["time_s"] <= goal["time_s"] and \
                    ("peak_rss_gb" not in goal or o["peak_rss_mb"] / 1024 <= goal["peak_rss_gb"])
            y, o = row.get("ytal"), row["ours"]
            if y and y.get("status") == "ok" and o.get("status") == "ok":
                row["speedup"] = y["time_s"] / o["time_s"]
                row["memory_ratio"] = y["peak_rss_mb"] / o["peak_rss_mb"]
            out["cases"].append(row)
    out["load_average_end"] = list(os.getloadavg())
    print(json.dumps(out, indent=1))
    _record.maybe_save(a, "recon_small" if a.small else "recon", out, load_start=load_start,
                       peers={"y-tal": ytal_version} if ytal_py is not None else None)
    return 0


if __name__ == "__main__":
    sys.exit(main())
