# %% [markdown]
# # 3. The detector model: what each effect does to a histogram
#
# A rendered capture holds *expected photons per laser pulse per time bin* at each pixel's aperture.
# A real SPAD with time-correlated single-photon counting (TCSPC) electronics records integer counts,
# and on the way light meets, in order: the **photon budget** (number of pulses), the **photon
# detection efficiency** (PDE), the **time gate**, **dark counts and ambient light**, **dead time and
# pile-up**, **afterpulsing**, **optical crosstalk** and **timing jitter**. `spad_detector`
# models all of them (pure numpy; see `docs/detector.md`).
#
# Part 1 applies `detect` to a hand-made histogram, one effect at a time. Part 2 runs `detect_stack` on a
# rendered NLOS capture, as `transient-mi detect` does.
#
# Units: time in ps (ns on plot axes), rates in counts per second (cps), the jitter as a FWHM in ps,
# dead times in ns. The defaults are the reference paper's detector: PDE 0.70, 25 ps FWHM jitter,
# 25 cps dark counts, 120 ps gate transitions, 20 MHz maximum TCSPC count rate, 50 MHz laser.

# %% [setup]

# %% [markdown]
# ## Part 1: one pixel
#
# The pixel's ideal histogram: 750 bins of 8 ps (a 6 ns window), with the relay wall's first-bounce
# return at 0.6 ns (19 photons per pulse) and a hidden object's light at 3.2-3.6 ns (0.29 photons per
# pulse). `detect(ideal[..., T], params, n_pulses, bin_width_ps=..., seed=...)`
# returns uint32 counts of the same shape; `expected_counts_low_flux` gives the mean counts without dead
# time, handy for showing a single effect without noise.

# %%
from spad_detector import (DetectorParams, coates_correction, detect, expected_counts_low_flux,
                                   gate_mean)

W_PS, T = 8.0, 750
t_ns = (np.arange(T) + 0.5) * W_PS / 1000


def pixel(scale=1.0):
    """Expected photons per pulse per bin: a wall return and a two-part hidden object."""
    wall = 5.0 * np.exp(-0.5 * ((t_ns - 0.6) / 0.012) ** 2) * (np.abs(t_ns - 0.6) < 0.1)
    head = 0.004 * np.exp(-0.5 * ((t_ns - 3.2) / 0.03) ** 2)
    torso = 0.010 * np.exp(-0.5 * ((t_ns - 3.6) / 0.08) ** 2)
    return scale * (wall + head + torso)


ideal = pixel()
N = 20_000 if SMALL else 200_000        # laser pulses (4 ms at 50 MHz)
# a detector with every effect switched off, to add them one at a time
NONE = dict(pde=1.0, jitter_ps=0.0, dark_count_rate_cps=0.0, dead_time_ns=0.0, tcspc_max_count_rate_hz=None,
            gate_transition_ps=120.0)
GATE = dict(gate_open_ps=2600.0, gate_close_ps=4600.0)
print(f"photons per pulse: wall return {ideal[t_ns < 1].sum():.3f}, hidden object {ideal[t_ns > 2].sum():.4f}")

# %% [markdown]
# ### Photon detection efficiency and the time gate
#
# Each photon triggers an avalanche with probability `pde` (a thinned Poisson process: the mean scales
# by 0.7). The gate arms the SPAD only between `gate_open_ps` and `gate_close_ps` (the 50 % points of
# edges with a 10-90 % time of `gate_transition_ps`): set around the hidden object's light it removes
# the wall return, which would otherwise blind the detector (below, dead time).

# %%
e_ideal = expected_counts_low_flux(ideal, DetectorParams(**NONE), N, bin_width_ps=W_PS)
e_pde = expected_counts_low_flux(ideal, DetectorParams(**{**NONE, "pde": 0.7}), N, bin_width_ps=W_PS)
e_gate = expected_counts_low_flux(ideal, DetectorParams(**{**NONE, "pde": 0.7}, **GATE), N, bin_width_ps=W_PS)
g = gate_mean(np.arange(T + 1) * W_PS, 2600.0, 4600.0, 120.0)   # bin-averaged gate efficiency

fig, (a0, a1) = plt.subplots(1, 2, figsize=(12, 3.2))
a0.semilogy(t_ns, np.maximum(e_ideal, 1e-3), color="0.6", label="photons (PDE 1)")
a0.semilogy(t_ns, np.maximum(e_pde, 1e-3), color="C0", label="PDE 0.70")
a0.semilogy(t_ns, np.maximum(e_gate, 1e-3), color="C1", label="PDE 0.70, gated 2.6-4.6 ns")
a0.set_ylim(0.1, None)
a0.set_ylabel(f"expected counts per bin ({N:.0e} pulses)")
a0.legend(fontsize=8)
a0.set_title("PDE and gate")
a1.plot(t_ns, g, color="C1")
a1.set_xlim(2.2, 5.0)
a1.axvline(2.6, color="0.7", lw=0.8)
a1.axvline(4.6, color="0.7", lw=0.8)
a1.set_ylabel("gate efficiency")
a1.set_title("the gate's edges (120 ps, 10-90 %)")
for ax in (a0, a1):
    ax.set_xlabel("time (ns)")
plt.show()

# %% [markdown]
# ### Timing jitter and the instrument response
#
# Every time stamp is the true arrival plus a random delay: a Gaussian with `jitter_ps` **FWHM** (25 ps
# FWHM = 10.6 ps standard deviation), optionally with an exponential tail (`irf_tail_fraction`,
# `irf_tail_ps`), or a measured IRF from `irf_file`. On a histogram this is a convolution: sharp
# features blur, counts are kept.

# %%
P_GATED = {**NONE, "pde": 0.7, **GATE}
e_jit = expected_counts_low_flux(ideal, DetectorParams(**{**P_GATED, "jitter_ps": 25.0}), N, bin_width_ps=W_PS)
e_slow = expected_counts_low_flux(ideal, DetectorParams(**{**P_GATED, "jitter_ps": 100.0}), N, bin_width_ps=W_PS)
e_tail = expected_counts_low_flux(ideal, DetectorParams(**{**P_GATED, "jitter_ps": 25.0, "irf_tail_fraction": 0.2,
                                                           "irf_tail_ps": 150.0}), N, bin_width_ps=W_PS)
fig, ax = plt.subplots(figsize=(8, 3))
ax.plot(t_ns, e_gate, color="0.6", label="no jitter")
ax.plot(t_ns, e_jit, color="C2", label="25 ps FWHM")
ax.plot(t_ns, e_slow, color="C4", label="100 ps FWHM")
ax.plot(t_ns, e_tail, color="C2", ls="--", label="25 ps FWHM + 20 % tail of 150 ps")
ax.set_xlim(2.9, 4.2)
ax.set_xlabel("time (ns)")
ax.set_ylabel("expected counts per bin")
ax.legend(fontsize=8)
plt.show()
print(f"total expected counts: {e_gate.sum():.1f} without jitter, {e_jit.sum():.1f} with 25 ps, "
      f"{e_tail.sum():.1f} with the tail: jitter moves counts, it does not remove them (unless it pushes "
      "them out of the window)")

# %% [markdown]
# ### Dark counts and ambient light
#
# Thermal dark counts (`dark_count_rate_cps`) and detected ambient light (`ambient_rate_cps`) are
# Poisson arrivals uniform in time while the SPAD is armed: a flat floor of
# `rate x bin_width x N x gate` counts per bin. Now with real (random) counts, one draw each:

# %%
P_REAL = {**P_GATED, "jitter_ps": 25.0}
c_clean = detect(ideal, DetectorParams(**P_REAL), N, bin_width_ps=W_PS, seed=1)
c_noisy = detect(ideal, DetectorParams(**{**P_REAL, "dark_count_rate_cps": 25.0, "ambient_rate_cps": 1e7}), N,
                 bin_width_ps=W_PS, seed=1)
floor = 1e7 * W_PS * 1e-12 * N
fig, ax = plt.subplots(figsize=(8, 3))
ax.step(t_ns, c_clean, where="mid", color="0.6", label="signal only")
ax.step(t_ns, c_noisy, where="mid", color="C3", lw=0.8, label="+ 25 cps dark counts + 1e7 cps ambient")
ax.axhline(floor, color="k", ls=":", lw=0.8, label=f"expected floor {floor:.2f} counts/bin")
ax.set_yscale("symlog", linthresh=1)
ax.set_ylim(0, None)
ax.set_xlim(2.4, 4.8)
ax.set_xlabel("time (ns)")
ax.set_ylabel("counts per bin")
ax.legend(fontsize=8)
plt.show()

# %% [markdown]
# ### Dead time, pile-up and Coates' correction
#
# After an avalanche the SPAD is dead for `dead_time_ns`, and the TCSPC needs `1 / tcspc_max_count_rate_hz`
# (50 ns at 20 MHz, i.e. longer than the 20 ns laser period) to convert a time stamp. At most one photon
# per cycle is recorded, and the earliest one wins: with a lot of light the histogram is skewed towards
# early bins (**pile-up**). Coates' estimator undoes it from the counts alone (`coates_correction`, also
# `spad_detector.coates`); with the 50 ns TCSPC dead time every count blinds the detector for two whole cycles
# (`blind_cycles=2`).

# %%
bright = pixel(10.0)            # ten times the light: 0.2 photons per pulse from the object
P_PILE = {**P_GATED, "dark_count_rate_cps": 0.0}                         # + the default dead times:
params = DetectorParams(**{**P_PILE, "dead_time_ns": 10.0, "tcspc_max_count_rate_hz": 20e6})
c = detect(bright, params, N, bin_width_ps=W_PS, seed=2).astype(float)
live = N - 2 * c.sum()          # cycles in which the detector was armed (each count blinds two)
lam = coates_correction(c, N, blind_cycles=2)
truth = expected_counts_low_flux(bright, DetectorParams(**P_PILE), 1, bin_width_ps=W_PS)
fig, ax = plt.subplots(figsize=(8, 3))
ax.plot(t_ns, truth, color="0.6", lw=2, label=f"truth ({truth.sum():.2f} detectable photons per pulse)")
ax.step(t_ns, c / live, where="mid", color="C4", label="counts per live cycle: the late part is lost")
ax.plot(t_ns, lam, color="k", ls="--", lw=0.8, label="Coates-corrected")
ax.set_xlim(2.9, 4.2)
ax.set_xlabel("time (ns)")
ax.set_ylabel("per pulse per bin")
ax.legend(fontsize=8)
plt.show()
print(f"{c.sum():.0f} counts in {N} pulses: {c.sum() / N:.3f} per pulse, for {truth.sum():.3f} detectable photons "
      f"per pulse")

# %% [markdown]
# How many counts per pulse a detector can deliver: the first-photon probability per cycle
# `1 - exp(-flux)` (Coates), and with the TCSPC's 50 ns dead time at 50 MHz two blind cycles after each
# count, `p / (1 + 2 p)`: never more than 1/3 of the pulses. The dots are the event-by-event engine.

# %%
flux = np.logspace(-3, 1.3, 30)
p_det = 1 - np.exp(-flux)
sim_flux = flux[::4]
sim = []
for f in sim_flux:
    pix = np.zeros((4 if SMALL else 16, 40))
    pix[:, 20] = f                   # all photons of a pulse in one bin
    n = 1000 if SMALL else 4000
    k = detect(pix, DetectorParams(pde=1.0, dark_count_rate_cps=0.0, jitter_ps=0.0), n, bin_width_ps=10.0,
               seed=3, engine="exact")
    sim.append(k.sum() / (pix.shape[0] * n))
fig, ax = plt.subplots(figsize=(6, 3.4))
ax.loglog(flux, flux, color="0.8", ls=":", label="no dead time")
ax.loglog(flux, p_det, color="0.5", label="first photon per cycle (Coates)")
ax.loglog(flux, p_det / (1 + 2 * p_det), color="C5", label="+ TCSPC 20 MHz at 50 MHz")
ax.loglog(sim_flux, sim, "o", color="C5", ms=5, label="exact engine")
ax.set_xlabel("detectable photons per pulse")
ax.set_ylabel("counts per pulse")
ax.legend(fontsize=8)
plt.show()

# %% [markdown]
# ### Afterpulsing
#
# A trapped carrier can release a second avalanche after the SPAD re-arms (`afterpulse_prob` per
# avalanche, delay `dead_time_ns` + an exponential of mean `afterpulse_delay_ns`). Its counts are
# correlated with the signal but land at random phases of later cycles: a background floor that grows
# with the signal. Here an ungated SPAD with 1000 cps dark counts, a TCSPC without its own dead time,
# and one pulse train of 0.16 photons per pulse.

# %%
sig = 0.01 * np.exp(-0.5 * ((t_ns - 3.4) / 0.05) ** 2)[None, :]
P_AP = dict(pde=0.7, dark_count_rate_cps=1000.0, jitter_ps=25.0, dead_time_ns=10.0, tcspc_max_count_rate_hz=None)
n_ap = 100_000 if SMALL else 1_000_000
fig, ax = plt.subplots(figsize=(8, 3))
for prob, color in ((0.0, "0.5"), (0.02, "C1"), (0.1, "C3")):
    c_ap = detect(sig, DetectorParams(afterpulse_prob=prob, **P_AP), n_ap, bin_width_ps=W_PS, seed=4)[0]
    coarse = c_ap.reshape(-1, 10).sum(axis=1)              # 80 ps bins for display
    ax.step(t_ns.reshape(-1, 10).mean(axis=1), np.maximum(coarse, 0.1), where="mid", color=color, lw=1,
            label=f"afterpulse probability {prob:g}: {c_ap[t_ns < 2.5].mean():.2f} counts per 8 ps bin before the signal")
ax.set_yscale("log")
ax.set_ylim(0.5, 1e7)
ax.set_xlabel("time (ns)")
ax.set_ylabel("counts per 80 ps")
ax.legend(fontsize=8, loc="upper left")
plt.show()

# %% [markdown]
# ### Optical crosstalk
#
# An avalanche emits photons that can trigger each of its four nearest neighbours at the same instant
# (`crosstalk_prob`). The last two axes of the `detect` input are the pixel grid. A 5 x 5 array with
# light on the centre pixel only: with 5 % crosstalk the neighbours record a copy of its histogram.

# %%
grid = np.zeros((5, 5, T))
grid[2, 2] = sig[0]
P_XT = dict(pde=0.7, dark_count_rate_cps=25.0, jitter_ps=25.0, dead_time_ns=10.0, tcspc_max_count_rate_hz=None)
c0 = detect(grid, DetectorParams(**P_XT), n_ap, bin_width_ps=W_PS, seed=5)
c5 = detect(grid, DetectorParams(crosstalk_prob=0.05, **P_XT), n_ap, bin_width_ps=W_PS, seed=5)
fig, axes = plt.subplots(1, 3, figsize=(12, 3.2), gridspec_kw={"width_ratios": [1, 1.2, 2]})
for ax, cc, name in ((axes[0], c0, "no crosstalk"), (axes[1], c5, "5 % crosstalk")):
    im = ax.imshow(np.log10(cc.sum(-1) + 1), cmap="viridis", vmin=0, vmax=np.log10(c5.sum(-1).max() + 1))
    ax.set_title(name)
    ax.set_xticks(range(5))
    ax.set_yticks(range(5))
fig.colorbar(im, ax=axes[1], shrink=0.8, label="log10(counts + 1)")
axes[2].step(t_ns, c5[2, 2] * 0.05, where="mid", color="0.6", label="centre pixel x 0.05")
axes[2].step(t_ns, c5[2, 3], where="mid", color="C0", lw=0.8, label="right neighbour")
axes[2].set_xlim(3.0, 3.8)
axes[2].set_xlabel("time (ns)")
axes[2].set_ylabel("counts per bin")
axes[2].legend(fontsize=8)
fig.tight_layout()
plt.show()
print("counts per pixel with crosstalk:\n", c5.sum(-1))

# %% [markdown]
# ## Part 2: a rendered capture
#
# The same model on a whole capture: `detect_stack(ideal_dir, out_dir, params, exposure_s=...)` reads
# the ideal capture one laser spot at a time and writes a counts capture (uint32 EXR stack, with every
# detector parameter in its manifest). We render the point-target scene as an array capture and use the
# reference paper's detector (`transient_mi.experiment.paper_detector`): its automatic gate opens for the
# three-bounce light from 25-75 cm in front of the wall and closes out the wall return, timed per
# laser spot. `laser_power_w` rescales the rendered light to another laser power.

# %%
import transient_mi  # noqa: F401  (registers the plug-ins and selects the LLVM before Mitsuba runs)
from spad_detector import detect_stack
from transient_mi.paper import paper_detector
from transient_mi.render_capture import render
from transient_mi.scenes import scene_path
from transient_core.stack import read_stack

px, spots, spp = (8, 2, 64) if SMALL else (16, 4, 512)
ideal_dir = render(scene_path("nlos_point_targets"), OUT / "ideal", spp=spp, progress=False,
                   defines={"width": str(px), "height": str(px), "pixel_footprint_m": str(0.8 / px),
                            "spots_x": str(spots), "spots_y": str(spots), "spot_spacing_m": str(0.6 / (spots - 1))})
m_ideal, ideal_data = read_stack(ideal_dir)              # [spot, y, x, time], photons per pulse per bin
tm = m_ideal["time"]
t_cap = (tm["t0_ps"] + (np.arange(tm["n_bins"]) + 0.5) * tm["bin_width_ps"]) / 1000
exposure_s = 0.01                                        # per laser spot: 5e5 pulses at 50 MHz
auto_dir = detect_stack(ideal_dir, OUT / "counts_auto_1mW", paper_detector(laser_power_w=0.001),
                        exposure_s=exposure_s, seed=0, progress=False)
m_c, c_auto = read_stack(auto_dir)
res = m_c["detector"]["resolved"]
print(f"{m_c['detector']['pulses']} pulses per spot; engines used: {sorted(set(res['engines_used']))}")
print("gate per laser spot (ns):", [f"{a / 1000:.2f}-{b / 1000:.2f}" for a, b in
                                    zip(res["gate_open_ps_per_spot"], res["gate_close_ps_per_spot"])][:4], "...")

# %% [markdown]
# Summed over pixels and spots: the expected photons (x PDE, no gate, no dead time) against the detected
# counts at 1 mW. Each spot's gate opens after that spot's own wall return (the spikes at 9-12 ns), so
# the returns are gated away while the hidden targets' light passes; before 12.7 ns only dark counts
# remain. At 1 mW the counts follow the expectation (0.02 counts per pulse per pixel: little pile-up).

# %%
pulses = m_c["detector"]["pulses"]
scale = 0.001 / m_ideal["laser"]["average_power_w"]       # the ideal capture was rendered at 100 mW
fig, ax = plt.subplots(figsize=(9, 3.2))
ax.semilogy(t_cap, np.maximum(ideal_data.sum(axis=(0, 1, 2)) * scale * 0.7 * pulses, 1e-2), color="0.6", lw=2.5,
            label="expected photons x PDE (no gate)")
ax.semilogy(t_cap, np.maximum(c_auto.sum(axis=(0, 1, 2)), 0.5), color="C3", lw=0.8, label="detected counts, 1 mW")
opens = np.array(res["gate_open_ps_per_spot"]) / 1000
ax.axvspan(opens.min(), opens.max(), color="C2", alpha=0.08, label="the spots' gates open, one after another")
ax.axvspan(opens.max(), t_cap[-1], color="C2", alpha=0.2, label="every spot's gate open")
ax.set_xlabel("time after the pulse (ns)")
ax.set_ylabel("counts per bin (all pixels and spots)")
ax.set_ylim(0.5, None)
ax.legend(fontsize=8)
plt.show()

# %% [markdown]
# At 100 mW (the scene's laser) the hidden light alone is about one photon per pulse per pixel: the
# detector saturates and pile-up bends every histogram towards its early bins. Coates' correction
# (`recon.preprocess.pileup_correction`, with the pulses and blind cycles read from the counts manifest)
# recovers the shape. It assumes that every count blinds the detector for the same number of whole
# cycles, which holds for a gate inside the recorded window; the automatic gates of the far laser spots
# stay open past the 20 ns period (the latest arrivals from 75 cm deep), so here both powers use one
# fixed gate, 12.3-17.5 ns, after every spot's wall return. One (spot, pixel) pair, each curve
# normalised to its sum:

# %%
import recon
from recon.preprocess import pileup_correction

counts = {}
for power_w in (0.001, 0.1):
    fixed_gate = paper_detector(auto_gate=False, gate_open_ps=12300.0, gate_close_ps=17500.0, laser_power_w=power_w)
    counts[power_w] = detect_stack(ideal_dir, OUT / f"counts_{power_w:g}W", fixed_gate, exposure_s=exposure_s,
                                   seed=0, progress=False)
c_lo, c_hi = read_stack(counts[0.001])[1], read_stack(counts[0.1])[1]
corrected = pileup_correction(recon.load_capture(counts[0.1])).data      # [spot, y, x, time]
j, y, x = 0, px // 2, px // 2
sel = (t_cap > 12.3)
curves = {"ideal (rendered)": ideal_data[j, y, x], "counts at 1 mW": c_lo[j, y, x],
          "counts at 100 mW": c_hi[j, y, x], "100 mW, Coates-corrected": corrected[j, y, x]}
fig, ax = plt.subplots(figsize=(9, 3.2))
for (name, h), style in zip(curves.items(), (dict(color="0.6", lw=2), dict(color="C0", lw=0.8),
                                             dict(color="C4", lw=0.8), dict(color="k", lw=0.8, ls="--"))):
    h = np.asarray(h, dtype=float) * sel
    ax.step(t_cap, h / h.sum(), where="mid", label=name, **style)
ax.set_xlim(12.3, t_cap[-1])
ax.set_xlabel("time after the pulse (ns)")
ax.set_ylabel("fraction per bin")
ax.set_title(f"spot {j}, pixel (y={y}, x={x})")
ax.legend(fontsize=8)
plt.show()
print(f"counts per pulse in this pixel: {c_lo[j, y, x].sum() / pulses:.4f} at 1 mW, "
      f"{c_hi[j, y, x].sum() / pulses:.4f} at 100 mW (100 x the light)")

# %% [markdown]
# From a shell, the same detection: `transient-mi detect out/ideal -o out/counts --auto-gate
# --exposure-s 0.01 --laser-power-w 0.001` (see `transient-mi detect --help`), or a `spad_film` in the
# scene file, which renders and detects in one go. Next: [04_reconstruction_methods](04_reconstruction_methods.ipynb).
