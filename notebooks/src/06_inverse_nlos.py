# %% [markdown]
# # 6. Inverse NLOS: gradients of a capture, and fitting the mannequin's pose to its counts
#
# transient-mi's NLOS renderer is differentiable: the derivative of a capture (expected photons per
# pulse, per pixel and time bin) with respect to the hidden object's geometry comes with the render.
# Here we look at that derivative for one joint of the paper's mannequin (which pixels and time bins
# respond when the right elbow bends), then let `transient-mi fit` recover an unseen pose from
# detected counts: the differentiable twin of the mannequin, the detector model and Adam
# (`docs/fit.md`).

# %% [setup]

# %% [markdown]
# ## A capture of a pose the fit has not seen
#
# The paper's scene (`scenes/paper_mannequin.xml`): 1 m relay wall, 2 x 2 laser spots, the SPAD array
# and the paper's detector for 10 ms per spot. The mannequin bends its right elbow and its left knee,
# raises its left arm and leg. Bins of 10 ps (the fit sums the counts into 10 ps bins anyway).

# %%
import transient_mi  # noqa: F401  (registers the plug-ins and selects the LLVM before Mitsuba runs)
from transient_mi.experiment import detect_counts, render_ideal
from transient_mi.paper import PaperConfig

array = 8 if SMALL else 16
joints = "elbow_right=50,shoulder_flexion_right=50,shoulder_abduction_left=70,hip_left=25,knee_left=35"
cfg = PaperConfig(array=array, spp=256 if SMALL else 1024, n_bins=1150, bin_width_ps=10.0, joints=joints)
ideal = render_ideal(cfg, OUT / "ideal", progress=False)
counts = detect_counts(ideal, OUT / "counts", exposure_s=0.01, progress=False)
print(f"{array} x {array} array, 4 laser spots, counts in {counts}")

# %% [markdown]
# ## Which pixels and times respond to the elbow? (forward mode)
#
# The twin (`transient_mi.fit.MannequinTwin`) gives the mesh's vertices as a Dr.Jit function of the
# joint angles. With a tangent on `elbow_right`, the renderer's forward mode returns
# d(capture)/d(elbow angle) for every pixel and bin: light from the forearm moves in time (positive
# where it arrives after the bend, negative where it left).

# %%
from transient_mi.fit import MannequinModel
from transient_mi.fit.capture_model import CaptureModel
from transient_mi.fit.sensitivity import parameter_sensitivity, sensitivity_figure
from transient_mi.scenes.mannequin_skeleton import parse_joints

model = MannequinModel(detail=12)
cap = CaptureModel(counts, model.faces, model.n_vertices, bin_width_ps=10.0)
theta = model.initial((0.0, 0.0, 0.5))
for name, value in parse_joints(joints).items():
    theta[model.names.index(name)] = value
d = parameter_sensitivity(model, cap, theta, "elbow_right", spp=64 if SMALL else 256)  # [y, x, bin] per degree

from IPython.display import Image, display

from transient_mi.reporting import save_figure

png = save_figure(sensitivity_figure(d, cap.t0_ps, cap.bin_width_ps, "elbow_right"), OUT / "elbow.png", dpi=72)
display(Image(filename=str(png)))

# %% [markdown]
# ## Fit the pose to the counts
#
# `fit_capture` is what `transient-mi fit COUNTS -o OUT --model mannequin` runs: it starts from the
# paper's `arms_down` pose at the backprojection's centroid and descends the objective (the Gaussian
# approximation of the Poisson likelihood, coarse to fine in time) by Gauss-Newton steps on the deterministic
# three-bounce estimator (`--estimator monte_carlo` switches to Adam on Monte Carlo derivatives). It writes
# `fit.json`, `fitted.ply`, `loss.png` and `fit.png`.

# %%
from transient_mi.fit import FitSettings, fit_capture

result = fit_capture(counts, OUT / "fit", settings=FitSettings(iterations=3 if SMALL else None), progress=False)
m = result["metrics"]
print(f"joint angles within {m['joint_error_max_deg']:.1f} deg (mean {m['joint_error_mean_deg']:.1f}), "
      f"position within {100 * m['position_error_m']:.2f} cm")
print(f"fit: Chamfer {100 * m['fit']['chamfer_m']:.2f} cm, IoU {m['fit']['iou']:.2f};  "
      f"backprojection: Chamfer {100 * m['backprojection']['chamfer_m']:.2f} cm, IoU {m['backprojection']['iou']:.2f}")

# %%

display(Image(filename=str(OUT / "fit" / "fit.png")))
display(Image(filename=str(OUT / "fit" / "loss.png")))

# %% [markdown]
# On small settings (the test suite) the fit runs a few iterations only; with the full settings (the fit's
# default 16 Gauss-Newton iterations on every 2nd pixel of the 16 x 16 array) the joint angles come within a few
# degrees.
# The paper's 32 x 32 capture: `python bench/bench_fit.py` and `docs/fit.md`.
