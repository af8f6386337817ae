# %% [markdown]
# # 2. An NLOS capture: laser, relay wall, SPAD array, hidden targets
#
# In a non-line-of-sight (NLOS) experiment a pulsed laser lights a spot on a visible *relay wall*;
# light scatters from the wall into the hidden space, off the hidden objects and back onto the wall,
# where a SPAD array focused on wall patches records its time of arrival. transient-mi renders the
# **ideal capture**: the expected number of photons reaching each pixel's aperture **per laser pulse,
# per time bin**. (The detector model that turns this into counts is notebook 3.)
#
# Scene: `scenes/nlos_point_targets.xml`, three Lambertian disks (radius 3 cm, albedo 0.8) 0.4 to
# 0.7 m behind a 1 m x 1 m wall (albedo 0.8) in the plane z = 0; laser and SPAD array 1.5 m from the
# wall, off to the side. Laser: 1550 nm, 50 MHz, 100 mW average power. Two capture modes:
#
# - **confocal**: pixel k recorded with the laser on pixel k's own wall patch (one file);
# - **array**: every pixel recorded for every laser spot (one file per spot).

# %% [setup]

# %% [markdown]
# ## Render a confocal and an array capture
#
# The scene's parameters are set like `-D name=value`. Both captures record 9 ns to 17.2 ns after the
# pulse leaves the laser (bins of 16 ps = 4.8 mm of path), and include the first and last segments
# (laser to wall, wall to detector) in the recorded time.

# %%
import transient_mi  # noqa: F401  (registers the plug-ins and selects the LLVM before Mitsuba runs)
from transient_mi.render_capture import render
from transient_mi.scenes import scene_path

targets = np.array([[0.2, 0.15, 0.4], [-0.15, -0.1, 0.55], [0.05, -0.25, 0.7]])  # disk centres, m
common = {f"target{i + 1}": ", ".join(map(str, p)) for i, p in enumerate(targets)}
if SMALL:
    common.update(n_bins="128", bin_width_ps="64")
    conf_px, conf_spp, arr_px, arr_spots, arr_spp = 8, 64, 8, 2, 64
else:
    common.update(n_bins="512", bin_width_ps="16")
    conf_px, conf_spp, arr_px, arr_spots, arr_spp = 32, 4096, 16, 4, 1024

# the pixels tile 0.8 m of the wall (a 1 m array would put a patch behind a target, seen from the detector)
confocal = render(scene_path("nlos_point_targets"), OUT / "confocal", spp=conf_spp, progress=False,
                  defines=dict(common, capture="confocal", width=str(conf_px), height=str(conf_px),
                               pixel_footprint_m=str(0.8 / conf_px)))
array = render(scene_path("nlos_point_targets"), OUT / "array", spp=arr_spp, progress=False,
               defines=dict(common, capture="array", width=str(arr_px), height=str(arr_px),
                            pixel_footprint_m=str(0.8 / arr_px), spots_x=str(arr_spots), spots_y=str(arr_spots),
                            spot_spacing_m="0.2"))
print("confocal:", sorted(p.name for p in confocal.iterdir()))
print("array:   ", len(list(array.glob("spot_*.exr"))), "spot files")

# %% [markdown]
# ## The geometry, from the manifest
#
# Everything a reconstruction needs is in `manifest.json`: laser and detector positions, the laser
# spots `S_j` (scan order row-major) and the wall patch centres `P_k` the pixels see.

# %%
from transient_core.stack import read_manifest, read_spot

mc, ma = read_manifest(confocal), read_manifest(array)
g = ma["geometry"]
laser, detector = np.array(g["laser_origin"]), np.array(g["detector_origin"])
P_arr = np.array(g["pixel_centers"])             # [H, W, 3]
S_arr = np.array(g["spots"])                      # [n_spots, 3]

fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(10, 3.8))
ax0.plot([-0.5, 0.5], [0, 0], "k", lw=3, label="relay wall (z = 0)")
ax0.plot(*laser[[0, 2]], "r*", ms=12, label="laser")
ax0.plot(*detector[[0, 2]], "bs", ms=8, label="SPAD array")
ax0.plot(targets[:, 0], targets[:, 2], "o", color="C2", ms=8, label="hidden disks")
for s in S_arr[:1]:
    ax0.plot([laser[0], s[0]], [laser[2], s[2]], "r:", lw=0.8)
ax0.set_xlabel("x (m)")
ax0.set_ylabel("z (m), depth in front of the wall")
ax0.set_title("top view")
ax0.set_aspect("equal")
ax0.legend(fontsize=7, loc="upper right")
ax1.plot(P_arr[..., 0].ravel(), P_arr[..., 1].ravel(), "s", ms=3, color="0.6", label="pixel patch centres P_k")
ax1.plot(S_arr[:, 0], S_arr[:, 1], "r*", ms=9, label="laser spots S_j (array capture)")
ax1.plot(targets[:, 0], targets[:, 1], "o", color="C2", ms=8, label="disks (behind)")
for i, p in enumerate(targets):
    ax1.annotate(f"{p[2]:.2f} m", p[:2] + 0.02, fontsize=8, color="C2")
ax1.set_xlim(-0.5, 0.5)
ax1.set_ylim(-0.5, 0.5)
ax1.set_aspect("equal")
ax1.set_xlabel("x (m)")
ax1.set_ylabel("y (m)")
ax1.set_title("the wall, seen from the hidden side")
ax1.legend(fontsize=7, loc="lower left")
plt.show()

# %% [markdown]
# ## Radiometry: what a bin holds
#
# Photons per pulse `N = E_pulse / (h c / lambda)`: 2 nJ at 1550 nm is 1.56e10 photons. The wall's
# own first-bounce return (the laser spot seen directly) reaches the pixel whose patch contains the
# spot `S` in closed form,
#
# `N (rho / pi) cos(theta_S) A_ap cos(theta_ap) / |S - D|^2`  photons per pulse,
#
# at path length `|L - S| + |S - D|` (Lambertian wall of albedo rho, aperture area `A_ap`). We check that
# against one pixel of the confocal capture.

# %%
from transient_core.units import C_M_PER_PS, photons_per_pulse

laser_info = mc["laser"]
N = photons_per_pulse(laser_info["pulse_energy_j"], laser_info["wavelength_nm"])
print(f"{laser_info['average_power_w'] * 1e3:g} mW at {laser_info['repetition_rate_hz'] / 1e6:g} MHz: "
      f"{laser_info['pulse_energy_j'] * 1e9:g} nJ per pulse = {N:.4g} photons per pulse (manifest: "
      f"{laser_info['photons_per_pulse']:.4g})")

gc, tc = mc["geometry"], mc["time"]
t0_ps, w_ps, n_bins = tc["t0_ps"], tc["bin_width_ps"], tc["n_bins"]
t_ns = (t0_ps + (np.arange(n_bins) + 0.5) * w_ps) / 1000.0
conf = read_spot(confocal, 0, mc)                    # [pixel_y, pixel_x, time]: photons per pulse per bin
P = np.array(gc["pixel_centers"])                    # confocal: laser spot k = patch centre k
ky, kx = conf_px // 2, conf_px // 4                  # some pixel
S = P[ky, kx]
to_D = detector - S
dist = np.linalg.norm(to_D)
cos_S = to_D[2] / dist                               # wall normal is +z
a_n = np.array(gc["aperture_normal"])
cos_ap = float(np.dot(-to_D / dist, a_n))
A_ap = np.pi * (gc["aperture_diameter_m"] / 2) ** 2
expected = N * (0.8 / np.pi) * cos_S * A_ap * cos_ap / dist ** 2
t_return_ps = (np.linalg.norm(S - laser) + dist) / C_M_PER_PS
b = int((t_return_ps - t0_ps) // w_ps)
print(f"pixel (y={ky}, x={kx}): wall return expected {expected:.5g} photons/pulse in bin {b} "
      f"({t_return_ps / 1000:.3f} ns); rendered {conf[ky, kx, b]:.5g}")
hidden = conf[ky, kx, b + 2:].sum()
print(f"three-bounce light from the hidden disks in that pixel: {hidden:.3g} photons/pulse, "
      f"{hidden / expected:.1e} of the wall return")
rate = laser_info["repetition_rate_hz"]
print(f"at {rate / 1e6:g} MHz and 70 % detection efficiency: {0.7 * rate * hidden:.3g} hidden-light and "
      f"{0.7 * rate * expected:.3g} wall-return photons per second would trigger this pixel")

# %% [markdown]
# The wall return is about a million times brighter than the light from the hidden objects, and
# both arrive far faster than a SPAD can count (a SPAD records at most one photon per dead time; the
# reference paper's TCSPC electronics at most 20 million per second). That is why real NLOS SPADs are
# time-gated to miss the wall return, and why the laser power, the pulses and the detector's pile-up
# decide what is measured: notebooks 3 and 5.
#
# ## Histograms per pixel
#
# Three pixels of the confocal capture (log scale). Dashed lines: the arrival time of each disk's
# centre, `(|L - P| + 2 |P - o| + |P - D|) / c` for a confocal pixel at `P` and a disk at `o`. The
# disks have a radius of 3 cm, so their light starts a little earlier and spreads over a few bins.

# %%
def arrival_ns(S, P, o):
    """Three-bounce arrival (ns): laser -> S -> o -> P -> detector."""
    L = (np.linalg.norm(S - laser, axis=-1) + np.linalg.norm(o - S, axis=-1)
         + np.linalg.norm(P - o, axis=-1) + np.linalg.norm(detector - P, axis=-1))
    return L / C_M_PER_PS / 1000.0


pixels = [(conf_px // 2, conf_px // 4), (int(conf_px * 0.7), int(conf_px * 0.75)), (conf_px // 4, conf_px // 2)]
fig, axes = plt.subplots(1, 3, figsize=(13, 3), sharey=True)
for ax, (py, px) in zip(axes, pixels):
    Pk = P[py, px]
    ax.step(t_ns, np.maximum(conf[py, px], 1e-12), where="mid", lw=0.8)
    for i, o in enumerate(targets):
        ax.axvline(arrival_ns(Pk, Pk, o), color=f"C{i + 1}", ls="--", lw=1, label=f"disk at z = {o[2]} m")
    ax.set_yscale("log")
    ax.set_ylim(1e-9, None)
    ax.set_title(f"pixel (y={py}, x={px}), P = ({Pk[0]:.2f}, {Pk[1]:.2f}) m")
    ax.set_xlabel("time after the pulse (ns)")
axes[0].set_ylabel(f"photons per pulse per {w_ps:g} ps bin")
axes[0].legend(fontsize=7)
plt.show()

# %% [markdown]
# ## Streak images
#
# The middle pixel row against time. Left: the whole capture, where the wall return (one bright bin per
# pixel) dominates the colour scale; right: the same without the wall return, on a log scale, with each
# disk's predicted arrival curve across the row drawn just before it (0.1 ns early, so that the data
# stay visible). The curves are skewed because the laser and the detector stand off to the left: the
# first and last segments are shorter for pixels on the left. These curves are what reconstruction
# algorithms invert.

# %%
# mask out each pixel's wall return: keep bins 300 ps after |L - P| + |P - D| (its shortest path)
t_ps = t0_ps + (np.arange(n_bins) + 0.5) * w_ps
t_return_conf = (np.linalg.norm(P - laser, axis=-1) + np.linalg.norm(detector - P, axis=-1)) / C_M_PER_PS
conf_hidden = np.where(t_ps > t_return_conf[..., None] + 300, conf, 0)   # [H, W, T]

row = conf_px // 2
Prow = P[row]                                           # [W, 3]
extent = [t_ns[0] - w_ps / 2000, t_ns[-1] + w_ps / 2000, conf_px - 0.5, -0.5]
fig, (a0, a1) = plt.subplots(1, 2, figsize=(12, 3.4))
a0.imshow(conf[row], aspect="auto", extent=extent, cmap="inferno")
a0.set_title("confocal row, linear scale: the wall return")
from matplotlib.colors import LogNorm

vmax = conf_hidden[row].max()
a1.imshow(np.maximum(conf_hidden[row], vmax * 1e-4), aspect="auto", extent=extent, cmap="inferno",
          norm=LogNorm(vmin=vmax * 1e-3, vmax=vmax))
for i, o in enumerate(targets):
    a1.plot(arrival_ns(Prow, Prow, o) - 0.1, np.arange(conf_px), color=f"C{i + 1}", ls="--", lw=1,
            label=f"disk at z = {o[2]} m (drawn 0.1 ns early)")
a1.set_xlim(12, t_ns[-1])
a1.set_title("without the wall return (log scale): the hidden disks")
a1.legend(fontsize=7, loc="lower right")
for ax in (a0, a1):
    ax.set_xlabel("time after the pulse (ns)")
    ax.set_ylabel("pixel x")
plt.show()

# %% [markdown]
# ## Time-integrated images
#
# Photons per pulse per pixel, summed over time, without the wall return (+: the disks). In the
# confocal capture the light falls off with the distance of the laser spot from the disks (`1/r^4`
# for three-bounce light; the nearest disk, 0.4 m away, is the brightest). The array capture, for one laser
# spot: the wall return is a single bright pixel (the one whose patch holds the spot); the hidden light
# is spread over every pixel.

# %%
arr_t = ma["time"]
spot = 0
arr = read_spot(array, spot, ma)                          # [pixel_y, pixel_x, time] for laser spot 0
S0 = S_arr[spot]
arr_t_ps = arr_t["t0_ps"] + (np.arange(arr_t["n_bins"]) + 0.5) * arr_t["bin_width_ps"]


def after_wall_return(j):
    """[H, W, T] mask: bins more than 300 ps after |L - S_j| + |P_k - D|, the shortest path via pixel k's patch."""
    t_min = (np.linalg.norm(S_arr[j] - laser) + np.linalg.norm(detector - P_arr, axis=-1)) / C_M_PER_PS
    return arr_t_ps[None, None, :] > t_min[..., None] + 300


after = after_wall_return(spot)
ext = [-0.4, 0.4, -0.4, 0.4]
fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
im = axes[0].imshow(conf_hidden.sum(-1), origin="lower", extent=ext, cmap="viridis")
axes[0].plot(targets[:, 0], targets[:, 1], "w+", ms=10)
axes[0].set_title("confocal: hidden light per pixel")
fig.colorbar(im, ax=axes[0], shrink=0.85)
im = axes[1].imshow(arr.sum(-1), origin="lower", extent=ext, cmap="viridis")
axes[1].plot(*S0[:2], "r*", ms=8)
axes[1].set_title(f"array, spot {spot}: everything")
fig.colorbar(im, ax=axes[1], shrink=0.85)
im = axes[2].imshow(np.where(after, arr, 0).sum(-1), origin="lower", extent=ext, cmap="viridis")
axes[2].plot(targets[:, 0], targets[:, 1], "w+", ms=10)
axes[2].plot(*S0[:2], "r*", ms=8)
axes[2].set_title(f"array, spot {spot}: hidden light only")
fig.colorbar(im, ax=axes[2], shrink=0.85, label="photons per pulse")
for ax in axes:
    ax.set_xlabel("x (m)")
axes[0].set_ylabel("y (m)")
fig.tight_layout()
plt.show()

# %% [markdown]
# ## All laser spots of the array capture
#
# Summed over pixels, per laser spot: the histogram starts with the wall return, then the three disks.
# The array capture supplies every (spot, pixel) pair, the data of the reference paper's
# backprojection.

# %%
fig, ax = plt.subplots(figsize=(9, 3))
for j in range(len(S_arr)):
    h = read_spot(array, j, ma).sum(axis=(0, 1))
    ax.semilogy(arr_t_ps / 1000, np.maximum(h, 1e-12), lw=0.7, label=f"spot {j}" if j < 4 else None)
ax.set_ylim(1e-8, None)
ax.set_xlabel("time after the pulse (ns)")
ax.set_ylabel(f"photons / pulse / {arr_t['bin_width_ps']:g} ps bin\n(all pixels)")
ax.legend(fontsize=7, ncol=4)
plt.show()
wall_sum = sum(read_spot(array, j, ma)[~after_wall_return(j)].sum() for j in range(len(S_arr)))
hidden_sum = sum(read_spot(array, j, ma)[after_wall_return(j)].sum() for j in range(len(S_arr)))
print(f"all spots and pixels: wall return {wall_sum:.3g}, hidden light {hidden_sum:.3g} photons per pulse")

# %% [markdown]
# From a shell: `transient-mi render scenes/nlos_point_targets.xml -o out/targets -D capture=confocal`
# writes the same kind of capture (plus `preview.png`). Next: [03_detector_model](03_detector_model.ipynb).
