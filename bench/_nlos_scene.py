"""The scene and configurations of the NLOS benchmark (``bench_nlos.py``): the letter F behind a 1 m x 1 m wall.

A 1 m x 1 m Lambertian relay wall, the letter F of three coplanar rectangles 0.5 m in front of it, laser and
detector 1.5 m away; three-bounce light, first/last segments and the wall's direct return excluded. Both
renderers render it from these definitions (transient-mi from :func:`ours_scene_dict` or
:func:`ours_scene_xml`, mitransient in ``_mitransient_worker.py`` from the same configuration).
"""

from __future__ import annotations

import math

import numpy as np


C_M_PER_PS = 299792458.0 * 1e-12

WALL = {"half_size": 0.5, "albedo": 0.8}
LASER = [-0.9, 0.05, 0.45]
DETECTOR = [-0.9, -0.05, 0.45]
LETTER_Z = 0.5
LETTER_SIZE = 0.4
RECTANGLES = [  # the letter F (as scenes/nlos_letter.xml), non-overlapping: centre, half sizes, albedo; facing -z
    {"center": [-0.22 * LETTER_SIZE, 0.0, LETTER_Z], "half": [0.08 * LETTER_SIZE, 0.5 * LETTER_SIZE], "albedo": 0.8},
    {"center": [0.08 * LETTER_SIZE, 0.42 * LETTER_SIZE, LETTER_Z], "half": [0.22 * LETTER_SIZE, 0.08 * LETTER_SIZE],
     "albedo": 0.8},
    {"center": [0.0, 0.02 * LETTER_SIZE, LETTER_Z], "half": [0.14 * LETTER_SIZE, 0.07 * LETTER_SIZE], "albedo": 0.8},
]
PULSE_ENERGY_J = 2e-9
WAVELENGTH_NM = 1550.0
APERTURE_DIAMETER_M = 0.0254
START_OPL = 0.6
#: Relative RMSE levels at which times to equal error are reported.
EPS = (0.2, 0.1, 0.05)  # metres of path (first/last segments excluded): three-bounce light spans ~0.9 to ~2.5 m


def configs(small: bool) -> list[dict]:
    if small:
        return [
            dict(name="confocal_8x8_64bins", capture="confocal", size=8, n_bins=64, spp=[4, 16], spp_ref=128,
                 mt_spp=[4, 16], mt_spp_ref=128, repeats=1),
            dict(name="array_4x4px_4x4spots_64bins", capture="array", size=4, n_bins=64, spp=[4, 16], spp_ref=64,
                 mt_spp=[4, 16], mt_spp_ref=64, pipeline_spots=[2, 4], repeats=1),
        ]
    return [
        dict(name="confocal_32x32_400bins", capture="confocal", size=32, n_bins=400, spp=[64, 256, 1024, 4096],
             spp_ref=65536, mt_spp=[64, 256, 1024, 4096, 16384], mt_spp_ref=131072),
        dict(name="confocal_64x64_2048bins", capture="confocal", size=64, n_bins=2048, spp=[16, 64, 256, 1024],
             spp_ref=8192, mt_spp=[16, 64, 256], mt_spp_ref=4096),
        dict(name="array_32x32px_32x32spots_400bins", capture="array", size=32, n_bins=400, spp=[16, 64, 256],
             spp_ref=2048, mt_spp=[4, 16, 64], mt_spp_ref=512, pipeline_spots=[8, 16, 32]),
    ]


def time_axis(cfg) -> tuple[float, float]:
    """(bin_width_opl_m, start_opl_m): 400 bins of 5 mm, 2048 bins of 1 mm."""
    span = 2.0 if cfg["n_bins"] >= 400 else 3.2
    return span / cfg["n_bins"], START_OPL


# ------------------------------------------------------------------ our side


def ours_scene_dict(cfg):
    import mitsuba as mi

    T = mi.ScalarTransform4f
    W = cfg["size"]
    bw, start = time_axis(cfg)
    fp = 2 * WALL["half_size"] / W

    def diffuse(a):
        return {"type": "diffuse", "reflectance": {"type": "rgb", "value": [a] * 3}}

    d = {
        "type": "scene",
        "integrator": {"type": "transient_nlos_path", "max_depth": 4,
                       "hidden_geometry_prob": cfg.get("hidden_geometry_prob", 0.8)},
        "laser": {"type": "pulsed_laser", "origin": mi.ScalarPoint3f(*LASER), "target": mi.ScalarPoint3f(0, 0, 0),
                  "spots_x": W if cfg["capture"] == "array" else 1, "spots_y": W if cfg["capture"] == "array" else 1,
                  "spot_spacing_m": fp, "pulse_energy_j": PULSE_ENERGY_J, "wavelength_nm": WAVELENGTH_NM},
        "sensor": {"type": "spad_array", "origin": mi.ScalarPoint3f(*DETECTOR), "target": mi.ScalarPoint3f(0, 0, 0),
                   "pixel_footprint_m": fp, "aperture_diameter_m": APERTURE_DIAMETER_M, "capture": cfg["capture"],
                   "include_first_last": False, "include_wall_return": False,
                   "pixel_sampling": cfg.get("pixel_sampling", "area"),
                   "film": {"type": "transient_film", "width": W, "height": W, "n_bins": cfg["n_bins"],
                            "bin_width_ps": bw / C_M_PER_PS, "t0_ps": start / C_M_PER_PS}},
        "relay_wall": {"type": "rectangle", "to_world": T().scale([WALL["half_size"], WALL["half_size"], 1.0]),
                       "bsdf": diffuse(WALL["albedo"])},
    }
    for i, r in enumerate(RECTANGLES):
        xf = T().translate(r["center"]) @ T().rotate([1, 0, 0], 180) @ T().scale([r["half"][0], r["half"][1], 1.0])
        d[f"hidden_{i}"] = {"type": "rectangle", "to_world": xf, "bsdf": diffuse(r["albedo"])}
    return d


def ours_scene_xml(cfg, n_spots_side: int) -> str:
    """The same scene as XML (for the pipeline run), with an n x n laser scan grid."""
    W = cfg["size"]
    bw, start = time_axis(cfg)
    fp = 2 * WALL["half_size"] / W
    rects = []
    for i, r in enumerate(RECTANGLES):
        rects.append(f"""  <shape type="rectangle" id="hidden_{i}"><transform name="to_world">
    <scale x="{r['half'][0]}" y="{r['half'][1]}"/><rotate x="1" angle="180"/>
    <translate x="{r['center'][0]}" y="{r['center'][1]}" z="{r['center'][2]}"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="{r['albedo']}"/></bsdf></shape>""")
    return f"""<scene version="3.0.0">
  <default name="spp" value="4"/>
  <integrator type="transient_nlos_path"><integer name="max_depth" value="4"/></integrator>
  <emitter type="pulsed_laser"><point name="origin" value="{', '.join(map(str, LASER))}"/>
    <point name="target" value="0, 0, 0"/><integer name="spots_x" value="{n_spots_side}"/>
    <integer name="spots_y" value="{n_spots_side}"/><float name="spot_spacing_m" value="{fp}"/>
    <float name="pulse_energy_j" value="{PULSE_ENERGY_J}"/><float name="wavelength_nm" value="{WAVELENGTH_NM}"/>
  </emitter>
  <sensor type="spad_array"><point name="origin" value="{', '.join(map(str, DETECTOR))}"/>
    <point name="target" value="0, 0, 0"/><float name="pixel_footprint_m" value="{fp}"/>
    <float name="aperture_diameter_m" value="{APERTURE_DIAMETER_M}"/><string name="capture" value="array"/>
    <boolean name="include_first_last" value="false"/><boolean name="include_wall_return" value="false"/>
    <film type="transient_film"><integer name="width" value="{W}"/><integer name="height" value="{W}"/>
      <integer name="n_bins" value="{cfg['n_bins']}"/><float name="bin_width_ps" value="{bw / C_M_PER_PS}"/>
      <float name="t0_ps" value="{start / C_M_PER_PS}"/></film>
    <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
  </sensor>
  <shape type="rectangle" id="relay_wall"><transform name="to_world"><scale x="0.5" y="0.5"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="{WALL['albedo']}"/></bsdf></shape>
{chr(10).join(rects)}
</scene>
"""


# ------------------------------------------------------------------ both sides


def mean_agreement(cfg, ours, mt, spots, mt_has_spots_only: bool = False) -> dict:
    """Compare transient-mi's and mitransient's references after dividing out the known geometric factors.

    ``ours``: transient-mi's capture ``[spot, H, W, T]`` (photons per pulse; array captures: the ``spots``
    only); ``mt``: mitransient's ``[spot, H, W, T]`` (array captures: every spot, indexed by ``spots``, or
    with ``mt_has_spots_only`` those spots alone).
    Per (spot, pixel) totals: ours divided by the pixel's solid-angle and aperture factor, mitransient's
    multiplied by ``N d^2 / cos`` of the spot; the fitted ratio of the two is ``1 / I`` (the projector's
    axial intensity) when both renderers compute the same light.
    """
    W = cfg["size"]
    fp = 2 * WALL["half_size"] / W
    o = np.asarray(ours, dtype=np.float64)  # [s, H, W, T]
    m = mt
    if cfg["capture"] == "array" and not mt_has_spots_only:
        m = m[spots]
    m = np.asarray(m, dtype=np.float64)
    u = (np.arange(W) - (W - 1) / 2) * fp
    P = np.stack(np.meshgrid(u, u, indexing="xy"), -1)  # [H, W, 2]: x = u[ix], y = u[iy]
    P = np.concatenate([P, np.zeros(P.shape[:2] + (1,))], -1)
    D = np.array(DETECTOR)
    L = np.array(LASER)
    pd = D - P
    dpd = np.linalg.norm(pd, axis=-1)
    n_ap = -D / np.linalg.norm(D)
    a_ap = math.pi * (APERTURE_DIAMETER_M / 2) ** 2
    g_pix = fp * fp * (pd[..., 2] / dpd) * a_ap * ((-pd / dpd[..., None]) @ n_ap) / dpd ** 2  # [H, W]
    h, c = 6.62607015e-34, 299792458.0
    N = PULSE_ENERGY_J / (h * c / (WAVELENGTH_NM * 1e-9))
    if cfg["capture"] == "confocal":
        S = P  # spot of pixel k = its patch centre
        ls = L - S
        g_spot = N * np.linalg.norm(ls, axis=-1) ** 2 / (ls[..., 2] / np.linalg.norm(ls, axis=-1))  # [H, W]
        g_spot = g_spot[None]
    else:
        Sj = P.reshape(-1, 3)[spots]
        ls = L - Sj
        dls = np.linalg.norm(ls, axis=-1)
        g_spot = (N * dls ** 2 / (ls[:, 2] / dls))[:, None, None]
    o_tot = o.sum(-1) / g_pix[None]  # ours -> radiance per unit projector intensity
    m_tot = m.sum(-1) * g_spot
    mask = (o_tot > 0) & (m_tot > 0)
    scale = float((o_tot[mask] * m_tot[mask]).sum() / (m_tot[mask] ** 2).sum())
    resid = float(np.sqrt(((o_tot - scale * m_tot)[mask] ** 2).mean()) / np.sqrt((o_tot[mask] ** 2).mean()))
    t = np.arange(o.shape[-1]) + 0.5
    with np.errstate(invalid="ignore", divide="ignore"):
        mo = (o * t).sum(-1) / o.sum(-1)
        mm = (m * t).sum(-1) / m.sum(-1)
    dt = (mo - mm)[mask]
    return {"scale_ours_over_mitransient": scale,
            "expected_scale": None,
            "note": "totals per (spot, pixel) divided by the pixel's solid-angle factor (ours) and multiplied by "
                    "N d^2 / cos of the spot (mitransient)",
            "rel_rms_residual_of_totals": resid,
            "mean_arrival_bin_difference": {"mean": float(dt.mean()), "rms": float(np.sqrt((dt ** 2).mean()))},
            "compared_values": int(mask.sum())}
