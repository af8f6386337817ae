# %% [markdown]
# # 1. Quick start: a transient Cornell box
#
# A transient render records *when* light arrives, not only how much: every pixel holds a
# histogram over time. Here we render Mitsuba's Cornell box with `transient_path` into a
# `transient_film`, load the result, and look at it as a time-integrated image, time slices,
# an x-t streak image, one pixel's histogram and an animation.
#
# Conventions used throughout transient-mi: time in **picoseconds** (`*_ps`), with **t = 0 when
# light leaves the emitter**; distances in **metres**; 1 ns of time of flight = 0.2998 m of path.
# A camera render stores, per pixel and time bin, the radiance that arrives in that bin, so the
# bins of a pixel sum to its ordinary (steady-state) radiance.

# %% [setup]

# %% [markdown]
# ## Render
#
# `import transient_mi` comes first: it sets up LLVM, selects the `llvm_ad_mono` variant and registers
# the plug-ins. `transient_mi.render_capture.render` is what `transient-mi render` runs; the scene's
# `<default>` parameters are overridden like `-D name=value` on the command line. The film covers
# 10 ns to 40 ns after emission (the light needs about 13 ns to reach the camera).

# %%
import transient_mi  # noqa: F401  (registers the plug-ins and selects the LLVM before Mitsuba runs)
from transient_mi.render_capture import render
from transient_mi.scenes import scene_path

if SMALL:
    size, n_bins, bin_width_ps, spp = 48, 150, 200.0, 16
else:
    size, n_bins, bin_width_ps, spp = 128, 600, 50.0, 512
defines = {"width": str(size), "height": str(size), "n_bins": str(n_bins),
           "bin_width_ps": str(bin_width_ps), "t0_ps": "10000"}
capture = render(scene_path("cornell_box"), OUT / "cornell_box", defines=defines, spp=spp, seed=0, progress=False)
print(f"rendered {size} x {size} pixels x {n_bins} bins of {bin_width_ps:g} ps at {spp} spp")

# %% [markdown]
# The same from a shell: `transient-mi render scenes/cornell_box.xml -o out/cornell_box -D n_bins=600
# -D bin_width_ps=50 --spp 512`.
#
# ## Load the stack
#
# A capture is a directory: `manifest.json` (time axis, provenance, ...) and one EXR file per laser
# spot (a camera render has one). `transient_core.stack.read_stack` returns the manifest and the data as
# `[file, pixel_y, pixel_x, time]`.

# %%
from transient_core.stack import read_stack

manifest, data = read_stack(capture)
hist = data[0]                                   # [pixel_y, pixel_x, time], float32
t = manifest["time"]
t0_ps, bin_width_ps, n_bins = t["t0_ps"], t["bin_width_ps"], t["n_bins"]
t_ns = (t0_ps + (np.arange(n_bins) + 0.5) * bin_width_ps) / 1000.0   # bin centres, ns
print("data:", data.shape, data.dtype)
print("time axis:", t)
print(f"render time {manifest['render']['render_time_s']:.1f} s; light arriving after the last bin "
      f"(dropped): {100 * manifest['dropped']['fraction']:.2f} %")

# %% [markdown]
# ## Time-integrated image
#
# Summing over time gives the steady-state image Mitsuba's `path` integrator would render (up to the
# light arriving after 40 ns, counted as dropped above). Display: scaled to the 99th percentile,
# gamma 1/2.2.

# %%
steady = hist.sum(axis=-1)


def tonemap(img, pct=99.0):
    return np.clip(img / np.percentile(img, pct), 0, 1) ** (1 / 2.2)


fig, ax = plt.subplots(figsize=(3.2, 3.2))
ax.imshow(tonemap(steady), cmap="gray")
ax.set_title("time-integrated radiance")
ax.axis("off")
plt.show()

# %% [markdown]
# ## Time slices
#
# Each panel is the light arriving within one bin, on one logarithmic colour scale (radiance per bin).
# First the light source itself (seen directly), then the ceiling next to it, then the light front
# sweeping over the walls, the boxes and the floor, and then the slowly fading inter-reflections.

# %%
from matplotlib.colors import LogNorm

slice_ns = [13.2, 15.5, 16.5, 17.5, 19.5, 23.0]
vmax = np.percentile(hist[..., t_ns > 13.5], 99.9)
norm = LogNorm(vmin=vmax * 1e-3, vmax=vmax)
fig, axes = plt.subplots(1, len(slice_ns), figsize=(13, 2.6))
for ax, ts in zip(axes, slice_ns):
    b = int(np.clip((ts * 1000 - t0_ps) // bin_width_ps, 0, n_bins - 1))
    im = ax.imshow(np.maximum(hist[..., b], vmax * 1e-4), cmap="inferno", norm=norm)
    ax.set_title(f"t = {t_ns[b]:.2f} ns")
    ax.axis("off")
fig.colorbar(im, ax=axes, shrink=0.8, label=f"radiance per {bin_width_ps:g} ps bin")
plt.show()

# %% [markdown]
# ## x-t streak image
#
# One image row (the middle one) against time, as a streak camera records it. The bright curve is the
# first light reaching each point of the row; its shape is the path length `|light - x| + |x - camera|`
# across the row. Everything to the right of it is light that bounced more than once.

# %%
row = hist.shape[0] // 2
fig, ax = plt.subplots(figsize=(8, 2.8))
ax.imshow(np.maximum(hist[row], vmax * 1e-4), cmap="inferno", norm=norm, aspect="auto",
          extent=[t_ns[0] - bin_width_ps / 2000, t_ns[-1] + bin_width_ps / 2000, hist.shape[1] - 0.5, -0.5])
ax.set_xlabel("time after emission (ns)")
ax.set_ylabel("pixel x")
ax.set_title(f"x-t streak image of row {row}")
ax.set_xlim(12, 30)
plt.show()

# %% [markdown]
# ## One pixel's histogram
#
# A pixel on the back wall, above the boxes (thin line; the thick line averages the 5 x 5 pixels
# around it, which shows the tail with less Monte Carlo noise). The earliest light it can receive has bounced once:
# from the ceiling light (a rectangle 0.46 m x 0.38 m at y = 0.99 m) to the wall point `p` and on to the
# camera at (0, 0, 3.9) m. We compute that shortest path from the scene geometry and mark it: the
# histogram starts there, and the long tail is light that bounced two or more times.

# %%
H, W = hist.shape[:2]
py, px = int(0.31 * H), W // 2                 # back wall, above the boxes
tan_half = np.tan(np.radians(39.3077) / 2)     # the scene's horizontal field of view
camera = np.array([0.0, 0.0, 3.9])
direction = np.array([((px + 0.5) / W * 2 - 1) * tan_half, (1 - (py + 0.5) / H * 2) * tan_half, -1.0])
p = camera + direction * (camera[2] + 1.0)     # hits the back wall z = -1
lx, lz = np.meshgrid(np.linspace(-0.23, 0.23, 101), 0.01 + np.linspace(-0.19, 0.19, 101))
light = np.stack([lx.ravel(), np.full(lx.size, 0.99), lz.ravel()], axis=1)
C_M_PER_NS = 0.299792458
first_ns = (np.linalg.norm(light - p, axis=1).min() + np.linalg.norm(p - camera)) / C_M_PER_NS

fig, ax = plt.subplots(figsize=(8, 2.8))
ax.step(t_ns, hist[py, px], where="mid", lw=0.6, color="0.6", label="one pixel")
ax.step(t_ns, hist[py - 2:py + 3, px - 2:px + 3].mean(axis=(0, 1)), where="mid", lw=1.2, color="C0",
        label="5 x 5 pixel mean")
ax.axvline(first_ns, color="C3", ls="--", lw=1, label=f"shortest one-bounce path: {first_ns:.2f} ns")
ax.set_yscale("log")
ax.set_xlim(12, 40)
ax.set_xlabel("time after emission (ns)")
ax.set_ylabel(f"radiance per {bin_width_ps:g} ps bin")
ax.set_title(f"pixel (y={py}, x={px}) at p = ({p[0]:.2f}, {p[1]:.2f}, {p[2]:.2f}) m")
ax.legend(loc="upper right")
plt.show()
onset = t_ns[np.argmax(hist[py, px] > 0)]
print(f"first non-empty bin centred at {onset:.2f} ns (predicted onset {first_ns:.2f} ns, bin width {bin_width_ps:g} ps)")

# %% [markdown]
# ## Animation
#
# The light front as a movie: one frame per 0.3 ns (bins summed), on a fixed logarithmic scale,
# written as a GIF with matplotlib's `PillowWriter` and shown inline.

# %%
from IPython.display import Image
from matplotlib.animation import FuncAnimation, PillowWriter

frame_ns = 0.3 if not SMALL else 1.0
edges = np.arange(14.0, 23.0 + 1e-9, frame_ns)
frames = []
for a, b in zip(edges[:-1], edges[1:]):
    sel = (t_ns >= a) & (t_ns < b)
    frames.append(hist[..., sel].sum(axis=-1))
fmax = np.percentile(np.stack(frames)[:, :, :], 99.5)
fnorm = LogNorm(vmin=fmax * 1e-3, vmax=fmax)

fig, ax = plt.subplots(figsize=(2.4, 2.6))
img = ax.imshow(np.maximum(frames[0], fmax * 1e-4), cmap="inferno", norm=fnorm)
ax.axis("off")
title = ax.set_title("")
fig.tight_layout()


def draw(k):
    img.set_data(np.maximum(frames[k], fmax * 1e-4))
    title.set_text(f"t = {edges[k]:.2f} ns")
    return img, title


anim = FuncAnimation(fig, draw, frames=len(frames), blit=False)
gif = OUT / "cornell_box.gif"
anim.save(gif, writer=PillowWriter(fps=6), dpi=56)
plt.close(fig)
print(f"{gif.name}: {len(frames)} frames, {gif.stat().st_size / 1e3:.0f} kB")
Image(filename=str(gif))

# %% [markdown]
# ## Next
#
# - Change the scene from Python or the command line: `-D max_depth=3` keeps only light that bounced
#   at most once (a clean light front), `-D kernel_sigma_ps=30` blurs time like a detector.
# - [02_nlos_capture](02_nlos_capture.ipynb): the same machinery looking around a corner.
