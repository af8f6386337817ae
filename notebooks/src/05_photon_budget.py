# %% [markdown]
# # 5. The photon budget: how many detected photons does a reconstruction need?
#
# A SPAD counts single photons, so every NLOS measurement is a trade between time and noise. The
# **photon budget** is what a capture collects: pulses per laser spot (exposure time x the 50 MHz
# repetition rate) times the light per pulse (laser power). The photon-budget study answers "how good is
# the reconstruction for this budget, this dark-count rate and this dead time?" with one expensive
# render and many cheap detections:
#
# 1. render the ideal capture of the reference paper's scene (`scenes/paper_mannequin.xml`: a mannequin
#    0.5 m behind a 1 m wall, 16 x 16 SPAD pixels, 2 x 2 laser spots, 10 mW) once;
# 2. for every exposure x dark-count rate x dead time, detect it with the paper's SPAD + TCSPC model
#    (70 % PDE, 25 ps FWHM jitter, automatic gate, 20 MHz TCSPC) for several seeds;
# 3. reconstruct each with backprojection + the paper's filter, score it against the mannequin mesh;
# 4. measure the signal-to-noise ratio over the seeds and compare it with the shot-noise limit.
#
# `transient_mi.study.run_photon_budget_study` does all of it (also `transient-mi study photon-budget`).

# %% [setup]

# %% [markdown]
# ## Run the study
#
# `quick=True` renders with 8 ps bins and 256 samples per pixel (the paper's 1 ps bins take longer and
# change little here). Exposures span five decades per laser spot (the study's default grid), from
# 1e-7 s (5 pulses: less than one detected photon per pixel) to 1e-3 s; the paper's 10 ms lie three
# decades past the point where the error stops improving. Dark-count rates: the paper's 25 cps, a
# typical InGaAs/InP SPAD at 1550 nm (1e5 cps), and a background as strong as the signal (1e7 cps). Dead
# times: a fast SPAD (10 ns) and the microsecond hold-off of InGaAs SPADs (1000 ns).

# %%
import time

import transient_mi  # noqa: F401  (registers the plug-ins and selects the LLVM before Mitsuba runs)
from transient_mi.study import run_photon_budget_study

if SMALL:
    settings = dict(defines={"array": 8, "spp": 64}, exposures_s=(1e-7, 1e-5), dark_count_rates_cps=(25.0, 1e7),
                    dead_times_ns=(10.0,), seeds=(0, 1), voxels=(16, 16, 8))
else:
    settings = dict(exposures_s=(1e-7, 1e-6, 1e-5, 1e-4, 1e-3), dark_count_rates_cps=(25.0, 1e5, 1e7),
                    dead_times_ns=(10.0, 1000.0), seeds=(0, 1, 2), voxels=(64, 64, 32))
t0 = time.perf_counter()
study = run_photon_budget_study("paper_mannequin", OUT / "study", quick=True, seed=0, progress=False, **settings)
print(f"{len(study.rows)} detections + reconstructions in {time.perf_counter() - t0:.0f} s")
print("tables: ", sorted(p.name for p in study.tables.values()))
print("figures:", sorted(p.name for p in study.figures.values()))

# %% [markdown]
# ## Reconstruction error against detected photons
#
# The study's own figure (`error_vs_photons.png`): Chamfer distance, depth error and IoU against the
# detected counts per pixel per laser spot, mean and spread over the detection seeds, one line per
# dark-count rate and dead time.

# %%
from IPython.display import Image, display

display(Image(filename=str(study.figures["error_vs_photons"])))

# %% [markdown]
# The same data from `study.aggregate` (one entry per setting, means and standard deviations over the
# seeds): here the Chamfer distance against the *signal* counts (detected counts minus the expected
# dark counts), which puts the background rates on one axis.

# %%
agg = study.aggregate
settings_seen = sorted({(a["dark_count_rate_cps"], a["dead_time_ns"]) for a in agg})
fig, ax = plt.subplots(figsize=(7, 3.6))
for k, (dark, dead) in enumerate(settings_seen):
    sel = sorted((a for a in agg if (a["dark_count_rate_cps"], a["dead_time_ns"]) == (dark, dead)),
                 key=lambda a: a["exposure_s"])
    x = np.array([a["signal_counts_per_pixel_per_spot_mean"] for a in sel])
    y = np.array([a["chamfer_m_mean"] for a in sel]) * 100
    e = np.array([a["chamfer_m_sd"] for a in sel]) * 100
    ax.errorbar(np.maximum(x, 1e-3), y, yerr=e, marker="o", ms=4, capsize=2, color=f"C{k % 10}",
                ls="-" if dead <= 10 else "--", label=f"dark {dark:g} cps, dead time {dead:g} ns")
ax.set_xscale("log")
ax.set_xlabel("signal counts per pixel per laser spot (mean)")
ax.set_ylabel("Chamfer distance (cm)")
ax.legend(fontsize=7)
plt.show()

# %%
from IPython.display import Markdown

rows = ["| dark (cps) | dead time (ns) | exposure (s) | pulses | counts/px/spot | signal counts/px/spot | Chamfer (cm) | IoU |",
        "|---|---|---|---|---|---|---|---|"]
for a in sorted(agg, key=lambda a: (a["dark_count_rate_cps"], a["dead_time_ns"], a["exposure_s"])):
    rows.append(f"| {a['dark_count_rate_cps']:g} | {a['dead_time_ns']:g} | {a['exposure_s']:g} | {a['pulses_per_spot']} | "
                f"{a['counts_per_pixel_per_spot_mean']:.3g} | {a['signal_counts_per_pixel_per_spot_mean']:.3g} | "
                f"{100 * a['chamfer_m_mean']:.2f} +- {100 * a['chamfer_m_sd']:.2f} | {a['iou_mean']:.3f} |")
Markdown("\n".join(rows))

# %% [markdown]
# ## Signal-to-noise ratio and the shot-noise limit
#
# Over the seeds, each time bin has a mean and a variance. For counts that are Poisson the SNR is
# `sqrt(N)` (the shot-noise limit, the diagonal); the measured Fano factor `var / mean` then is 1.
# Background counts add variance without signal, so the *signal* SNR `(mean - background) / sqrt(var)`
# falls below `sqrt(N_signal)`. Per pixel (a histogram's total), dead time makes counts more regular
# than Poisson (each count blinds the detector), which the renewal model predicts.

# %%
display(Image(filename=str(study.figures["snr_vs_photons"])))
from transient_mi.study.snr import MIN_COINCIDENCES

# the Gaussian standard error of the Fano factor is trusted where two seeds are expected to count in the
# same bin at least MIN_COINCIDENCES (20) times; sparser classes rest on a handful of coincidences
bins = [b for b in study.snr_bins if b["fano_sd"] and b["coincidences"] >= MIN_COINCIDENCES]
z = [abs(b["fano"] - 1) / b["fano_sd"] for b in bins]
print(f"per-bin Fano factor within 3 standard errors of 1 (Poisson) in {sum(v <= 3 for v in z)} of {len(z)} "
      f"classes of bins (largest |z| = {max(z, default=float('nan')):.2f})")

# %% [markdown]
# ## What the reconstructions look like
#
# Front views (seen from the wall) of the filtered reconstruction along the budget, for the first
# detector setting (`reconstructions.png`):

# %%
display(Image(filename=str(study.figures["reconstructions"])))

# %% [markdown]
# ## Reading the results
#
# - The error falls steeply from ~0.1 to ~7 detected counts per pixel per laser spot, then levels off
#   at the floor that the scene, the array size and backprojection + filter allow (Chamfer ~2.2 cm at
#   these 1.6 cm voxels: the backprojection's blur, not noise). Past that point more exposure buys nothing.
# - 25 or 1e5 dark counts per second change nothing: the gate keeps the SPAD armed ~10 ns per 20 ns period.
#   At 1e7 cps most counts are background, and the same error needs about ten times more pulses; with a
#   1 us dead time the background also blinds the detector, which delays the recovery by another decade.
# - Per bin, the counts are Poisson (Fano factor 1) in every setting, so the shot-noise limit is the
#   right yardstick; what dead time changes is how many photons are counted per pulse and how regular
#   the per-pixel totals are (sub-Poisson, as the renewal model predicts), not the statistics per bin.
#
# [docs/studies.md](../docs/studies.md) has the measured tables of the command-line study.
#
# The same study from a shell, with its tables, figures and `summary.md` in one directory:
# `transient-mi study photon-budget paper_mannequin -o out/photon-budget --quick`.
