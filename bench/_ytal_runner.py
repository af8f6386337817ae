"""Run one y-tal 0.20.0 reconstruction and print one JSON line (time, peak RSS).

Executed by ``bench_recon.py --with-ytal`` with the Python of y-tal's own
virtual environment; it imports y-tal (GPL) as a library and nothing of
transient-mi, so no y-tal code is copied into this project.

Usage: python _ytal_runner.py CASE CAPTURE.h5 GRID.json
"""

import json
import resource
import sys
import time


def rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def main() -> None:
    case, h5, grid_json = sys.argv[1:4]
    spec = json.loads(open(grid_json).read())
    import numpy as np
    import tal
    from tal.enums import CameraSystem, VolumeFormat

    tal.set_log_level(tal.LogLevel.WARNING)
    if spec.get("cpu_processes", 1) > 1 or spec.get("downscale"):
        tal.set_resources(cpu_processes=spec.get("cpu_processes", 1), downscale=spec.get("downscale"))
    data = tal.io.read_capture(h5)
    x, y, z = (np.asarray(spec[k], dtype=np.float32) for k in ("x_m", "y_m", "z_m"))
    V = np.stack(np.meshgrid(x, y, z, indexing="ij"), axis=-1)          # (X, Y, Z, 3)
    base = rss_mb()
    t = time.perf_counter()
    method = spec["method"]
    if method == "bp":
        vol = tal.reconstruct.bp.solve(data, volume_xyz=V, volume_format=VolumeFormat.X_Y_Z_3,
                                       camera_system=CameraSystem.DIRECT_LIGHT, progress=False)
    elif method == "phasor":
        # nt must be given explicitly in 0.20.0 (its default None is used in arithmetic)
        vol = tal.reconstruct.pf_dev.solve(data, wl_mean=spec["wavelength_m"], wl_sigma=spec["pulse_sigma_m"],
                                           volume_xyz=V, volume_format=VolumeFormat.X_Y_Z_3,
                                           camera_system=CameraSystem.DIRECT_LIGHT, progress=False,
                                           nt=data.H.shape[0])
    elif method == "fk":
        vol = tal.reconstruct.fk.solve(data)
    elif method == "lct":
        if not hasattr(tal.reconstruct, "lct"):
            print(json.dumps({"status": "unavailable", "reason": f"no LCT in y-tal {tal.__version__}"}))
            return
        vol = tal.reconstruct.lct.solve(data)
    else:
        raise SystemExit(f"unknown method {method}")
    elapsed = time.perf_counter() - t
    vol = np.abs(np.asarray(vol))
    print(json.dumps({"status": "ok", "time_s": elapsed, "peak_rss_mb": rss_mb(), "rss_before_mb": base,
                      "shape": list(vol.shape), "version": tal.__version__}))


if __name__ == "__main__":
    main()
