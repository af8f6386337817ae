"""``transient-mi fit --model mesh --reflectance face``: a reflectance per face of the free mesh.

The forward model reads it as the model mesh's face attribute ``face_reflectance`` (a ``mesh_attribute``
texture); these tests check that one value per face renders as the single reflectance does, that the
quadrature's derivative with respect to every face's reflectance matches central differences, the smoothness
energy's gradient, and that a fit of a two-tone plate (its PLY carrying the faces' reflectance as the scene's
own face attribute) finds the brighter half brighter, writes the values into ``fitted.ply`` where Mitsuba's
loader reads them, and carries them across a subdivision stage and a resume. Every render here is the
quadrature's (deterministic) and the detection seed is fixed: no false-failure rate to state.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import transient_mi  # noqa: F401  (before mitsuba/drjit)
from transient_core.errors import UserInputError
from transient_mi.fit import FitSettings, fit_capture
from transient_mi.fit.mesh_fit import FACE_PLY_PROPERTY, MeshSettings, _capture_model
from transient_mi.fit.mesh_model import MeshModel
from transient_mi.fit.mesh_regularizers import (MeshTopology, albedo_regularizer, outline_weights,
                                                reflectance_total_variation)
from mesh_helpers import tilted_grid

ROOT = Path(__file__).resolve().parents[1]
DARK, BRIGHT = 0.3, 0.8


def _grid(n: int, side: float, tilt_deg: float = 30.0, z: float = 0.5):
    """The tilted plane's grid (:func:`mesh_helpers.tilted_grid`) and each face's side of the plane's horizontal
    midline (-1 below, +1 above: both halves span the same depths, so their light arrives in the same bins; split
    along the tilt, the farther half's arrives after the nearer's and the paper's detector, piled up by then,
    holds little of it)."""
    x, f = tilted_grid(n, side, tilt_deg, z)
    return x, f, np.sign(x[f, 1].mean(axis=1))


@pytest.fixture(scope="module")
def two_tone(tmp_path_factory):
    """The tilted plane's scene with its square replaced by a 7 x 7-vertex PLY grid whose faces carry their
    reflectance (0.3 on one half, 0.8 on the other: the property ``reflectance_0``, the face attribute
    ``face_reflectance`` through a ``mesh_attribute`` texture), rendered by the quadrature on 4 x 4 pixels of 10
    cm, 2 x 2 laser spots, and detected with the paper's detector for 10 ms (seed 0). Returns ``(counts
    directory, vertices, faces, side of each face)``."""
    from spad_detector import detect_stack
    from transient_mi.paper import paper_detector
    from transient_mi.render_capture import render
    from transient_mi.scenes import scene_path
    from transient_mi.scenes._ply import write_ply

    d = tmp_path_factory.mktemp("two_tone")
    v, f, side_of = _grid(7, 0.4)
    rho = np.where(side_of > 0, BRIGHT, DARK)
    write_ply(d / "two_tone.ply", v, f, {FACE_PLY_PROPERTY: rho})
    xml = Path(scene_path("nlos_tilted_plane")).read_text()
    i0 = xml.index('<shape type="rectangle" id="tilted_plane">')
    i1 = xml.index("</shape>", i0) + len("</shape>")
    xml = xml[:i0] + ('<shape type="ply" id="two_tone"><string name="filename" value="two_tone.ply"/>'
                      '<bsdf type="diffuse"><texture type="mesh_attribute" name="reflectance">'
                      '<string name="name" value="face_reflectance"/></texture></bsdf></shape>') + xml[i1:]
    scene = d / "two_tone.xml"
    scene.write_text(xml)
    ideal = render(scene, d / "ideal", progress=False,
                   defines={"spots_x": "2", "spots_y": "2", "aperture_diameter_m": "0.005", "estimator": "quadrature",
                            "element_size_m": "0.04", "patch_cells": "2", "width": "4", "height": "4",
                            "pixel_footprint_m": "0.1", "n_bins": "512", "bin_width_ps": "16", "t0_ps": "9000"})
    counts = detect_stack(ideal, d / "counts", paper_detector(), exposure_s=0.01, seed=0, progress=False)
    return counts, v, f, side_of


def test_albedo_regularizer_gradient_and_zero_on_a_uniform_mesh():
    """The smoothness energy is 0 for one reflectance everywhere, and its closed-form gradient matches central
    differences (a quadratic: exact up to rounding; tolerance 1e-8)."""
    v, f, _ = _grid(4, 0.3)
    pairs = MeshTopology(f, len(v)).face_pairs
    assert len(pairs) > 0
    e0, g0 = albedo_regularizer(np.full(len(f), 0.4), pairs, 0.5)
    assert e0 == 0.0 and np.all(g0 == 0.0)
    rho = np.random.default_rng(0).uniform(0.2, 0.9, len(f))
    e, g = albedo_regularizer(rho, pairs, 0.5)
    d = np.random.default_rng(1).normal(size=len(f))
    h = 1e-5
    fd = (albedo_regularizer(rho + h * d, pairs, 0.5)[0] - albedo_regularizer(rho - h * d, pairs, 0.5)[0]) / (2 * h)
    assert abs(float(g @ d) - fd) <= 1e-8 * abs(fd), (float(g @ d), fd)


def test_total_variation_gradient_and_a_step_costs_its_height():
    """The carving's prior (:func:`reflectance_total_variation` with :func:`outline_weights`): 0 for one
    reflectance everywhere; its closed-form gradient matches central differences (smooth; relative tolerance 1e-6 at
    a step of 1e-6); a step between the two halves of the grid costs its closed form, the height (rounded within
    ``delta``) times the outline's length over the square root of the area, the same on a grid of 6 x 6 faces and
    of 12 x 12; and it grows with the height, not its square (a step of 0.8 against 0.4, far above ``delta`` =
    0.01: 2.03 times the cost, where the square costs 4 times)."""
    side = 0.4
    costs = []
    for n in (7, 13):
        v, f, side_of = _grid(n, side)
        topo = MeshTopology(f, len(v))
        pairs, w = topo.face_pairs, outline_weights(v, topo)
        e0, g0 = reflectance_total_variation(np.full(len(f), 0.4), pairs, w, 0.05)
        assert e0 == 0.0 and np.all(g0 == 0.0)
        rho = np.random.default_rng(0).uniform(0.0, 1.0, len(f))
        e, g = reflectance_total_variation(rho, pairs, w, 0.05)
        d = np.random.default_rng(1).normal(size=len(f))
        h = 1e-6
        fd = (reflectance_total_variation(rho + h * d, pairs, w, 0.05)[0]
              - reflectance_total_variation(rho - h * d, pairs, w, 0.05)[0]) / (2 * h)
        assert abs(float(g @ d) - fd) <= 1e-6 * abs(fd), (float(g @ d), fd)
        costs.append([reflectance_total_variation(np.where(side_of > 0, c, 0.0), pairs, w, 0.01)[0]
                      for c in (0.4, 0.8)])
        sq = [albedo_regularizer(np.where(side_of > 0, c, 0.0), pairs, 1.0)[0] for c in (0.4, 0.8)]
        assert sq[1] / sq[0] == pytest.approx(4.0, rel=1e-12)
    # (the grid is side x side, its midline side long: the outline over the square root of the area)
    assert costs[0][0] == pytest.approx((np.hypot(0.4, 0.01) - 0.01) * side / np.sqrt(side * side), rel=1e-9)
    assert costs[1] == pytest.approx(costs[0], rel=1e-9)
    ratio = (np.hypot(0.8, 0.01) - 0.01) / (np.hypot(0.4, 0.01) - 0.01)  # (2.03)
    assert costs[0][1] / costs[0][0] == pytest.approx(ratio, rel=1e-12) and ratio < 2.05


def test_one_reflectance_per_face_renders_as_the_single_reflectance(two_tone):
    """The capture model with ``reflectance="face"`` and every face at 0.6 gives the same ideal capture as the
    single reflectance 0.6 (the same quadrature pairs; float32 histograms: 1e-6 of the largest bin)."""
    counts, v, f, _ = two_tone
    st = FitSettings(iterations=2, element_size_m=0.05)
    caps = [_capture_model(counts, v, f, st, 16.0, r) for r in ("global", "face")]
    out = []
    for cap in caps:
        cap.set_element_size(0.05)
        cap.set_mesh(v, 0.6)
        out.append(cap.ideal(0, 0, 40.0))
    assert out[0].max() > 0
    np.testing.assert_allclose(out[1], out[0], rtol=0, atol=1e-6 * out[0].max())


def test_face_reflectance_gradient_against_central_differences(two_tone):
    """``backward``'s derivative of ``<w, ideal>`` with respect to each face's reflectance against central
    differences of the deterministic render (step 0.05: the capture is linear in each reflectance, so the
    difference is exact up to the float32 histograms), for the faces of both halves; tolerance 1e-3 relative to
    the largest."""
    counts, v, f, side_of = two_tone
    st = FitSettings(iterations=2, element_size_m=0.05)
    cap = _capture_model(counts, v, f, st, 16.0, "face")
    cap.set_element_size(0.05)
    rho = np.where(side_of > 0, 0.7, 0.4)
    cap.set_mesh(v, rho)
    ideal = cap.ideal(0, 0, 40.0)
    w = np.random.default_rng(5).uniform(0.5, 1.5, ideal.shape)
    factor = np.ones_like(ideal)

    class _Identity:  # (the derivative of <w, ideal> itself: no detector layer)
        def probabilities(self, ref):
            return None

        def vjp(self, ref, g, probabilities=None):
            return g

    cap.layers = [_Identity() for _ in range(cap.n_spots)]
    _, gr = cap.backward(w, ideal, 0, 0, 40.0, factor)
    assert gr.shape == (len(f),)
    faces = [int(np.flatnonzero(side_of > 0)[3]), int(np.flatnonzero(side_of < 0)[5]), 0]
    h = 0.05
    for k in faces:
        vals = []
        for s in (1, -1):
            r = rho.copy()
            r[k] += s * h
            cap.set_mesh(v, r)
            vals.append(float(np.sum(w * cap.ideal(0, 0, 40.0))))
        fd = (vals[0] - vals[1]) / (2 * h)
        assert abs(gr[k] - fd) <= 1e-3 * np.abs(gr).max(), (k, gr[k], fd)


def test_fit_finds_the_brighter_half_and_writes_it_where_mitsuba_reads_it(two_tone, tmp_path):
    """From the true geometry with one reflectance, 0.5 (no alignment, small vertex steps), 40 iterations in two
    stages with ``reflectance="face"``: the faces of the bright half come out brighter than those of the dark half
    (their means' ratio above 1.15; measured 0.545 against 0.430, 1.27, where the truth's is 0.8 against 0.3: the
    reflectance converges slowly, docs/fit.md); the stage's subdivision gives each face's four children its value
    (``fitted.ply`` has four times the faces); ``fitted.ply`` carries them as ``reflectance_0``, which Mitsuba
    loads as the face attribute ``face_reflectance``; ``fit.json`` summarises them; a resume of the finished fit
    does nothing more."""
    import mitsuba as mi

    from transient_mi.scenes._ply import write_ply

    counts, v, f, side_of = two_tone
    write_ply(tmp_path / "start.ply", v, f)
    kw = dict(model="mesh", bin_width_ps=16.0, progress=False, log=lambda *a: None,
              settings=FitSettings(iterations=40, sigma_start_ps=60.0, element_size_m=0.05),
              mesh=MeshSettings(start_mesh=str(tmp_path / "start.ply"), stages=2, cell_m=0.02, step_m=0.0005,
                                align=0, reflectance="face"))
    res = fit_capture(counts, tmp_path / "fit", **kw)
    fit = res["parameters"]["fit"]
    assert fit["reflectance"] == "face" and fit["albedo_min"] < fit["albedo"] < fit["albedo_max"]
    assert fit["n_faces"] == 4 * len(f)
    m = mi.load_dict({"type": "ply", "filename": str(tmp_path / "fit" / "fitted.ply")})
    rho = np.asarray(mi.traverse(m)["face_reflectance"], dtype=np.float64)
    assert len(rho) == 4 * len(f)
    child_side = np.repeat(side_of, 4)  # (each face's four children follow it: mesh_start.subdivide's order)
    bright, dark = rho[child_side > 0].mean(), rho[child_side < 0].mean()
    assert bright > 1.15 * dark, (bright, dark)
    assert res["poisson_nll"]["fit"] < res["poisson_nll"]["start"]
    assert "albedo" in res["regularizer"]["parts_at_fit"]
    r2 = fit_capture(counts, tmp_path / "fit", resume=True, **kw)
    assert len(r2["history"]["objective"]) == 40
    assert json.loads((tmp_path / "fit" / "fit.json").read_text())["parameters"]["fit"]["reflectance"] == "face"


@pytest.mark.parametrize("mesh,words", [
    (MeshSettings(reflectance="vertex"), ["--reflectance", "vertex", "global, face"]),
    (MeshSettings(albedo_smoothness=-1.0), ["albedo_smoothness=-1.0", ">= 0"]),
])
def test_bad_reflectance_settings_are_refused_in_one_line(two_tone, tmp_path, mesh, words):
    counts = two_tone[0]
    out = tmp_path / "fit"
    with pytest.raises(UserInputError) as e:
        fit_capture(counts, out, model="mesh", mesh=mesh, settings=FitSettings(iterations=2), bin_width_ps=16.0,
                    progress=False)
    msg = str(e.value)
    assert "\n" not in msg and all(w in msg for w in words), msg
    assert not out.exists() or not any(out.iterdir())


def test_mesh_model_keeps_a_reflectance_per_face():
    """``theta`` holds the vertices' block then one reflectance per face; a single start value is given to every
    face; the gradient's reflectance block is the data's plus the smoothness energy's."""
    v, f, _ = _grid(3, 0.3)
    m = MeshModel(v, f, 0.5, reflectance="face", reg_scale=2.0)
    th = m.initial()
    assert len(th) == 3 * len(v) + len(f) and np.all(m.albedo(th) == 0.5)
    th[m.n_u:] = np.linspace(0.3, 0.7, len(f))
    g = m.gradient(th, np.zeros_like(v), np.ones(len(f)))
    _, ga, _ = m.albedo_regularization(th)
    np.testing.assert_allclose(g[m.n_u:], 1.0 + ga)
    with pytest.raises(ValueError):
        MeshModel(v, f, np.ones(3), reflectance="face")


def test_cli_reflectance_refusal_is_one_line(two_tone, tmp_path):
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "transient_mi", "fit", str(two_tone[0]), "-o", str(tmp_path / "fit"),
                        "--model", "mesh", "--reflectance", "vertex"], capture_output=True, text=True, cwd=ROOT)
    lines = [ln for ln in r.stderr.strip().splitlines() if ln]
    assert r.returncode != 0 and len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert "--reflectance 'vertex'" in lines[0] and "global, face" in lines[0]
