"""Run one y-tal 0.20.0 reconstruction and print one JSON line (times, peak memory).

Executed by ``bench_recon.py --with-ytal`` with the Python of y-tal's own
virtual environment; it imports y-tal (GPL) as a library and nothing of
transient-mi (only ``_rss.py`` beside it, standard library), so no y-tal code is copied into this project.

The warm/cold policy is bench_recon's, for both sides: one warm-up call of
the same method on the tiny capture ``spec["warm_h5"]`` (4^3 voxels where the
method takes a volume), then up to ``spec["repeat"]`` timed calls on the real
capture, stopping once they took ``spec["repeat_budget_s"]`` in total. Memory
is ``VmHWM`` of this process, reset after the warm-up (``clear_refs``).

Usage: python _ytal_runner.py CASE CAPTURE.h5 GRID.json
"""

import json
import sys
import time

from _rss import peak_rss_mb, reset_peak_rss, rss_mb  # this folder (the script's own, first on sys.path)


def main() -> None:
    case, h5, grid_json = sys.argv[1:4]
    spec = json.loads(open(grid_json).read())
    import numpy as np
    import tal
    from tal.enums import CameraSystem, VolumeFormat

    tal.set_log_level(tal.LogLevel.WARNING)
    if spec.get("cpu_processes", 1) > 1 or spec.get("downscale"):
        tal.set_resources(cpu_processes=spec.get("cpu_processes", 1), downscale=spec.get("downscale"))
    method = spec["method"]
    if method == "lct" and not hasattr(tal.reconstruct, "lct"):
        print(json.dumps({"status": "unavailable", "reason": f"no LCT in y-tal {tal.__version__}",
                          "version": tal.__version__}))
        return

    def volume(x, y, z):
        x, y, z = (np.asarray(v, dtype=np.float32) for v in (x, y, z))
        return np.stack(np.meshgrid(x, y, z, indexing="ij"), axis=-1)          # (X, Y, Z, 3)

    def run(data, V):
        if method == "bp":
            return tal.reconstruct.bp.solve(data, volume_xyz=V, volume_format=VolumeFormat.X_Y_Z_3,
                                            camera_system=CameraSystem.DIRECT_LIGHT, progress=False)
        if method == "phasor":
            # nt must be given explicitly in 0.20.0 (its default None is used in arithmetic)
            return tal.reconstruct.pf_dev.solve(data, wl_mean=spec["wavelength_m"], wl_sigma=spec["pulse_sigma_m"],
                                                volume_xyz=V, volume_format=VolumeFormat.X_Y_Z_3,
                                                camera_system=CameraSystem.DIRECT_LIGHT, progress=False,
                                                nt=data.H.shape[0])
        if method == "fk":
            return tal.reconstruct.fk.solve(data)
        if method == "lct":
            return tal.reconstruct.lct.solve(data)
        raise SystemExit(f"unknown method {method}")

    def lin4(v):
        return np.linspace(min(v), max(v), 4)

    t = time.perf_counter()
    run(tal.io.read_capture(spec["warm_h5"]), volume(lin4(spec["x_m"]), lin4(spec["y_m"]), lin4(spec["z_m"])))
    warm = time.perf_counter() - t
    data = tal.io.read_capture(h5)
    V = volume(spec["x_m"], spec["y_m"], spec["z_m"])
    before = rss_mb()
    reset_peak_rss()
    times, peaks, vol = [], [], None
    for _ in range(max(1, int(spec.get("repeat", 1)))):
        vol = None
        t = time.perf_counter()
        vol = run(data, V)
        times.append(time.perf_counter() - t)
        peaks.append(peak_rss_mb())
        if sum(times) >= float(spec.get("repeat_budget_s", 0.0)):
            break
    shape = list(np.shape(vol))
    out = {"status": "ok", "time_s": min(times), "median_s": float(sorted(times)[len(times) // 2]),
           "times_s": times, "warmup_s": warm, "peak_rss_mb": max(peaks), "peak_rss_per_call_mb": peaks,
           "rss_before_mb": before, "shape": shape, "output_voxels": int(np.prod(shape[:3])),
           "version": tal.__version__}
    if method == "fk":
        out["shape_xyz"] = shape[:3][::-1]  # y-tal 0.20.0's f-k returns (z = time bins, y, x)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
