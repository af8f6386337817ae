#!/usr/bin/env python3
"""docs/img/fit_elbow_sensitivity.png: which pixels and time bins of an NLOS capture respond to the mannequin's
right elbow (forward-mode derivative of the paper's scene, 16 x 16 array, laser spot 0, in the bench's unseen pose).

    python docs/make_fit_figures.py        # ~1 minute on 2 cores

(The fit figure, docs/img/fit_paper_mannequin.png, comes from `python bench/bench_fit.py --save --figure ...`.)
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))


def main() -> None:
    import transient_mi  # noqa: F401  (before mitsuba)
    from bench_fit import UNSEEN
    from transient_mi.experiment import detect_counts, render_ideal
    from transient_mi.fit import MannequinModel
    from transient_mi.fit.capture_model import CaptureModel
    from transient_mi.fit.sensitivity import parameter_sensitivity, sensitivity_figure
    from transient_mi.paper import PaperConfig
    from transient_mi.reporting import save_figure
    from transient_mi.scenes.mannequin_skeleton import parse_joints

    cfg = PaperConfig(array=16, spp=256, n_bins=1150, bin_width_ps=10.0, estimator="monte_carlo").replace(**UNSEEN)
    with tempfile.TemporaryDirectory() as tmp:
        ideal = render_ideal(cfg, Path(tmp) / "ideal", progress=False)
        counts = detect_counts(ideal, Path(tmp) / "counts", exposure_s=0.01, progress=False)
        model = MannequinModel()
        cap = CaptureModel(counts, model.faces, model.n_vertices, bin_width_ps=10.0)
        theta = model.initial((0.0, 0.0, cfg.distance_m))
        theta[model.names.index("rotation_deg")] = cfg.rotation_deg
        for name, value in parse_joints(cfg.joints).items():
            theta[model.names.index(name)] = value
        d = parameter_sensitivity(model, cap, theta, "elbow_right", spp=512)
        fig = sensitivity_figure(d, cap.t0_ps, cap.bin_width_ps, "elbow_right")
    out = save_figure(fig, ROOT / "docs" / "img" / "fit_elbow_sensitivity.png", dpi=100)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
