"""The detector step of dataset items.

``test_detector_step_wiring`` replaces ``spad_detector.detect_stack`` by
a recording wrapper bound to the real function's signature and checks what the
item worker asks of it and where the counts land.
``test_detector_step_with_the_real_detector`` runs the real model on a tiny
NLOS capture (the detector and the NLOS scenes ship with the package: never
skipped).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from transient_core import stack
from transient_mi.dataset import expand_items, item_status, parse_spec
from transient_mi.dataset.index import item_row
from transient_mi.dataset.worker import build_item

SMALL = {"width": 8, "height": 8, "n_bins": 50, "bin_width_ps": 600}


def _recording_detect_stack(calls: list):
    """A stand-in for ``detect_stack`` that takes exactly the real one's arguments (bound with its
    ``inspect.signature``, so a call the real function would refuse fails here too), records them, and writes
    Poisson counts (the real model needs an NLOS capture; the wiring test renders a small camera scene)."""
    import inspect

    from spad_detector import detect_stack as real

    sig = inspect.signature(real)

    def detect_stack(*args, **kwargs):
        bound = sig.bind(*args, **kwargs)
        bound.apply_defaults()
        a = dict(bound.arguments)
        ideal_dir, out_dir, params = Path(a["ideal_dir"]), Path(a["out_dir"]), a["params"]
        calls.append(dict(a, ideal_dir=ideal_dir, out_dir=out_dir))
        m, data = stack.read_stack(ideal_dir)
        rng = np.random.default_rng(a["seed"])
        counts = rng.poisson(np.clip(data, 0, None) * params.pde * a["pulses"]).astype(np.uint32)
        cm = dict(m, kind="counts", quantity="counts", status="incomplete",
                  detector={"pde": params.pde, "pulses": a["pulses"], "seed": a["seed"]}, source_ideal="ideal")
        for j in range(m["n_files"]):
            stack.write_spot(out_dir, j, counts[j], cm)
        stack.write_manifest(out_dir, dict(cm, status="complete"))
        return out_dir

    return detect_stack


def test_detector_step_wiring(tmp_path, monkeypatch):
    import spad_detector

    calls: list = []
    monkeypatch.setattr(spad_detector, "detect_stack", _recording_detect_stack(calls))
    spec = parse_spec({"scene": "cornell_box", "seed": 4, "spp": 2, "defines": SMALL,
                       "detector": {"pulses": 1000, "engine": "analytic"},
                       "grid": {"detector.pde": [0.3, 0.9]}})
    items = expand_items(spec, variant="llvm_ad_mono", scene_sha256="0" * 64)
    items_dir = tmp_path / "items"
    items_dir.mkdir()
    for it in items:
        res = build_item({"record": it.record, "items_dir": str(items_dir), "scene_file": str(spec.scene_file),
                          "threads": None})
        assert res["status"] == "built"
    assert [c["params"].pde for c in calls] == [0.3, 0.9]
    for it, call in zip(items, calls):
        d = items_dir / it.name
        assert call["pulses"] == 1000 and call["exposure_s"] is None and call["engine"] == "analytic"
        assert call["seed"] == it.record["detector"]["seed"] and call["progress"] is False
        # the layout of `transient-mi render` with a spad_film: counts in capture/, ideal in capture/ideal/
        assert call["ideal_dir"].name == "ideal" and call["ideal_dir"].parent == call["out_dir"]
        assert call["out_dir"].name == "capture" and call["out_dir"].parent.name.startswith(".tmp-" + it.name)
        mc, counts = stack.read_stack(d / "capture")
        mi_, ideal = stack.read_stack(d / "capture" / "ideal")
        assert mc["kind"] == "counts" and counts.dtype == np.uint32 and mi_["kind"] == "ideal"
        assert counts.sum() > 0
        assert item_status(d, it.params_sha256) == "valid"
        row = item_row(d, tmp_path)
        assert row["kind"] == "counts" and row["detector_seed"] == it.record["detector"]["seed"]
        assert row["capture"] == f"items/{it.name}/capture" and row["ideal"] == f"items/{it.name}/capture/ideal"
        assert row["detector.pde"] == call["params"].pde and row["detector.pulses"] == 1000
        rec = json.loads((d / "params.json").read_text())
        assert rec["commands"][-1].split(" -o ")[1].startswith("capture/ideal ")
    assert calls[0]["seed"] != calls[1]["seed"]


def test_detector_step_with_the_real_detector(tmp_path):
    spec = parse_spec({"scene": "nlos_point_targets", "seed": 2, "spp": 4,
                       "defines": {"width": 4, "height": 4, "spots_x": 2, "spots_y": 2, "n_bins": 128,
                                   "bin_width_ps": 64},
                       "detector": {"pulses": 100000},
                       "grid": {"detector.pde": [0.35, 0.7]}})
    items = expand_items(spec, variant="llvm_ad_mono", scene_sha256="0" * 64)
    items_dir = tmp_path / "items"
    items_dir.mkdir()
    for it in items:
        build_item({"record": it.record, "items_dir": str(items_dir), "scene_file": str(spec.scene_file),
                    "threads": None})
    c = []
    for it in items:
        d = items_dir / it.name
        m, counts = stack.read_stack(d / "capture")
        assert m["kind"] == "counts" and counts.dtype == np.uint32 and counts.shape == (4, 4, 4, 128)
        assert m["detector"]["pde"] == it.record["detector"]["params"]["pde"]
        assert m["detector"]["seed"] == it.record["detector"]["seed"] and m["detector"]["pulses"] == 100000
        assert stack.read_manifest(d / "capture" / "ideal")["kind"] == "ideal"
        assert item_status(d, it.params_sha256) == "valid"
        c.append(int(counts.sum()))
    assert c[1] > c[0] > 0  # twice the detection efficiency, more counts


def _spad_film_scene(tmp_path: Path) -> Path:
    """nlos_point_targets.xml with its transient_film turned into a spad_film (the detector in the scene)."""
    from transient_mi.scenes import scene_path

    text = scene_path("nlos_point_targets").read_text()
    assert text.count('<film type="transient_film">') == 1
    text = text.replace('<film type="transient_film">',
                        '<film type="spad_film">\n            <integer name="pulses" value="100000"/>')
    p = tmp_path / "spad_scene.xml"
    p.write_text(text)
    return p


def test_scene_with_a_spad_film_gives_counts_items(tmp_path):
    from transient_mi.dataset.runner import validate_scene

    scene = _spad_film_scene(tmp_path)
    spec = parse_spec({"scene": str(scene), "seed": 2, "spp": 4,
                       "defines": {"width": 4, "height": 4, "spots_x": 2, "spots_y": 2, "n_bins": 128,
                                   "bin_width_ps": 64}})
    (it,) = expand_items(spec, variant="llvm_ad_mono", scene_sha256="0" * 64)
    validate_scene(spec, [it])
    items_dir = tmp_path / "items"
    items_dir.mkdir()
    build_item({"record": it.record, "items_dir": str(items_dir), "scene_file": str(spec.scene_file),
                "threads": None})
    d = items_dir / it.name
    m, counts = stack.read_stack(d / "capture")
    assert m["kind"] == "counts" and counts.dtype == np.uint32
    assert stack.read_manifest(d / "capture" / "ideal")["kind"] == "ideal"
    row = item_row(d, tmp_path)
    assert row["kind"] == "counts" and row["ideal"] == f"items/{it.name}/capture/ideal"
    assert row["detector_seed"] == m["detector"]["seed"] is not None
    # detector settings in the spec as well would detect twice: refused before any work
    both = parse_spec({"scene": str(scene), "spp": 4, "defines": {"width": 4, "height": 4},
                       "detector": {"pulses": 1000}})
    from transient_core.errors import UserInputError

    with pytest.raises(UserInputError, match="has a spad_film, which runs the detector itself"):
        validate_scene(both, expand_items(both, variant="llvm_ad_mono", scene_sha256="0" * 64))
