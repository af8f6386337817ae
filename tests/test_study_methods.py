"""The methods study (leaderboard) on tiny settings: outputs, rows, reproducibility, scene ground truth, bad input."""

from __future__ import annotations

import csv
import json
import subprocess
import sys

import numpy as np
import pytest

#: 4x4 and 8x8 arrays, 2x2 laser spots, 8 ps bins, 64 spp, 1 ms per spot; 32x32x16 voxels; two methods, each
#: also completed behind its front.
TINY = dict(arrays=(4, 8), exposures_s=(1e-3,), methods=("bp", "midpoint-fk"), defines={"spp": 64, "estimator": "monte_carlo"}, quick=True,
            voxels=(32, 32, 16), progress=False, complete="auto")
METRICS = ("chamfer_m", "completeness_m", "iou", "depth_mae_m", "visible_completeness_m", "visible_iou",
           "silhouette_iou")


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    import transient_mi  # noqa: F401
    from transient_mi.study import run_methods_study

    return run_methods_study("paper_mannequin", tmp_path_factory.mktemp("sm") / "study", **TINY)


def test_outputs_rows_and_figures(study):
    import matplotlib.image as mpimg

    out, rows = study
    assert not (out / "captures").exists()
    for name in ("leaderboard.csv", "leaderboard.json", "leaderboard.png", "reconstructions.png", "summary.md",
                 "ground_truth.ply"):
        assert (out / name).is_file(), name
    assert mpimg.imread(out / "leaderboard.png").shape[0] > 100
    names = ["bp", "bp+completion", "midpoint-fk", "midpoint-fk+completion"]
    assert [(r["array"], r["method"]) for r in rows] == [(n, m) for n in (4, 8) for m in names]
    for r in rows:
        assert r["scene"] == "paper_mannequin" and r["exposure_s"] == 1e-3 and r["counts_per_pixel_per_spot"] > 0
        for k in ("chamfer_m", "completeness_m", "depth_mae_m", "visible_completeness_m"):
            assert 0 < r[k] < 0.5, (k, r[k])
        assert 0 < r["iou"] <= 1 and 0 < r["silhouette_iou"] <= 1 and 0 <= r["visible_iou"] <= 1
        assert r["reconstruct_s"] > 0 and r["peak_traced_mb"] > 0
    for plain, done in zip(rows[0::2], rows[1::2]):
        # completion closes the surface behind the same front: the same columns
        assert done["silhouette_iou"] == plain["silhouette_iou"]
        # midpoint-fk's fronts recede (the body is round): the back it adds brings the whole surface closer.
        # (bp's blobs show no recession, aspect 0: they become their front surface alone.)
        if plain["method"] == "midpoint-fk":
            assert done["completeness_m"] < plain["completeness_m"]
        assert done["reconstruct_s"] > plain["reconstruct_s"] and len(done["completion_aspects"]) >= 1
    with open(out / "leaderboard.csv") as f:
        assert len(list(csv.DictReader(f))) == 8
    data = json.loads((out / "leaderboard.json").read_text())
    assert data["settings"]["methods"] == ["bp", "midpoint-fk"] and data["settings"]["detection_seed"] == 1
    assert data["settings"]["completion"] == "auto"
    text = (out / "summary.md").read_text()
    assert "| paper_mannequin | 8x8 | 1 | midpoint-fk |" in text


def test_same_seed_same_metrics(study, tmp_path):
    """Render, detection and metrics are seeded: a rerun gives the same metric values (times differ)."""
    from transient_mi.study import run_methods_study

    _, again = run_methods_study("paper_mannequin", tmp_path / "again", **TINY)
    for a, b in zip(study[1], again):
        assert {k: a[k] for k in METRICS} == {k: b[k] for k in METRICS}


def test_scene_ground_truth_is_the_letter():
    """The letter scene's F: three rectangles (six triangles) at the letter's depth (default z = 0.5 m), 0.4 m tall."""
    import transient_mi  # noqa: F401
    from transient_mi.study.methods import scene_ground_truth
    from transient_mi.study.scene import study_scene

    gt = scene_ground_truth(study_scene("nlos_letter"))
    v = gt.mesh.vertices
    np.testing.assert_allclose(v[:, 2], 0.5, atol=1e-6)
    assert len(gt.mesh.faces) == 6
    np.testing.assert_allclose([v[:, 1].min(), v[:, 1].max()], [-0.2, 0.2], atol=1e-6)
    # unit letter: stem 0.16 x 1.0, top bar 0.44 x 0.16, middle bar 0.28 x 0.14; scaled by 0.4
    np.testing.assert_allclose(gt.mesh.area, 0.4 ** 2 * (0.16 * 1.0 + 0.44 * 0.16 + 0.28 * 0.14), rtol=1e-5)


def test_bad_input(tmp_path):
    from transient_core.errors import UserInputError
    from transient_mi.study import run_methods_study

    with pytest.raises(UserInputError, match="need confocal captures"):
        run_methods_study("paper_mannequin", tmp_path / "x", methods=("lct",), **{k: v for k, v in TINY.items()
                                                                               if k != "methods"})
    with pytest.raises(UserInputError, match="method='nope'"):
        run_methods_study("paper_mannequin", tmp_path / "x", methods=("nope",), **{k: v for k, v in TINY.items()
                                                                                if k != "methods"})
    r = subprocess.run([sys.executable, "-m", "transient_mi", "study", "methods", "-o", str(tmp_path / "y"),
                        "--arrays", "4,x"], capture_output=True, text=True)
    assert r.returncode == 2 and "error: --arrays" in r.stderr and "Traceback" not in r.stderr
    with pytest.raises(UserInputError, match="noise_target: -1 is not allowed"):
        run_methods_study("paper_mannequin", tmp_path / "x", noise_target=-1, **TINY)
    r = subprocess.run([sys.executable, "-m", "transient_mi", "study", "methods", "-o", str(tmp_path / "y"),
                        "--noise-target", "small"], capture_output=True, text=True)
    assert r.returncode == 2 and "error: --noise-target 'small'" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()


def test_rows_report_the_rendering_noise(study):
    """Without a noise target (``quick``) the scene's spp is rendered as it is, and every row still records the
    measured ratio of rendering to photon noise and the samples used; the summary states the worst ratio."""
    out, rows = study
    for r in rows:
        assert r["render_spp"] == 64 and r["render_noise_ratio"] > 0
    assert json.loads((out / "leaderboard.json").read_text())["settings"]["noise_target"] is None
    worst = max(r["render_noise_ratio"] for r in rows)
    assert f"without a noise target: rendering noise up to {worst:.3g} x" in (out / "summary.md").read_text()


def test_noise_target_renders_until_the_rendering_noise_is_small(tmp_path):
    """``noise_target=0.1``: each array is rendered from the 64-spp pilot until its rendering variance is at most
    0.1 x the photon variance at the largest exposure; the rows record more samples than the pilot and a measured
    ratio within the target (pooled over spots, it cannot exceed the worst spot's, which the render brought under
    the target), below the pilot-only render's."""
    from transient_mi.study import run_methods_study

    kw = {**TINY, "arrays": (4,), "methods": ("bp",), "complete": None}
    _, pilot = run_methods_study("paper_mannequin", tmp_path / "a", **kw)
    out, rows = run_methods_study("paper_mannequin", tmp_path / "b", noise_target=0.1, **kw)
    assert pilot[0]["render_noise_ratio"] > 0.1, "the pilot alone must miss the target for this test to mean anything"
    (r,) = rows
    assert r["render_spp"] > 64 and 0 < r["render_noise_ratio"] <= 0.1
    assert json.loads((out / "leaderboard.json").read_text())["settings"]["noise_target"] == 0.1
    assert "rendered until its rendering noise was at most 0.1 x" in (out / "summary.md").read_text()


def test_fit_row_beside_the_methods(tmp_path):
    """``fit="mannequin"`` adds one ``fit:mannequin`` row per array x exposure: the fit of the same counts
    (``transient-mi detect``'s writer, the study's detection seed), its surface voxelised on the study's grid and
    scored like the methods; its time is the fit's, its settings are recorded, and nothing of its work is left in
    the output. The mannequin model starts from the paper's pose, this scene's: even two iterations place the
    surface closer to the mannequin than midpoint-fk's thresholded front (Chamfer, over the whole mesh)."""
    from transient_mi.study import run_methods_study
    from transient_mi.study.methods import fit_bin_width_ps, is_fit

    kw = {**TINY, "arrays": (8,), "methods": ("midpoint-fk",), "complete": None}
    out, rows = run_methods_study("paper_mannequin", tmp_path / "s", fit="mannequin", fit_iterations=2, **kw)
    assert [r["method"] for r in rows] == ["midpoint-fk", "fit:mannequin"]
    fk, fit = rows
    assert is_fit(fit["method"]) and not is_fit(fk["method"])
    assert fit["fit_iterations"] == 2 and fit["fit_bin_width_ps"] == 16.0
    assert fit["reconstruct_s"] > 0
    assert fit["chamfer_m"] < fk["chamfer_m"]
    assert fit["fit_joint_error_max_deg"] is not None and fit["fit_position_error_m"] is not None
    data = json.loads((out / "leaderboard.json").read_text())
    assert data["settings"]["fit"]["model"] == "mannequin" and data["settings"]["fit"]["iterations"] == 2
    assert "fit:mannequin" in (out / "summary.md").read_text()
    assert sorted(p.name for p in out.iterdir()) == ["ground_truth.ply", "leaderboard.csv", "leaderboard.json",
                                                     "leaderboard.png", "reconstructions.png", "summary.md"]
    # the smallest multiple of the capture's bins reaching 10 ps that divides the capture's bin count
    assert fit_bin_width_ps(1.0, 11500) == 10.0 and fit_bin_width_ps(4.0, 2880) == 12.0
    assert fit_bin_width_ps(4.0, 2875) == 20.0 and fit_bin_width_ps(25.0, 7) == 25.0


def test_two_fitted_models_each_on_its_own_arrays(tmp_path):
    """``fit=("mesh", "mannequin")`` with per-model iterations and arrays: the free mesh (issue 29) is fitted to the
    4x4 array's counts only, starting from midpoint-fk's front surface, the mannequin model to the 8x8 array's only, each row after the methods of its array in the order the models
    were given; the settings record both fits (a list), and the summary says which row knows the object's kind."""
    from transient_mi.study import run_methods_study
    from transient_mi.study.methods import fit_records

    kw = {**TINY, "methods": ("midpoint-fk",), "complete": None}
    out, rows = run_methods_study("paper_mannequin", tmp_path / "s", fit=("mesh", "mannequin"),
                                  fit_iterations={"mesh": 2, "mannequin": 1},
                                  fit_arrays={"mesh": (4,), "mannequin": (8,)}, **kw)
    assert [(r["array"], r["method"]) for r in rows] == [(4, "midpoint-fk"), (4, "fit:mesh"), (8, "midpoint-fk"),
                                                         (8, "fit:mannequin")]
    assert rows[1]["fit_iterations"] == 2 and rows[3]["fit_iterations"] == 1
    assert all(r["reconstruct_s"] > 0 and r["chamfer_m"] is not None for r in rows[1::2])
    settings = json.loads((out / "leaderboard.json").read_text())["settings"]
    fits = fit_records(settings)
    assert [(f["model"], f["arrays"], f["iterations"]) for f in fits] == [("mesh", [4], 2), ("mannequin", [8], 1)]
    assert fits[0]["start"] == "midpoint-fk's front surface" and "start" not in fits[1]
    assert fits[0]["estimator"] == "quadrature"  # the free mesh's forward model, always
    text = (out / "summary.md").read_text()
    assert "Rows `fit:mesh` are" in text and "a free mesh from midpoint-fk's front surface, which knows no kind" in text
    assert "Rows `fit:mannequin` are" in text and "model-based (it knows what kind of object hides)" in text


def test_fit_bad_input(tmp_path):
    from transient_core.errors import UserInputError
    from transient_mi.study import run_methods_study

    with pytest.raises(UserInputError, match="fit='cube': allowed mannequin, patches, mesh"):
        run_methods_study("paper_mannequin", tmp_path / "x", fit="cube", **TINY)
    with pytest.raises(UserInputError, match="fit_iterations=5: needs fit"):
        run_methods_study("paper_mannequin", tmp_path / "x", fit_iterations=5, **TINY)
    with pytest.raises(UserInputError, match="fit_iterations=0"):
        run_methods_study("paper_mannequin", tmp_path / "x", fit="mannequin", fit_iterations=0, **TINY)
    with pytest.raises(UserInputError, match="fit_arrays=\\[4\\]: needs fit"):
        run_methods_study("paper_mannequin", tmp_path / "x", fit_arrays=[4], **TINY)
    with pytest.raises(UserInputError, match="fit_arrays=\\[16\\]: each must be one of the study's arrays 4, 8"):
        run_methods_study("paper_mannequin", tmp_path / "x", fit="mesh", fit_arrays=(16,), **TINY)
    with pytest.raises(UserInputError, match="fit=\\['mesh', 'mesh'\\]: each model at most once"):
        run_methods_study("paper_mannequin", tmp_path / "x", fit=("mesh", "mesh"), **TINY)
    with pytest.raises(UserInputError, match="fit='cube': allowed"):
        run_methods_study("paper_mannequin", tmp_path / "x", fit=("mesh", "cube"), **TINY)
    with pytest.raises(UserInputError, match="fit_iterations=\\{'patches': 3\\}: 'patches' is not one of the fitted "
                                             "models mesh"):
        run_methods_study("paper_mannequin", tmp_path / "x", fit="mesh", fit_iterations={"patches": 3}, **TINY)
    with pytest.raises(UserInputError, match="fit_iterations of mesh=0"):
        run_methods_study("paper_mannequin", tmp_path / "x", fit=("mannequin", "mesh"), fit_iterations={"mesh": 0},
                          **TINY)
    with pytest.raises(UserInputError, match="fit_arrays=\\[16\\]: each must be one of"):
        run_methods_study("paper_mannequin", tmp_path / "x", fit=("mannequin", "mesh"), fit_arrays={"mesh": [16]},
                          **TINY)
    assert not (tmp_path / "x").exists()


def test_the_fit_sees_the_counts_the_methods_see(tmp_path):
    """The fit's counts (written by ``transient-mi detect``'s ``detect_stack``) are the in-memory detection the
    methods reconstruct (:func:`transient_mi.study.methods._detect`), bin for bin, for the same seed."""
    import recon
    from spad_detector import detect_stack
    from transient_mi.study.common import render
    from transient_mi.study.methods import _detect
    from transient_mi.study.scene import array_size_defines, base_detector, study_scene

    sc = study_scene("paper_mannequin", {"spp": 64, "estimator": "monte_carlo"}, quick=True)
    ideal = render(sc.with_defines(**array_size_defines(sc, 4)), tmp_path / "ideal", 0)
    params = base_detector(sc)
    cap = _detect(ideal, params, 1e-3, 1)[0]
    written = recon.load_capture(detect_stack(ideal, tmp_path / "counts", params, exposure_s=1e-3, seed=1,
                                              progress=False))
    assert written.kind == "counts" and written.data.sum() > 0
    np.testing.assert_array_equal(written.data, cap.data)


@pytest.mark.parametrize("given, estimator, expected", [("auto", "quadrature", 0.01), ("auto", "monte_carlo", 0.1),
                                                        (0.1, "quadrature", 0.1), (0.05, "monte_carlo", 0.05)])
def test_the_auto_noise_target_holds_the_quadrature_to_a_hundredth(tmp_path, given, estimator, expected):
    """A study's ``noise_target="auto"`` asks 0.1 x the photon noise of Monte Carlo and 0.01 x of the deterministic
    quadrature (issue 27), decided when the render knows the scene's estimator; a number given is kept for both."""
    from pathlib import Path

    from spad_detector import DetectorParams
    from transient_mi.render_capture import prepare_render
    from transient_mi.study.common import noise_target_spec, resolve_noise_target

    spec = noise_target_spec(given, resolve_noise_target(given, quick=False), DetectorParams(auto_gate=True), 1e-3)
    scene = Path(__file__).resolve().parents[1] / "scenes" / "nlos_letter.xml"
    prepare_render(scene, tmp_path / "c", defines={"estimator": estimator, "width": "4", "height": "4"}, spp=64,
                   noise_target=spec)
    assert spec.target == expected
    assert not (tmp_path / "c").exists()  # prepare_render writes nothing
