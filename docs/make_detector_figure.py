"""Draw docs/img/detector_effects.png: what each detector effect does to one pixel's histogram.

Usage::

    python docs/make_detector_figure.py [-o docs/img/detector_effects.png]

Seeded and deterministic. Each panel shows a histogram before (grey) and
after (colour) one effect of the model, in the order light meets them.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from spad_detector import (DetectorParams, coates_correction, detect, expected_counts_low_flux,  # noqa: E402
                                   gate_mean)

W_PS, T = 8.0, 750  # 6 ns window
t_ns = (np.arange(T) + 0.5) * W_PS / 1000


def scene_pixel(scale: float = 1.0) -> np.ndarray:
    """Expected photons per pulse: a wall first-bounce return and a two-part hidden object."""
    first = 5.0 * np.exp(-0.5 * ((t_ns - 0.6) / 0.012) ** 2)
    head = 0.004 * np.exp(-0.5 * ((t_ns - 3.2) / 0.03) ** 2)
    torso = 0.010 * np.exp(-0.5 * ((t_ns - 3.6) / 0.08) ** 2)
    return scale * np.where(np.abs(t_ns - 0.6) < 0.1, first, 0.0) + scale * (head + torso)


def main(argv=None) -> Path:
    ap = argparse.ArgumentParser()
    ap.add_argument("-o", "--out", default=str(Path(__file__).parent / "img" / "detector_effects.png"))
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    N = 200_000
    ideal = scene_pixel()[None, :]
    none = dict(jitter_ps=0.0, dark_count_rate_cps=0.0, dead_time_ns=0.0, tcspc_max_count_rate_hz=None)
    gate = dict(gate_open_ps=2600.0, gate_close_ps=4600.0, gate_transition_ps=120.0)

    fig, axes = plt.subplots(2, 3, figsize=(12, 6.2))
    grey = dict(color="0.6", lw=1.0)

    # 1. PDE: photons -> detectable photons (expected per pulse)
    ax = axes[0, 0]
    ax.semilogy(t_ns, ideal[0], label="photons / pulse", **grey)
    ax.semilogy(t_ns, 0.7 * ideal[0], color="C0", lw=1.2, label="x PDE 0.70")
    ax.set_ylim(1e-6, 20)
    ax.set_title("1  detection efficiency (pde)")

    # 2. gate: suppresses the first bounce (expected counts, log)
    ax = axes[0, 1]
    e0 = expected_counts_low_flux(ideal, DetectorParams(pde=0.7, **none), N, bin_width_ps=W_PS)[0]
    eg = expected_counts_low_flux(ideal, DetectorParams(pde=0.7, **none, **gate), N, bin_width_ps=W_PS)[0]
    g = gate_mean(np.arange(T + 1) * W_PS, 2600.0, 4600.0, 120.0)
    ax.semilogy(t_ns, np.maximum(e0, 1e-3), label="no gate", **grey)
    ax.semilogy(t_ns, np.maximum(eg, 1e-3), color="C1", lw=1.2, label="gated 2.6-4.6 ns")
    ax2 = ax.twinx()
    ax2.plot(t_ns, g, color="C1", ls=":", lw=1)
    ax2.set_ylim(0, 1.05)
    ax2.set_ylabel("gate efficiency", fontsize=8)
    ax.set_title("2  time gate (120 ps transitions)")

    # 3. jitter + IRF tail (zoom on the object)
    ax = axes[0, 2]
    ej = expected_counts_low_flux(ideal, DetectorParams(pde=0.7, **{**none, "jitter_ps": 25.0}, **gate), N,
                                  bin_width_ps=W_PS)[0]
    et = expected_counts_low_flux(ideal, DetectorParams(pde=0.7, **{**none, "jitter_ps": 25.0}, **gate,
                                                        irf_tail_fraction=0.2, irf_tail_ps=150.0), N,
                                  bin_width_ps=W_PS)[0]
    ax.plot(t_ns, eg, label="no jitter", **grey)
    ax.plot(t_ns, ej, color="C2", lw=1.2, label="25 ps FWHM")
    ax.plot(t_ns, et, color="C2", ls="--", lw=1.0, label="+ 20 % tail, 150 ps")
    ax.set_xlim(2.9, 4.2)
    ax.set_title("3  timing jitter / IRF")

    # 4. dark counts + ambient light: a flat floor (one noisy draw)
    ax = axes[1, 0]
    p_clean = DetectorParams(pde=0.7, **gate, dark_count_rate_cps=0.0)
    p_noisy = DetectorParams(pde=0.7, **gate, dark_count_rate_cps=25.0, ambient_rate_cps=1e7)
    c0 = detect(ideal, p_clean, N, bin_width_ps=W_PS, seed=1)[0]
    c1 = detect(ideal, p_noisy, N, bin_width_ps=W_PS, seed=1)[0]
    ax.step(t_ns, c0, where="mid", label="signal only", **grey)
    ax.step(t_ns, c1, where="mid", color="C3", lw=0.8, label="+ dark 25/s, ambient 1e7/s")
    ax.set_xlim(2.5, 4.8)
    ax.set_yscale("log")
    ax.set_ylim(0.7, 3e3)
    ax.set_title(f"4  dark counts + ambient ({N:.0e} pulses)")

    # 5. pile-up at high flux and Coates' correction (per-cycle units)
    ax = axes[1, 1]
    hi = scene_pixel(10.0)[None, :]
    p_hi = DetectorParams(pde=0.7, **gate, dark_count_rate_cps=0.0, jitter_ps=0.0)
    n5 = 200_000
    c = detect(hi, p_hi, n5, bin_width_ps=W_PS, seed=2)[0].astype(float)
    live = n5 - 2 * c.sum()
    lam = coates_correction(c, n5, blind_cycles=2)
    truth = expected_counts_low_flux(hi, p_hi, 1, bin_width_ps=W_PS)[0]
    ax.plot(t_ns, truth, label=f"true ({truth.sum():.1f} photons / pulse)", **grey)
    ax.step(t_ns, c / live, where="mid", color="C4", lw=1.0, label="counts / live cycle: early bins win")
    ax.plot(t_ns, lam, color="k", lw=0.8, ls="--", label="Coates-corrected")
    ax.set_xlim(2.9, 4.2)
    ax.set_ylabel("per pulse", fontsize=8)
    ax.set_title("5  pile-up (10x flux) and its correction")

    # 6. dead time > period: count rate saturation
    ax = axes[1, 2]
    flux = np.logspace(-3, 1.3, 30)
    p_det = 1 - np.exp(-flux)
    ax.loglog(flux, p_det, label="first photon per cycle (Coates)", **grey)
    ax.loglog(flux, p_det / (1 + 2 * p_det), color="C5", lw=1.2, label="+ TCSPC 20 MHz at 50 MHz (m = 2)")
    ax.loglog(flux, flux, color="0.8", ls=":", lw=1, label="no dead time")
    sim = []
    for f in flux[::4]:
        pix = np.zeros((16, 40))
        pix[:, 20] = f
        k = detect(pix, DetectorParams(pde=1.0, dark_count_rate_cps=0.0, jitter_ps=0.0), 4000, bin_width_ps=10.0,
                   seed=3, engine="exact").sum() / (16 * 4000)
        sim.append(k)
    ax.loglog(flux[::4], sim, "o", color="C5", ms=4, label="exact engine")
    ax.set_xlabel("detectable photons per pulse")
    ax.set_ylabel("counts per pulse")
    ax.set_title("6  dead time longer than the period")

    for ax in axes.ravel():
        ax.legend(fontsize=7, loc="best")
        ax.tick_params(labelsize=8)
    for ax in list(axes[0]) + list(axes[1, :2]):
        ax.set_xlabel("time (ns)", fontsize=8)
    fig.suptitle("SPAD + TCSPC model: what each effect does to one pixel's histogram", fontsize=11)
    fig.tight_layout()
    fig.savefig(out, dpi=80)
    plt.close(fig)
    print(out)
    return out


if __name__ == "__main__":
    main()
