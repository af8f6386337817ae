"""The fits' visibility memo (``transient_mi._visibility_memo``): a capture model traces each of
the quadrature's visibility rays once per mesh geometry, and what it serves from the memo is what it would have
traced.

The model mesh here is two tilted grids, the nearer one hiding part of the farther one from the wall, so the masks
hold occluded samples. Every render is the quadrature's (deterministic) and the detection seed is fixed: the
comparisons are of bytes, with no false-failure rate to state.
"""

from __future__ import annotations

import contextlib
import hashlib

import numpy as np
import pytest

import transient_mi  # noqa: F401  (before mitsuba/drjit)
from transient_mi.fit import FitSettings
from transient_mi.fit.mesh_fit import _capture_model
from transient_mi._visibility_memo import VisibilityMemo, current
from mesh_helpers import tilted_grid


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    """The tilted plane's scene rendered by the quadrature on 4 x 4 pixels of 10 cm with 2 x 2 laser spots,
    detected with the paper's detector for 10 ms (seed 0): a counts capture for the model."""
    from spad_detector import detect_stack
    from transient_mi.paper import paper_detector
    from transient_mi.render_capture import render
    from transient_mi.scenes import scene_path

    d = tmp_path_factory.mktemp("memo")
    ideal = render(scene_path("nlos_tilted_plane"), d / "ideal", progress=False,
                   defines={"spots_x": "2", "spots_y": "2", "aperture_diameter_m": "0.005", "estimator": "quadrature",
                            "element_size_m": "0.04", "patch_cells": "2", "width": "4", "height": "4",
                            "pixel_footprint_m": "0.1", "n_bins": "512", "bin_width_ps": "16", "t0_ps": "9000"})
    return detect_stack(ideal, d / "counts", paper_detector(), exposure_s=0.01, seed=0, progress=False)


def _two_grids(shift_m: float = 0.0):
    """A 5 x 5-vertex grid of 36 cm at 55 cm and a 3 x 3-vertex one of 14 cm at 40 cm in front of it (moved
    ``shift_m`` sideways): ``(vertices, faces)``."""
    v1, f1 = tilted_grid(5, 0.36, 20.0, 0.55)
    v2, f2 = tilted_grid(3, 0.14, 0.0, 0.40)
    v2 = v2 + np.array([0.05 + shift_m, 0.03, 0.0])
    return np.concatenate([v1, v2]), np.concatenate([f1, f2 + len(v1)])


def _model(capture, v, f):
    return _capture_model(capture, v, f, FitSettings(element_size_m=0.04), 16.0, "face")


def _digest(*arrays) -> str:
    return hashlib.sha1(b"".join(np.ascontiguousarray(a).tobytes() for a in arrays)).hexdigest()


def _forward_and_reverse(cap, v, rho) -> str:
    """Digest of the ideal capture and the vertex and reflectance derivatives of a fixed residual's pairing."""
    cap.set_mesh(v, rho)
    ideal = cap.ideal(0, 0, 30.0)
    factor = cap.dead_time_factor(ideal)
    resid = cap.objective(cap.expected_counts(ideal, factor), 30.0)[1]
    gv, gr = cap.backward(resid, ideal, 0, 0, 30.0, factor, vertices=True)
    return _digest(ideal, gv, gr)


def test_renders_served_from_the_memo_equal_traced_ones_bit_for_bit(capture):
    """One model renders and differentiates the two grids twice (the second time every visibility ray is served
    from the memo: no new trace); a model whose memo is switched off gives the same bytes, and some of the masks
    it kept mark occluded samples (the test exercises occlusion)."""
    v, f = _two_grids()
    rho = np.linspace(0.3, 0.9, len(f))
    cap = _model(capture, v, f)
    first = _forward_and_reverse(cap, v, rho)
    misses, hits = cap.visibility.misses, cap.visibility.hits
    assert misses > 0 and hits > 0  # (the reverse pass already took the forward pass's masks)
    assert any((m != 15).any() for m in cap.visibility._masks.values())
    again = _forward_and_reverse(cap, v, rho[::-1].copy())
    assert cap.visibility.misses == misses and cap.visibility.hits > hits
    off = _model(capture, v, f)
    off._held_geometry = contextlib.nullcontext
    assert _forward_and_reverse(off, v, rho) == first
    assert _forward_and_reverse(off, v, rho[::-1].copy()) == again
    assert off.visibility.hits == off.visibility.misses == 0


def test_a_moved_mesh_is_traced_again(capture, monkeypatch):
    """After the nearer grid moves 4 cm, the model's render equals a new model's (the memo forgot the old
    geometry's masks), and moving it back gives the first render's bytes. Chunks of 8 elements, so that the farther
    grid's visibility is traced in calls without the nearer grid's samples: their arguments are the same before
    and after the move, their masks not."""
    from transient_mi.integrators import _nlos_pairs

    monkeypatch.setattr(_nlos_pairs, "PAIRS_PER_CHUNK", 8 * 64)  # (64 cells: 4 x 4 pixels of 2 x 2 cells)
    v, f = _two_grids()
    moved, _ = _two_grids(0.04)
    rho = np.full(len(f), 0.6)
    cap = _model(capture, v, f)
    first = _forward_and_reverse(cap, v, rho)
    misses = cap.visibility.misses
    assert _forward_and_reverse(cap, moved, rho) == _forward_and_reverse(_model(capture, moved, f), moved, rho)
    assert cap.visibility.misses > misses
    assert _forward_and_reverse(cap, v, rho) == first


def test_the_memo_is_served_after_a_variant_change(capture):
    """A variant change re-imports the plug-in sub-packages' modules (``transient_mi._registry``); the memo's context
    variable must be the one the quadrature reads afterwards too (when the memo lived in ``transient_mi.integrators``
    it was imported twice and the fit's renders traced everything again; found by the CI's test order)."""
    import transient_mi

    before = transient_mi.variant()
    other = "llvm_ad_mono_polarized" if before != "llvm_ad_mono_polarized" else "llvm_ad_rgb"
    transient_mi.set_variant(other)
    transient_mi.set_variant(before)
    v, f = _two_grids()
    cap = _model(capture, v, f)
    _forward_and_reverse(cap, v, np.full(len(f), 0.5))
    assert cap.visibility.misses > 0 and cap.visibility.hits > 0


def test_the_memo_keeps_one_geometry_within_its_bytes_and_only_while_active():
    """Masks are kept per geometry (a new one forgets them), not past ``max_bytes``, and a memo serves only inside
    its ``active`` block."""
    memo = VisibilityMemo(max_bytes=100)
    assert current() is None
    origins, samples = np.zeros((2, 3)), np.ones((3, 4, 3))
    assert memo.key(None, origins, (0, 0, 1), samples, None, False) is None  # (no geometry stated yet)
    memo.set_geometry(np.arange(6.0))
    k = memo.key(None, origins, (0, 0, 1), samples, None, False)
    assert k != memo.key(None, origins, (0, 0, 1), samples, np.arange(3), False)
    memo.put(k, np.full(6, 15, dtype=np.uint8))
    got = memo.get(k)
    assert got.tolist() == [15] * 6 and memo.hits == 1
    got[:] = 0  # (a copy: the memo's masks stay)
    assert memo.get(k).tolist() == [15] * 6
    big = memo.key(None, origins + 1, (0, 0, 1), samples, None, False)
    memo.put(big, np.zeros(200, dtype=np.uint8))
    assert memo.get(big) is None
    memo.set_geometry(np.arange(6.0))  # (the same geometry: kept)
    assert memo.get(k) is not None
    memo.set_geometry(np.arange(6.0) + 1e-3)
    assert memo.get(memo.key(None, origins, (0, 0, 1), samples, None, False)) is None
    with memo.active():
        assert current() is memo
    assert current() is None
