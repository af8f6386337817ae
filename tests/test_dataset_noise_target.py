"""A dataset spec's ``noise_target``: every item rendered to a rendering / photon noise ratio at its detector
budget (``render --noise-target``), by refinement for quadrature captures and by samples for Monte Carlo ones;
``result.json`` and the index say which estimator made each capture. Small renders (seconds)."""

from __future__ import annotations

import json

import pytest

from transient_core import stack
from transient_core.errors import UserInputError
from transient_mi.dataset import expand_items, parse_spec
from transient_mi.dataset.index import item_row
from transient_mi.dataset.worker import build_item

#: The letter at 4 x 4 pixels, one spot, 64 ps bins, coarse elements: a quadrature render of about a second.
LETTER = {"width": 4, "height": 4, "spots_x": 1, "spots_y": 1, "n_bins": 96, "bin_width_ps": 64,
          "element_size_m": 0.04, "patch_cells": 2}


def _spec(**changes):
    d = {"scene": "nlos_letter", "seed": 1, "defines": dict(LETTER), "detector": {"pulses": 1000},
         "noise_target": 0.1}
    d.update(changes)
    return parse_spec({k: v for k, v in d.items() if v is not None})


def _build(spec, tmp_path):
    (item,) = expand_items(spec, variant="llvm_ad_mono", scene_sha256="0" * 64)
    items_dir = tmp_path / "items"
    items_dir.mkdir()
    build_item({"record": item.record, "items_dir": str(items_dir), "scene_file": str(spec.scene_file),
                "threads": None})
    d = items_dir / item.name
    return d, json.loads((d / "result.json").read_text()), stack.read_manifest(d / "capture" / "ideal")


def test_noise_target_is_recorded_only_when_given_and_needs_a_detector():
    with_target = expand_items(_spec(), variant="llvm_ad_mono", scene_sha256="0" * 64)[0].record
    without = expand_items(_spec(noise_target=None), variant="llvm_ad_mono", scene_sha256="0" * 64)[0].record
    assert with_target["noise_target"] == 0.1 and "noise_target" not in without
    assert with_target["params_sha256"] != without["params_sha256"]
    assert "--noise-target 0.1 --pulses 1000" in with_target["commands"][-1]
    assert "--noise-target" not in without["commands"][-1]
    with pytest.raises(UserInputError, match="noise_target: 0.1 needs a detector section"):
        _spec(detector=None)
    for bad in (0, -1, "0.1", True, float("inf")):
        with pytest.raises(UserInputError, match="noise_target: .*expected a finite number > 0"):
            _spec(noise_target=bad)


def test_quadrature_item_is_refined_to_the_target_and_says_so(tmp_path):
    # a tight target at a large budget: the first round misses it, refinement meets it (or reports that it did not)
    spec = _spec(detector={"pulses": 10**7}, noise_target=0.01)
    item_dir, res, m = _build(spec, tmp_path)
    nt = m["render"]["noise_target"]
    assert m["render"]["estimator"] == "quadrature" and res["estimator"] == "quadrature"
    assert res["spp_used"] is None  # no samples to count
    assert res["noise_target"] == {"target": 0.01, "met": nt["met"]}
    (spot,) = nt["spots"]
    assert spot["rounds"] > 1 and spot["element_size_m"] < LETTER["element_size_m"] and spot["ratio"] >= 0
    assert spot["met"] == (spot["ratio"] <= 0.01)
    # detect's ratio of the counts is the render's, carried through the same detector and budget
    assert res["render_noise_ratio"] == pytest.approx(spot["ratio"], rel=1e-6)
    assert item_row(item_dir, tmp_path)["estimator"] == "quadrature"


def test_monte_carlo_item_renders_the_samples_its_pilot_asks_for(tmp_path):
    spec = _spec(spp=16, defines=dict(LETTER, estimator="monte_carlo"), detector={"pulses": 10**5})
    _, res, m = _build(spec, tmp_path)
    (spot,) = m["render"]["noise_target"]["spots"]
    assert res["estimator"] == "monte_carlo" and res["spp_used"] == spot["spp"] >= 16
    assert res["noise_target"]["met"] == spot["met"]
