"""Statistical helpers and small captures for the detector tests (not a test module)."""

from __future__ import annotations

import numpy as np
from scipy import stats

from transient_core.stack import new_manifest, write_stack
from transient_core.units import photons_per_pulse

#: Significance level of every statistical test in the detector suite.
ALPHA = 1e-3


def chisq_gof(observed, expected, ddof: int = 1, min_expected: float = 5.0) -> float:
    """p-value of Pearson's chi-square goodness of fit.

    Adjacent categories are pooled (in order) until each expects at least
    ``min_expected``. ``ddof=1`` when the totals are fixed (multinomial),
    0 for independent Poisson categories.
    """
    o = np.asarray(observed, float).ravel()
    e = np.asarray(expected, float).ravel()
    po, pe, acc_o, acc_e = [], [], 0.0, 0.0
    for oi, ei in zip(o, e):
        acc_o += oi
        acc_e += ei
        if acc_e >= min_expected:
            po.append(acc_o)
            pe.append(acc_e)
            acc_o = acc_e = 0.0
    if acc_e > 0 or acc_o > 0:
        if pe:
            po[-1] += acc_o
            pe[-1] += acc_e
        else:
            po.append(acc_o)
            pe.append(acc_e)
    po, pe = np.array(po), np.array(pe)
    stat = float(((po - pe) ** 2 / pe).sum())
    dof = max(len(po) - ddof, 1)
    return float(stats.chi2.sf(stat, dof))


def two_sample_chisq(a, b, min_total: float = 10.0) -> float:
    """p-value that two histograms come from the same distribution (chi-square contingency)."""
    a = np.asarray(a, float).ravel()
    b = np.asarray(b, float).ravel()
    rows_a, rows_b, acc_a, acc_b = [], [], 0.0, 0.0
    for x, y in zip(a, b):
        acc_a += x
        acc_b += y
        if acc_a + acc_b >= min_total:
            rows_a.append(acc_a)
            rows_b.append(acc_b)
            acc_a = acc_b = 0.0
    if rows_a:
        rows_a[-1] += acc_a
        rows_b[-1] += acc_b
    table = np.array([rows_a, rows_b])
    if table.shape[1] < 2:
        return 1.0
    return float(stats.chi2_contingency(table, correction=False)[1])


def variance_ratio_pvalue(sample, sigma2: float) -> float:
    """Two-sided p-value of ``(n - 1) s^2 / sigma^2 ~ chi2(n - 1)``."""
    x = np.asarray(sample, float)
    n = len(x)
    q = (n - 1) * x.var(ddof=1) / sigma2
    return float(2 * min(stats.chi2.cdf(q, n - 1), stats.chi2.sf(q, n - 1)))


def z_within(observed, expected, sigma, k: float = 3.0) -> bool:
    return abs(float(observed) - float(expected)) <= k * float(sigma)


def bonferroni_z(n_tests: int, alpha: float = 0.0027) -> float:
    """|z| threshold keeping the family-wise false-alarm rate of a 3-sigma test over ``n_tests``."""
    return float(stats.norm.isf(alpha / (2 * n_tests)))


# ------------------------------------------------------------------- captures

LASER = {"wavelength_nm": 1550.0, "repetition_rate_hz": 50e6, "average_power_w": 1e-3, "pulse_energy_j": 2e-11,
         "photons_per_pulse": photons_per_pulse(2e-11, 1550.0)}


def wall_geometry(H: int, W: int, spots, pitch: float = 0.1, capture: str = "array") -> dict:
    """Relay wall in z = 0, pixel patches on a ``pitch`` grid centred on the origin."""
    xs = (np.arange(W) - (W - 1) / 2) * pitch
    ys = (np.arange(H) - (H - 1) / 2) * pitch
    pc = [[[float(x), float(y), 0.0] for x in xs] for y in ys]
    pn = [[[0.0, 0.0, 1.0]] * W for _ in ys]
    if capture == "confocal":
        spots = [p for row in pc for p in row]
    return dict(laser_origin=[0.0, -0.5, 1.0], detector_origin=[0.0, 0.5, 1.0], spots=[list(s) for s in spots],
                spot_grid=[1, len(spots)], pixel_centers=pc, pixel_normals=pn, wall_normal=[0.0, 0.0, 1.0],
                wall_size_m=[1.0, 1.0], pixel_footprint_m=pitch, aperture_diameter_m=0.02)


def make_ideal_capture(path, data, *, bin_width_ps: float, t0_ps: float = 0.0, capture: str = "array",
                       spots=None, laser=LASER, **extra):
    """Write an ideal capture ``data[n_files, H, W, T]`` (photons per pulse) with a wall geometry."""
    data = np.asarray(data, np.float32)
    S, H, W, T = data.shape[:4]  # (a fifth axis: channels, with channels=... in extra)
    if spots is None:
        spots = [[0.05 * (j - (S - 1) / 2), 0.0, 0.0] for j in range(S)]
    geo = wall_geometry(H, W, spots, capture=capture)
    m = new_manifest(kind="ideal", capture=capture, width=W, height=H, n_files=S, t0_ps=t0_ps,
                     bin_width_ps=bin_width_ps, n_bins=T, quantity="photons_per_pulse", geometry=geo,
                     laser=laser, render={"scene_file": "synthetic.xml", "seed": 0, "spp": 1,
                                          "config_sha256": "0" * 64}, **extra)
    write_stack(path, m, data)
    return m


def poison_spot(directory, index: int, manifest: dict, value: float = float("nan")) -> None:
    """Overwrite one pixel of an ideal spot file with ``value`` (bypassing the writer's checks)."""
    import OpenEXR

    from transient_core.stack import _header, channel_names, read_spot, spot_path

    data = read_spot(directory, index, manifest)
    data[0, 0, 0] = value
    chans = {n: np.ascontiguousarray(data[:, :, b]) for b, n in enumerate(channel_names(data.shape[2]))}
    OpenEXR.File(_header(manifest, index), chans).write(str(spot_path(directory, index)))
