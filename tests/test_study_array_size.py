"""The array-size study on tiny settings: outputs, metrics and timings per array size, reproducibility."""

from __future__ import annotations

import csv
import json

import pytest

#: 4x4 and 8x8 arrays, 2x2 laser spots, 8 ps bins, 64 spp, 1 ms per spot; 32x32x16 voxels.
TINY = dict(arrays=(4, 8), defines={"spp": 64, "estimator": "monte_carlo"}, exposure_s=1e-3, quick=True, voxels=(32, 32, 16), progress=False)


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    import transient_mi  # noqa: F401
    from transient_mi.study import run_array_size_study

    return run_array_size_study("paper_mannequin", tmp_path_factory.mktemp("as") / "study", **TINY)


def test_outputs_tables_and_figures(study):
    import matplotlib.image as mpimg

    out = study.out_dir
    assert study.study == "array_size"
    assert not (out / "captures").exists() and not (out / "warmup").exists()
    assert not list(out.parent.glob(f".{out.name}.*"))
    assert set(study.figures) == {"array_size", "reconstructions"}
    for p in study.figures.values():
        assert mpimg.imread(p).shape[0] > 100
    for name in ("results_csv", "results_json", "timings_csv", "timings_json"):
        assert study.tables[name].is_file()
    with open(study.tables["results_csv"]) as f:
        rows = list(csv.DictReader(f))
    assert [int(r["array"]) for r in rows] == [4, 8]
    for r, n in zip(study.rows, (4, 8)):
        assert r["pixels"] == n * n and r["n_spots"] == 4 and r["pulses_per_spot"] == 50_000
        assert r["counts_per_pixel_per_spot"] > 100 and r["ideal_bytes"] > 0 and r["counts_bytes"] > 0
        for k in ("chamfer_m", "accuracy_m", "completeness_m", "depth_mae_m"):
            assert 0 < r[k] < 0.5, (k, r[k])
        assert 0 < r["iou"] <= 1
    for t in study.timings:
        assert all(t[k] >= 0 for k in ("render_s", "detect_s", "reconstruct_s", "metrics_s"))
        assert t["total_s"] >= t["render_s"] + t["detect_s"]
    data = json.loads(study.tables["results_json"].read_text())
    assert data["settings"]["arrays"] == [4, 8] and data["settings"]["detection_seed"] == 1
    text = study.summary.read_text()
    assert "| 4x4 |" in text and "| 8x8 |" in text and "render (s)" in text


def test_rows_report_the_rendering_noise_the_methods_study_measures(study, tmp_path):
    """Each row records its counts' rendering-to-photon noise ratio (from ``transient-mi detect``'s manifest); at
    64 spp it is far above 0.1 and the summary says so. The methods study, which detects in memory, measures the
    same ratio for the same render and budget."""
    from transient_mi.study import run_methods_study

    for r in study.rows:
        assert r["render_noise_ratio"] > 0.1 and r["estimator"] == "monte_carlo"
    assert "above the usual 0.1: part of the error at large arrays is Monte Carlo noise" in study.summary.read_text()
    assert "(64 spp)" in study.summary.read_text()
    _, rows = run_methods_study("paper_mannequin", tmp_path / "m", arrays=(4,), exposures_s=(1e-3,), methods=("bp",),
                                defines={"spp": 64, "estimator": "monte_carlo"}, quick=True, voxels=(32, 32, 16), progress=False)
    assert rows[0]["render_noise_ratio"] == pytest.approx(study.rows[0]["render_noise_ratio"], rel=1e-9)


def test_the_noise_sentence_names_the_quadrature_where_it_made_the_captures():
    """Quadrature captures have no samples: the summary says which estimator made them and, above 0.1, that the
    excess is its discretisation error, not Monte Carlo noise."""
    from transient_mi.study.array_size import _noise_sentence

    rows = [{"array": 4, "render_noise_ratio": 0.004, "estimator": "quadrature"},
            {"array": 8, "render_noise_ratio": 0.2, "estimator": "quadrature"}]
    text = _noise_sentence(rows, 16384)
    assert "by the deterministic quadrature" in text and "16384 spp" not in text
    assert "the quadrature's discretisation error, not photon noise" in text and "4x4: 0.004, 8x8: 0.2" in text


def test_same_seed_same_bytes_and_kept_captures(study, tmp_path):
    """A rerun gives the same results.csv/json (timings apart); --keep-captures keeps the stacks."""
    from transient_mi.study import run_array_size_study

    again = run_array_size_study("paper_mannequin", tmp_path / "again", keep_captures=True, **TINY)
    for name in ("results.csv", "results.json"):
        assert (again.out_dir / name).read_bytes() == (study.out_dir / name).read_bytes(), name
    for n in (4, 8):
        for kind in ("ideal", "counts"):
            assert (again.out_dir / "captures" / f"array_{n:02d}" / kind / "manifest.json").is_file()


def test_scene_with_width_and_height(tmp_path):
    """Scenes without an `array` parameter get -D width=N -D height=N; no ground truth: no metrics."""
    import transient_mi  # noqa: F401
    from transient_mi.study import run_array_size_study

    r = run_array_size_study("nlos_point_targets", tmp_path / "s", arrays=(4, 6), exposure_s=1e-4,
                             defines={"spp": "16", "spots_x": "2", "spots_y": "2"}, voxels=(16, 16, 16),
                             progress=False)
    assert [row["pixels"] for row in r.rows] == [16, 36]
    assert all(row["chamfer_m"] is None for row in r.rows)
    assert "no error metrics" in r.summary.read_text()


@pytest.mark.parametrize("kwargs, match", [
    (dict(arrays=()), "arrays"),
    (dict(arrays=(4, 0)), "arrays=0"),
    (dict(arrays=(4, 4)), "distinct"),
    (dict(exposure_s=0.0), "exposure_s"),
    (dict(defines={"array": "8"}), "set by the study"),
    (dict(voxels=0), "voxels"),
    (dict(ground_truth="/no/such/mesh.ply"), "does not exist"),
])
def test_bad_arguments_fail_before_any_work(tmp_path, kwargs, match):
    import transient_mi  # noqa: F401
    from transient_core.errors import UserInputError
    from transient_mi.study import run_array_size_study

    kw = dict(TINY)
    kw.update(kwargs)
    with pytest.raises(UserInputError, match=match):
        run_array_size_study("paper_mannequin", tmp_path / "out" / "study", **kw)
    assert not (tmp_path / "out").exists()
