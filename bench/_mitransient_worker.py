"""Benchmark worker run inside mitransient's own virtual environment (see bench_nlos.py).

Renders the benchmark scene with mitransient's ``transient_nlos_path``
integrator and ``nlos_capture_meter`` sensor at several sample counts and
writes, for each, the transient data (``.npy``, axes ``[spot, pixel_y,
pixel_x, time]``) and a JSON line with the timings and peak memory.

Memory is this process's ``VmHWM`` (``/proc/self/status``), reset before each
run (``clear_refs``), so every run reports its own peak: ``render_rss_mb`` is
the peak up to the end of ``mi.render`` + ``dr.eval`` (mitransient's renderer
alone), ``max_rss_mb`` the peak including the one float32 numpy copy of the
result that the benchmark needs to save it. No float64 copy is made.

``save_spots`` (optional): the spots whose data are kept and saved (array captures; all are rendered).

Only numpy, mitsuba, mitransient and ``_rss.py`` (beside this file, standard
library only) are imported: this file must run with that environment's interpreter.
Usage: ``python _mitransient_worker.py CONFIG.json``.
"""

import json
import sys
import time

import numpy as np

from _rss import peak_rss_mb, reset_peak_rss  # this folder (the script's own, first on sys.path)


def main(path):
    cfg = json.load(open(path))
    import drjit as dr
    import mitsuba as mi

    mi.set_variant("llvm_ad_mono")
    import mitransient  # noqa: F401  (registers the plug-ins)
    from mitransient.nlos import focus_emitter_at_relay_wall_3dpoint

    T = mi.ScalarTransform4f
    W, H = cfg["width"], cfg["height"]
    exhaustive = cfg["capture"] == "array"

    def diffuse(a):
        return {"type": "diffuse", "reflectance": {"type": "rgb", "value": [a, a, a]}}

    film = {"type": "transient_hdr_film", "width": W, "height": H, "temporal_bins": cfg["n_bins"],
            "bin_width_opl": cfg["bin_width_opl"], "start_opl": cfg["start_opl"], "rfilter": {"type": "box"}}
    if exhaustive:
        film.update(exhaustive_scan=True, laser_scan_width=W, laser_scan_height=H)
    wall = cfg["wall"]
    relay = mi.load_dict({
        "type": "rectangle", "id": "relay_wall", "bsdf": diffuse(wall["albedo"]),
        "to_world": T().scale([wall["half_size"], wall["half_size"], 1.0]),
        "sensor": {"type": "nlos_capture_meter", "sensor_origin": cfg["detector"], "film": film,
                   "sampler": {"type": "independent", "sample_count": 1}},
    })
    laser = mi.load_dict({"type": "projector", "fov": 0.2, "irradiance": {"type": "rgb", "value": [1.0] * 3},
                          "to_world": T().look_at(origin=cfg["laser"], target=[0, 0, 0], up=[0, 1, 0])})
    scene = {"type": "scene", "relay_wall": relay, "laser": laser,
             "integrator": {"type": "transient_nlos_path", "nlos_laser_sampling": True,
                            "nlos_hidden_geometry_sampling": True,
                            "nlos_hidden_geometry_sampling_includes_relay_wall": False,
                            "temporal_filter": "box", "account_first_and_last_bounces": False,
                            "max_depth": cfg["max_depth"],
                            "capture_type": "exhaustive" if exhaustive else "confocal"}}
    for i, r in enumerate(cfg["rectangles"]):
        xf = T().translate(r["center"]) @ T().rotate([1, 0, 0], 180) @ T().scale([r["half"][0], r["half"][1], 1.0])
        scene[f"hidden_{i}"] = {"type": "rectangle", "to_world": xf, "bsdf": diffuse(r["albedo"])}
    scene = mi.load_dict(scene)
    focus_emitter_at_relay_wall_3dpoint(mi.Point3f(0.0, 0.0, 0.0), relay, laser)

    # radiant intensity of the projector along its axis (sample_direction weight = I / d^2 at d = 1 m)
    it = dr.zeros(mi.Interaction3f)
    origin = mi.Point3f(*cfg["laser"])
    it.p = origin + dr.normalize(mi.Point3f(0.0, 0.0, 0.0) - origin)
    _, w = laser.sample_direction(it, mi.Point2f(0.5, 0.5))
    intensity = float(np.array(w).ravel()[0])

    out = []
    for i, (spp, seed, save) in enumerate(cfg["runs"]):
        timings, render_rss = [], []
        ref = cfg.get("ref_last") and i == len(cfg["runs"]) - 1
        data = transient = None
        reset_peak_rss()
        for rep in range(1 if ref else 1 + cfg.get("repeats", 2)):  # first call compiles; min of the others
            data = transient = None
            t0 = time.perf_counter()
            _, transient = mi.render(scene, spp=int(spp), seed=int(seed))
            dr.eval(transient)
            render_rss.append(peak_rss_mb())
            data = np.array(transient, dtype=np.float32)
            timings.append(time.perf_counter() - t0)
        data = data[..., 0]
        if exhaustive:
            # mitransient stores [pixel_y, pixel_x, i // H, i % H, T] for laser target i, and its targets
            # are the pixel centres with x fastest (i = iy * W + ix): -> [spot (row-major), H, W, T]
            data = data.reshape(H, W, W * H, -1).transpose(2, 0, 1, 3)
        else:
            data = data[None]
        if cfg.get("save_spots") is not None:  # only these spots are kept (the rest are rendered and timed)
            data = np.ascontiguousarray(data[cfg["save_spots"]])
        if save:
            np.save(save, data)
        del transient
        out.append({"spp": spp, "seed": seed, "time_s": min(timings[1:] or timings), "first_call_s": timings[0],
                    "times_s": timings, "max_rss_mb": peak_rss_mb(), "render_rss_mb": max(render_rss),
                    "shape": list(data.shape), "sum": float(data.sum(dtype=np.float64)),
                    "projector_intensity": intensity})
        print(json.dumps(out[-1]), flush=True)
    json.dump(out, open(cfg["result"], "w"))


if __name__ == "__main__":
    main(sys.argv[1])
