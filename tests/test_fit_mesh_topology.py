"""``transient-mi fit --model mesh`` on generated hidden shapes of other topology (transient_mi/scenes/topology.py):
the scenes' ground truth, and a small fit from the defaults on the holed plate.

Every test here is deterministic (quadrature renders, a fixed detection seed): no false-failure rate to state.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import transient_mi  # noqa: F401  (before mitsuba/drjit)
from transient_core.errors import UserInputError
from transient_mi.fit import FitSettings, fit_capture
from transient_mi.fit.mesh_fit import MeshSettings
from transient_mi.scene_mesh import hidden_mesh
from transient_mi.scenes.topology import (HOLE_RADIUS_M, PLATE_SIDE_M, TOPOLOGY_SHAPES, topology_mesh,
                                          write_topology_scene)


def test_generated_scenes_hold_their_shapes(tmp_path):
    """The written scene's hidden geometry (what the fit's metrics compare with) is the generated mesh (float32
    in the PLY); the chair is six closed boxes of the stated sizes, the holed plate a square less the hole's
    48-gon; the same call writes the same bytes; an unknown name is refused in one line."""
    import trimesh

    for name in TOPOLOGY_SHAPES:
        xml = write_topology_scene(name, tmp_path / "a")
        v, f, ids = hidden_mesh(xml)
        v0, f0 = topology_mesh(name)
        assert ids == [name] and np.array_equal(f, f0)
        np.testing.assert_allclose(v, v0, atol=1e-7)
        write_topology_scene(name, tmp_path / "b")
        for ext in ("xml", "ply"):
            assert (tmp_path / "a" / f"{name}.{ext}").read_bytes() == (tmp_path / "b" / f"{name}.{ext}").read_bytes()
    parts = trimesh.Trimesh(*topology_mesh("chair"), process=True).split(only_watertight=False)  # (corners merged)
    assert len(parts) == 6 and all(p.is_watertight and p.volume > 0 for p in parts)
    vol = 0.3 * 0.03 * 0.2 + 0.3 * 0.23 * 0.03 + 4 * 0.03 * 0.18 * 0.03
    assert math.isclose(sum(p.volume for p in parts), vol, rel_tol=1e-9)
    plate = trimesh.Trimesh(*topology_mesh("holed_plate"), process=False)
    hole = 24 * HOLE_RADIUS_M ** 2 * math.sin(2 * math.pi / 48)
    assert math.isclose(plate.area, PLATE_SIDE_M ** 2 - hole, rel_tol=1e-9)
    assert np.all(plate.face_normals[:, 2] < 0)  # (one-sided, facing the wall)
    with pytest.raises(UserInputError, match="allowed: chair, holed_plate"):
        write_topology_scene("torus", tmp_path)


@pytest.fixture(scope="module")
def holed_plate_capture(tmp_path_factory):
    """The holed plate on 4 x 4 pixels of 8 cm, one laser spot, 200 bins of 32 ps, the paper's detector for
    10 ms (seed 0); rendered by the quadrature (4 cm elements, 2 cells; about 2 s)."""
    from spad_detector import detect_stack
    from transient_mi.paper import paper_detector
    from transient_mi.render_capture import render

    d = tmp_path_factory.mktemp("holed_plate")
    ideal = render(write_topology_scene("holed_plate", d / "scene"), d / "ideal", progress=False,
                   defines={"spots_x": "1", "spots_y": "1", "aperture_diameter_m": "0.005", "estimator": "quadrature",
                            "element_size_m": "0.04", "patch_cells": "2", "width": "4", "height": "4",
                            "pixel_footprint_m": "0.08", "n_bins": "200", "bin_width_ps": "32", "t0_ps": "10500"})
    return detect_stack(ideal, d / "counts", paper_detector(), exposure_s=0.01, seed=0, progress=False)


def test_fit_from_the_defaults_improves_the_holed_plate_and_repeats_bit_for_bit(holed_plate_capture, tmp_path):
    """The mesh fit at its defaults (the backprojection's front surface at 4 cm, the 8-iteration alignment, two
    rings grown and 40 carving iterations with the total-variation prior, two stages) with a small budget (2 vertex
    iterations, 6 cm elements; about 25 s), twice in one process: the voxel IoU against the holed plate rises from
    the start's, and the second fit writes the first's ``fitted.ply`` and ``fit.json`` metrics byte for byte.
    Measured: IoU 0.057 -> 0.32 aligned -> 0.31 fitted, Chamfer 5.52 -> 5.72 cm aligned -> 6.21 cm fitted (with the
    cell's curvature in the quadrature's spread, 2026-12-08; before it 0.27 fitted and 5.30 cm aligned, and before
    the element slope 0.35, 4.61 and 4.86 cm: on this capture, 8 cm pixels of 2 cells, one spot, the cells' part
    dominates the forward model's error, each change to it moves the alignment's few steps elsewhere, and the
    aligned surface's Chamfer distance is not determined by its 16 pixels: it is not asserted here; the
    alignment's recovery of a plane's tilt is, on 8 x 8 pixels, in ``tests/test_fit_mesh.py``). Threshold: IoU at
    least 3x the start's. The repeat guards the carving's reverse pass: before its Dr.Jit scatter-adds ran in a fixed order
    (``ordered_sums`` in ``_nlos_quadrature_ad``, 2026-12-07) the carving's L-BFGS-B amplified their last-bit
    differences and three fits in one process gave three meshes (IoU 0.31 to 0.33, Chamfer 5.2 to 5.4 cm). The
    fit's Chamfer is not asserted: on this capture (one spot, 4 x 4 pixels) the carving drops faces by light it
    barely resolves, so the last-bit differences between machines' floating point could move it as far (5.0 to
    5.9 cm in four runs with the unordered sums). The silhouette IoU is not asserted either: on one spot the fit
    cannot open the hole (docs/fit.md)."""
    runs = []
    for k in range(2):
        res = fit_capture(holed_plate_capture, tmp_path / f"fit{k}", model="mesh", bin_width_ps=32.0, progress=False,
                          log=lambda *a: None, settings=FitSettings(iterations=2, sigma_start_ps=120.0,
                                                                    element_size_m=0.06),
                          mesh=MeshSettings())
        runs.append(res["metrics"])
    m = runs[0]
    assert m["fit"]["iou"] >= 3 * m["start"]["iou"], m
    assert runs[1] == runs[0]
    assert (tmp_path / "fit1" / "fitted.ply").read_bytes() == (tmp_path / "fit0" / "fitted.ply").read_bytes()
