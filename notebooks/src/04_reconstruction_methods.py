# %% [markdown]
# # 4. Reconstruction methods side by side
#
# `recon` turns a capture into a volume of the hidden scene. Five methods:
#
# | method | captures | what it does |
# |---|---|---|
# | `bp` | any | ellipsoidal backprojection (the reference paper's): every bin votes for the voxels on its ellipsoid `\|S_j - v\| + \|v - P_k\| = path` |
# | `fbp` | any | backprojection of histograms filtered in time (a band-limited ramp filter): sharper, signed |
# | `lct` | confocal | light-cone transform (O'Toole et al. 2018): a 3-D deconvolution with a Wiener filter |
# | `fk` | confocal | f-k (Stolt) migration (Lindell et al. 2019), from seismic imaging |
# | `phasor` | any | phasor fields (Liu et al. 2019): a virtual wave focused on each voxel |
#
# After the method, the paper's filter: a Gaussian (sigma one voxel), the negative Laplacian (keeps
# bright blobs), then a threshold at 30 % of the maximum (`rel:0.3`). Metrics compare the occupied voxels
# with the hidden mesh: Chamfer distance (m), depth error per column (m), voxel IoU.
#
# The hidden object: the letter F of `scenes/nlos_letter.xml` (40 cm tall, 0.5 m behind the wall).

# %% [setup]

# %% [markdown]
# ## Captures
#
# A confocal capture (the laser on each pixel's own patch) and an array capture (4 x 4 laser spots, every
# pixel recorded for every spot) of the same letter, over 0.8 m x 0.8 m of wall. The wall's own return is
# left out of the render (`include_wall_return=false`), as a gated detector would miss it; the capture
# still includes the laser-to-wall and wall-to-detector segments, which every method removes.

# %%
import transient_mi  # noqa: F401  (registers the plug-ins and selects the LLVM before Mitsuba runs)
from transient_mi.render_capture import render
from transient_mi.scenes import scene_path

if SMALL:
    conf_px, conf_spp, arr_px, arr_spp, voxels = 16, 256, 8, 64, (32, 32, 20)
    time_axis = {"n_bins": "256", "bin_width_ps": "32"}
else:
    conf_px, conf_spp, arr_px, arr_spp, voxels = 32, 4096, 16, 1024, (64, 64, 40)
    time_axis = {"n_bins": "512", "bin_width_ps": "16"}
letter = {"letter_center": "0, 0, 0.5", "letter_size": "0.4", "include_wall_return": "false", **time_axis}
confocal = render(scene_path("nlos_letter"), OUT / "confocal", spp=conf_spp, progress=False,
                  defines=dict(letter, capture="confocal", width=str(conf_px), height=str(conf_px),
                               pixel_footprint_m=str(0.8 / conf_px)))
array = render(scene_path("nlos_letter"), OUT / "array", spp=arr_spp, progress=False,
               defines=dict(letter, capture="array", width=str(arr_px), height=str(arr_px),
                            pixel_footprint_m=str(0.8 / arr_px), spots_x="4", spots_y="4", spot_spacing_m="0.2"))
BOUNDS = (-0.4, 0.4, -0.4, 0.4, 0.25, 0.75)       # xmin, xmax, ymin, ymax, zmin, zmax (m)
print(f"confocal {conf_px} x {conf_px}, array {arr_px} x {arr_px} pixels x 16 spots; "
      f"voxels {voxels} over {BOUNDS}")

# %% [markdown]
# ## Ground truth
#
# The letter's three rectangles, as the scene file places them (a unit-height letter scaled by
# `letter_size` and moved to `letter_center`), as a triangle mesh for the metrics.

# %%
import trimesh


def letter_mesh(size=0.4, center=(0.0, 0.0, 0.5)):
    """The F of scenes/nlos_letter.xml: rectangles (x range, y range) of a unit-height letter."""
    rects = [((-0.30, -0.14), (-0.50, 0.50)), ((-0.14, 0.30), (0.34, 0.50)), ((-0.14, 0.14), (-0.05, 0.09))]
    verts, faces = [], []
    for (x0, x1), (y0, y1) in rects:
        k = len(verts)
        verts += [(x0, y0, 0), (x1, y0, 0), (x1, y1, 0), (x0, y1, 0)]
        faces += [(k, k + 1, k + 2), (k, k + 2, k + 3)]
    v = np.array(verts) * size + np.array(center)
    return trimesh.Trimesh(vertices=v, faces=np.array(faces), process=False)


mesh = letter_mesh()
print(f"letter area {mesh.area:.4f} m^2")

# %% [markdown]
# ## Five methods on the confocal capture
#
# `recon.reconstruct(capture, method, bounds=..., voxels=...)` returns a `Reconstruction` with `raw`
# (the method's output) and `volume` (after the paper's filter), both `[z, y, x]`.

# %%
import time

import recon
from recon.ground_truth import ground_truth_silhouette
from recon.metrics import GroundTruth, compute_metrics


def run_methods(capture_dir, methods):
    """``methods``: names, or ``{label: (method, options)}``; returns ``{label: (rec, metrics, seconds)}``."""
    if not isinstance(methods, dict):
        methods = {m: (m, {}) for m in methods}
    cap = recon.load_capture(capture_dir)
    results = {}
    for label, (method, options) in methods.items():
        t0 = time.perf_counter()
        rec = recon.reconstruct(cap, method, bounds=BOUNDS, voxels=voxels, filter="paper", threshold="rel:0.3",
                                **options)
        seconds = time.perf_counter() - t0
        metrics = compute_metrics(rec, GroundTruth(mesh=mesh, source="letter F"), seed=0)
        results[label] = (rec, metrics, seconds)
    return results


def show(results, title):
    """Per method: raw and filtered front views (max along z), filtered top view (max along y)."""
    methods = list(results)
    g = next(iter(results.values()))[0].grid
    ext_xy = [g.x_m[0], g.x_m[-1], g.y_m[0], g.y_m[-1]]
    ext_xz = [g.x_m[0], g.x_m[-1], g.z_m[0], g.z_m[-1]]
    fig, axes = plt.subplots(3, len(methods) + 1, figsize=(2.3 * (len(methods) + 1), 6.9))
    sil = ground_truth_silhouette(mesh, g.x_m, g.y_m)
    axes[0, 0].imshow(sil, origin="lower", extent=ext_xy, cmap="gray")
    axes[0, 0].set_title("ground truth")
    axes[1, 0].axis("off")
    axes[2, 0].hlines(mesh.vertices[:, 2].mean(), mesh.vertices[:, 0].min(), mesh.vertices[:, 0].max(), color="k")
    axes[2, 0].set_xlim(ext_xz[:2])
    axes[2, 0].set_ylim(ext_xz[2:])
    axes[2, 0].set_aspect("equal")
    for col, m in enumerate(methods, start=1):
        rec, metrics, seconds = results[m]
        axes[0, col].imshow(np.abs(rec.raw).max(axis=0), origin="lower", extent=ext_xy, cmap="inferno")
        axes[0, col].set_title(f"{m}: raw ({seconds:.2f} s)")
        axes[1, col].imshow(rec.volume.max(axis=0), origin="lower", extent=ext_xy, cmap="inferno")
        axes[1, col].set_title("filtered, front")
        axes[2, col].imshow(rec.volume.max(axis=1), origin="lower", extent=ext_xz, cmap="inferno")
        axes[2, col].set_title("filtered, top")
    for ax in axes.ravel():
        ax.tick_params(labelsize=7)
    for ax in axes[:2].ravel():
        ax.set_xticks([])
        ax.set_yticks([])
    axes[2, 0].set_xlabel("x (m)")
    axes[2, 0].set_ylabel("z (m)")
    fig.suptitle(title)
    fig.tight_layout()
    plt.show()


conf_results = run_methods(confocal, ["bp", "fbp", "lct", "fk", "phasor"])
show(conf_results, f"confocal capture, {conf_px} x {conf_px} pixels (front: as seen from the wall; top: x-z)")

# %% [markdown]
# `raw` of `fbp` and `lct` is signed; the front views show its absolute value. Backprojection alone is a
# blurred blob (every bin smears over a whole ellipsoid); the paper's filter sharpens it. The filtered
# views of every method should show the F's stem on the left, the top bar and the shorter middle bar.
#
# ## Metrics
#
# From `recon.metrics.compute_metrics` (also written by `transient-mi recon --ground-truth`):
# `chamfer_m` is the mean of accuracy (occupied voxels to the surface) and completeness (surface to the
# nearest occupied voxel); `depth_mae_m` the mean depth error over columns where both have a surface;
# `iou` the overlap of occupied voxels with the voxels the surface passes through. The letter lies exactly
# on a face between two voxel layers (z = 0.5 m), so no depth error can be below half a voxel here.

# %%
from IPython.display import Markdown


def table(results):
    rows = ["| method | time (s) | Chamfer (cm) | accuracy (cm) | completeness (cm) | depth MAE (cm) | IoU | occupied voxels |",
            "|---|---|---|---|---|---|---|---|"]
    for m, (rec, mt, seconds) in results.items():
        cm = lambda k: f"{100 * mt[k]:.2f}" if mt.get(k) is not None else "-"  # noqa: E731
        rows.append(f"| {m} | {seconds:.2f} | {cm('chamfer_m')} | {cm('accuracy_m')} | {cm('completeness_m')} | "
                    f"{cm('depth_mae_m')} | {mt['iou']:.3f} | {mt['occupied_voxels']} |")
    return Markdown("\n".join(rows))


vx = [(b - a) / n for (a, b), n in zip(zip(BOUNDS[::2], BOUNDS[1::2]), voxels)]
print("voxel size (cm):", [f"{100 * v:.2f}" for v in vx])
table(conf_results)

# %% [markdown]
# ## Array capture: bp, fbp and phasor
#
# LCT and f-k need confocal data; backprojection and phasor fields take any geometry. The array capture
# pairs each of the 16 laser spots with every pixel, which is what a SPAD array with a few laser
# positions records (the reference paper's setup). Phasor fields resolve about one virtual wavelength;
# the default, 4 pixel pitches, is 10 cm for the confocal capture above but 20 cm for this coarser
# array, so we also run it with `wavelength_m=0.08`.

# %%
arr_pitch = 0.8 / arr_px
arr_results = run_methods(array, {"bp": ("bp", {}), "fbp": ("fbp", {}),
                                  f"phasor {400 * arr_pitch:.0f} cm": ("phasor", {}),
                                  "phasor 8 cm": ("phasor", {"wavelength_m": 0.08})})
show(arr_results, f"array capture, {arr_px} x {arr_px} pixels x 16 laser spots")
table(arr_results)

# %% [markdown]
# ## Options worth knowing
#
# - `threshold`: `rel:F` (fraction of the maximum), `abs:V`, `otsu`, `none`; `sigma_m` sets the
#   Gaussian of the paper's filter; `filter="none"` keeps `volume = raw`.
# - Method options: `fbp_sigma_m` (fbp), `snr` (lct's Wiener filter), `wavelength_m` and `pulse_sigma_m`
#   (phasor's virtual wave; default 4 pixel pitches), `voxel_integration` (bp).
# - Counts captures: `recon.preprocess.pileup_correction` first when the detector saturated (notebook 3).
#
# The same from a shell, with pictures and `metrics.json`:
# `transient-mi recon out/confocal -o out/rec_lct --method lct --bounds -0.4,0.4,-0.4,0.4,0.25,0.75`.
# Next: [05_photon_budget](05_photon_budget.ipynb), how many photons a reconstruction needs.
