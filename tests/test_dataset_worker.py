"""The per-item worker, in-process: item layout, skips, a lost race, one-thread scene loading."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from transient_mi.dataset import expand_items, item_status, parse_spec
from transient_mi.dataset import worker as w

ROOT = Path(__file__).resolve().parents[1]
MESH_SCENE = ROOT / "tests" / "data" / "dataset_mesh_scene.xml"


@pytest.fixture()
def mannequin_item(tmp_path):
    spec = parse_spec({"scene": str(MESH_SCENE), "seed": 8, "spp": 2, "object": {"kind": "mannequin", "detail": 8}})
    (item,) = expand_items(spec, variant="llvm_ad_mono", scene_sha256="0" * 64)
    items_dir = tmp_path / "items"
    items_dir.mkdir()
    task = {"record": item.record, "items_dir": str(items_dir), "scene_file": str(spec.scene_file), "threads": 2}
    return item, items_dir, task


def test_item_layout_and_skip(mannequin_item):
    item, items_dir, task = mannequin_item
    assert w.build_item(task)["status"] == "built"
    d = items_dir / item.name
    res = json.loads((d / "result.json").read_text())
    # a camera scene: no variance files by default (docs/noise.md)
    assert sorted(res["files"]) == ["capture/manifest.json", "capture/preview.png", "capture/spot_00000.exr",
                                    "mesh.ply", "params.json"]
    assert json.loads((d / "params.json").read_text()) == item.record
    assert item_status(d, item.params_sha256) == "valid"
    assert item_status(d, "f" * 64) == "other"
    before = {p: p.stat().st_mtime_ns for p in d.rglob("*")}
    assert w.build_item(task)["status"] == "existed"
    assert {p: p.stat().st_mtime_ns for p in d.rglob("*")} == before
    assert [p.name for p in items_dir.iterdir()] == [item.name]


def test_losing_a_race_keeps_the_finished_item(mannequin_item, monkeypatch):
    """A second attempt of a finished item (a worker thought dead was not) leaves the first one in place."""
    item, items_dir, task = mannequin_item
    w.build_item(task)
    d = items_dir / item.name
    first = (d / "capture" / "spot_00000.exr").stat().st_ino
    real = w.item_status
    calls = []

    def blind_once(path, sha=None):  # the second attempt does not see the finished item at its start
        calls.append(path)
        return "missing" if len(calls) == 1 else real(path, sha)

    monkeypatch.setattr(w, "item_status", blind_once)
    assert w.build_item(task)["status"] == "existed"
    assert len(calls) == 2  # it built, failed to rename onto the finished item, and checked it
    assert (d / "capture" / "spot_00000.exr").stat().st_ino == first
    assert [p.name for p in items_dir.iterdir()] == [item.name]  # its temporary directory is gone


def test_failure_leaves_no_item_and_no_temporary(mannequin_item, monkeypatch):
    item, items_dir, task = mannequin_item
    import transient_mi.render_capture as pipeline

    def broken(*a, **k):
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(pipeline, "run_render", broken)
    with pytest.raises(RuntimeError, match="disk on fire"):
        w.build_item(task)
    assert list(items_dir.iterdir()) == []


def test_scene_loads_on_one_thread_and_renders_on_all(mannequin_item, monkeypatch):
    """Mitsuba's vertex normals of a normal-less PLY differ in the last bits when computed on several
    threads (parallel float adds); items load their scene on one thread so the same item gives the same bytes."""
    import drjit as dr

    import mitsuba as mi

    import transient_mi.render_capture as pipeline
    import transient_mi.scene_io as scene_io

    item, items_dir, task = mannequin_item
    seen = {}
    real_load, real_run = mi.load_file, pipeline.run_render

    def load(*a, **k):
        seen["load"] = dr.thread_count()
        return real_load(*a, **k)

    def run(*a, **k):
        seen["render"] = dr.thread_count()
        return real_run(*a, **k)

    monkeypatch.setattr(scene_io.mi, "load_file", load)
    monkeypatch.setattr(pipeline, "run_render", run)
    monkeypatch.delenv(w.THREADS_ENV, raising=False)
    try:
        w.build_item(task)
    finally:
        w._THREADS_SET = None
    assert seen == {"load": 1, "render": 2}


def test_an_item_renders_on_the_workers_share_of_threads(mannequin_item, monkeypatch):
    """The task's threads set numba's count on the thread that builds the item (the quadrature's kernels), not only
    drjit's: two workers on two cores each render on one thread of each, not on both beside the other."""
    import numba

    import transient_mi.render_capture as pipeline

    item, items_dir, task = mannequin_item
    seen = {}
    real_run = pipeline.run_render

    def run(*a, **k):
        seen["numba"] = numba.get_num_threads()
        return real_run(*a, **k)

    monkeypatch.setattr(pipeline, "run_render", run)
    monkeypatch.delenv(w.THREADS_ENV, raising=False)
    before = numba.get_num_threads()
    try:
        w.build_item(dict(task, threads=1))
    finally:
        w._THREADS_SET = None
        numba.set_num_threads(before)
    assert seen == {"numba": 1}


def test_ground_truth_only_object_matches_the_mannequin_the_scene_builds(tmp_path):
    """``define: null``: the paper scene builds its mannequin from $pose/$distance/$rotation, the worker
    writes the same mesh as ground truth and passes no mesh path."""
    import numpy as np
    import trimesh

    import transient_mi  # noqa: F401
    from transient_mi.scene_io import load_scene
    from transient_mi.scenes import scene_path

    spec = parse_spec({
        "scene": "paper_mannequin", "seed": 3, "spp": 2,
        "defines": {"array": 4, "n_bins": 50, "bin_width_ps": 100, "estimator": "monte_carlo", "pose": "${object.pose}",
                    "distance": "${object.position_z}", "rotation": "${object.rotation_deg}"},
        "object": {"kind": "mannequin", "define": None, "pose": "arms_raised", "position_z": 0.55,
                   "rotation_deg": 10.0},
    })
    (item,) = expand_items(spec, variant="llvm_ad_mono", scene_sha256="0" * 64)
    assert "define.mesh" not in item.record["parameters"] and item.record["object"]["define"] is None
    items_dir = tmp_path / "items"
    items_dir.mkdir()
    task = {"record": item.record, "items_dir": str(items_dir), "scene_file": str(spec.scene_file), "threads": 2}
    assert w.build_item(task)["status"] == "built"
    gt = trimesh.load(items_dir / item.name / "mesh.ply", force="mesh")
    scene = load_scene(scene_path("paper_mannequin"), {k[len("define."):]: str(v) for k, v in
                                                       item.record["parameters"].items() if k.startswith("define.")})
    (shape,) = [s for s in scene.shapes() if s.id() == "mannequin"]
    v = np.asarray(shape.vertex_positions_buffer()).reshape(-1, 3)
    np.testing.assert_allclose(np.sort(v, axis=0), np.sort(np.asarray(gt.vertices), axis=0), atol=1e-6)
