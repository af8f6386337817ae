"""Small NLOS scenes and independent reference computations for the NLOS tests.

The reference functions here are written from the radiometry in
``docs/nlos.md`` in plain numpy, independently of the renderer's code.
"""

from __future__ import annotations

import math

import numpy as np

from transient_core.units import C_M_PER_PS, photons_per_pulse

WALL_ALBEDO = 0.8
LASER = np.array([-0.9, 0.05, 1.2])
DETECTOR = np.array([-0.9, -0.05, 1.2])
PULSE_ENERGY_J = 2e-9
WAVELENGTH_NM = 1550.0
APERTURE_DIAMETER_M = 0.0254


def square(center, side, albedo, *, normal_z=-1.0, id_="target"):
    """A Lambertian square (Mitsuba rectangle) of side ``side`` facing -z (the wall) by default."""
    import mitsuba as mi

    T = mi.ScalarTransform4f
    xf = T().translate([float(c) for c in center])
    if normal_z < 0:
        xf = xf @ T().rotate([1, 0, 0], 180)
    xf = xf @ T().scale([side / 2.0, side / 2.0, 1.0])
    return {"type": "rectangle", "id": id_, "to_world": xf,
            "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [albedo] * 3}}}


def nlos_scene(*, width=4, height=4, footprint=0.05, capture="array", spots=(1, 1), spacing=0.0,
               laser_target=(0.0, 0.0, 0.0), target=(0.0, 0.0, 0.0), include_first_last=True,
               include_wall_return=True, max_depth=4, n_bins=256, bin_width_ps=10.0, t0_ps=0.0,
               hidden=None, laser=LASER, detector=DETECTOR, spp=64, hidden_geometry_prob=None, pitch=None,
               integrator="transient_nlos_path", laser_extra=None):
    """Load an NLOS scene: 1 m x 1 m relay wall at z = 0 plus ``hidden`` shapes (dicts).

    ``laser_extra``: further ``pulsed_laser`` parameters (e.g. ``{"divergence_mrad": 20.0}``).
    """
    import mitsuba as mi

    integ = {"type": integrator, "max_depth": max_depth}
    if hidden_geometry_prob is not None:
        integ["hidden_geometry_prob"] = hidden_geometry_prob
    d = {
        "type": "scene",
        "integrator": integ,
        "laser": {"type": "pulsed_laser", "origin": mi.ScalarPoint3f(*laser),
                  "target": mi.ScalarPoint3f(*laser_target), "spots_x": spots[0], "spots_y": spots[1],
                  "spot_spacing_m": spacing, "pulse_energy_j": PULSE_ENERGY_J, "wavelength_nm": WAVELENGTH_NM,
                  **(laser_extra or {})},
        "sensor": {"type": "spad_array", "origin": mi.ScalarPoint3f(*detector),
                   "target": mi.ScalarPoint3f(*target), "pixel_footprint_m": footprint,
                   **({} if pitch is None else {"pixel_pitch_m": pitch}),
                   "aperture_diameter_m": APERTURE_DIAMETER_M, "capture": capture,
                   "include_first_last": include_first_last, "include_wall_return": include_wall_return,
                   "film": {"type": "transient_film", "width": width, "height": height, "n_bins": n_bins,
                            "bin_width_ps": bin_width_ps, "t0_ps": t0_ps},
                   "sampler": {"type": "independent", "sample_count": spp}},
        "relay_wall": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale([0.5, 0.5, 1.0]),
                       "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [WALL_ALBEDO] * 3}}},
    }
    for i, shape in enumerate(hidden or []):
        d[f"hidden_{i}"] = shape
    return mi.load_dict(d, optimize=False)


def render(scene, seed, spp, spot=0):
    """Histogram ``[H, W, T]`` (float64) of one spot."""
    sensor = scene.sensors()[0]
    res = scene.integrator().render_transient(scene, sensor, seed=seed, spp=spp, spot=spot)
    return res.histogram.astype(np.float64)


def n_photons() -> float:
    return photons_per_pulse(PULSE_ENERGY_J, WAVELENGTH_NM)


def patch_centers(width, height, footprint, target=(0.0, 0.0, 0.0)):
    """Patch centres ``[H, W, 3]`` on the wall z = 0 (x along world x, y along world y)."""
    t = np.asarray(target, dtype=float)
    u = (np.arange(width) - (width - 1) / 2.0) * footprint
    v = (np.arange(height) - (height - 1) / 2.0) * footprint
    vv, uu = np.meshgrid(v, u, indexing="ij")
    return np.stack([t[0] + uu, t[1] + vv, np.full_like(uu, t[2])], axis=-1)


def _gauss(n, lo, hi):
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (hi - lo) * x + 0.5 * (hi + lo), 0.5 * (hi - lo) * w


def three_bounce_reference(S, pixel_center, footprint, X0, side, target_albedo, laser=LASER,
                           detector=DETECTOR, n=8):
    """Expected three-bounce photons per pulse at one pixel (Gauss-Legendre quadrature).

    Integrates, over the pixel's wall patch (z = 0, normal +z) and a square
    target of side ``side`` centred at ``X0`` facing -z,
    ``N (rho_w/pi) cos_S / |S-X|^2 cos_X,in (rho_t/pi) cos_X,out cos_p,in / |X-p|^2
    (rho_w/pi) cos_p,out A_ap cos_ap / |p-D|^2``.
    Returns ``(photons, opl_min, opl_max)`` with the optical path lengths
    ``|S-X| + |X-p|`` over the integration domain (without first/last).
    """
    S = np.asarray(S, float)
    D = np.asarray(detector, float)
    nw = np.array([0.0, 0.0, 1.0])
    nt = np.array([0.0, 0.0, -1.0])
    a_ap = math.pi * (APERTURE_DIAMETER_M / 2) ** 2
    n_ap = -D / np.linalg.norm(D)  # the aperture faces the array target (origin)
    px, wpx = _gauss(n, pixel_center[0] - footprint / 2, pixel_center[0] + footprint / 2)
    py, wpy = _gauss(n, pixel_center[1] - footprint / 2, pixel_center[1] + footprint / 2)
    tx, wtx = _gauss(n, X0[0] - side / 2, X0[0] + side / 2)
    ty, wty = _gauss(n, X0[1] - side / 2, X0[1] + side / 2)
    P = np.stack(np.meshgrid(px, py, indexing="ij"), -1).reshape(-1, 2)
    WP = np.outer(wpx, wpy).reshape(-1)
    X = np.stack(np.meshgrid(tx, ty, indexing="ij"), -1).reshape(-1, 2)
    WX = np.outer(wtx, wty).reshape(-1)
    P3 = np.concatenate([P, np.zeros((len(P), 1))], 1)
    X3 = np.concatenate([X, np.full((len(X), 1), X0[2])], 1)
    sx = X3 - S
    dsx = np.linalg.norm(sx, axis=1)
    cos_s = (sx @ nw) / dsx
    cos_x_in = (-sx @ nt) / dsx
    E_x = n_photons() * (WALL_ALBEDO / math.pi) * cos_s * cos_x_in / dsx ** 2  # [nX]
    xp = P3[:, None, :] - X3[None, :, :]  # [nP, nX, 3]
    dxp = np.linalg.norm(xp, axis=2)
    cos_x_out = (xp @ nt) / dxp
    cos_p_in = (-xp @ nw) / dxp
    pd = D - P3
    dpd = np.linalg.norm(pd, axis=1)
    cos_p_out = (pd @ nw) / dpd
    cos_ap = (-pd @ n_ap) / dpd
    L_p = ((target_albedo / math.pi) * E_x[None, :] * cos_x_out * cos_p_in / dxp ** 2 * WX[None, :]).sum(1)
    L_p = (WALL_ALBEDO / math.pi) * L_p
    phi = (L_p * cos_p_out * a_ap * cos_ap / dpd ** 2 * WP).sum()
    # path-length range over a fine grid including the domain's corners
    g = np.linspace(-0.5, 0.5, 9)
    Pg = np.stack(np.meshgrid(pixel_center[0] + g * footprint, pixel_center[1] + g * footprint, indexing="ij"), -1)
    Xg = np.stack(np.meshgrid(X0[0] + g * side, X0[1] + g * side, indexing="ij"), -1)
    Pg = np.concatenate([Pg.reshape(-1, 2), np.zeros((81, 1))], 1)
    Xg = np.concatenate([Xg.reshape(-1, 2), np.full((81, 1), X0[2])], 1)
    opl = np.linalg.norm(Xg - S, axis=1)[None, :] + np.linalg.norm(Pg[:, None, :] - Xg[None, :, :], axis=2)
    return phi, float(opl.min()), float(opl.max())


def wall_return_reference(S, laser=LASER, detector=DETECTOR):
    """Closed-form first-bounce return (photons per pulse) of a Lambertian wall spot ``S`` (z = 0)."""
    S = np.asarray(S, float)
    D = np.asarray(detector, float)
    L = np.asarray(laser, float)
    sd = D - S
    d = np.linalg.norm(sd)
    cos_s = sd[2] / d
    n_ap = -D / np.linalg.norm(D)
    cos_ap = (-sd @ n_ap) / d
    a_ap = math.pi * (APERTURE_DIAMETER_M / 2) ** 2
    photons = n_photons() * (WALL_ALBEDO / math.pi) * cos_s * a_ap * cos_ap / d ** 2
    return photons, float(np.linalg.norm(L - S) + d)


def bin_of(opl_m, t0_ps, bin_width_ps):
    return int(math.floor((opl_m / C_M_PER_PS - t0_ps) / bin_width_ps))


def seed_stats(values):
    """Mean and standard error over the first axis (independent seeds)."""
    v = np.asarray(values, dtype=np.float64)
    return v.mean(axis=0), v.std(axis=0, ddof=1) / math.sqrt(v.shape[0])
