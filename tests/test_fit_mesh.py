"""``transient-mi fit --model mesh`` (transient_mi/fit/mesh_*.py): the regularisers' and the parametrisation's
gradients, the regularised objective's gradient against central differences of the deterministic forward model,
a fit that recovers a displaced plane, and the refusals.

The capture: `scenes/nlos_tilted_plane.xml` (a 40 cm square 50 cm behind the wall, turned 30 degrees about the
vertical) rendered by the quadrature (deterministic) on 4 x 4 pixels of 10 cm, one laser spot, the paper's
detector for 10 ms. Every test here is deterministic (quadrature renders, fixed detection seed): no
false-failure rate to state.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import transient_mi  # noqa: F401  (before mitsuba/drjit)
from transient_core.errors import UserInputError
from transient_mi.fit import FitSettings, fit_capture
from transient_mi.fit.mesh_fit import MeshSettings, _capture_model
from transient_mi.fit.mesh_model import MeshModel
from transient_mi.fit.mesh_optimize import regularized_objective
from transient_mi.fit.mesh_regularizers import MeshTopology, RegularizerWeights, regularizer
from mesh_helpers import tilted_grid

ROOT = Path(__file__).resolve().parents[1]
SETTINGS = FitSettings(iterations=2, sigma_start_ps=60.0, element_size_m=0.05)


_grid = tilted_grid


def _tilted_plane_counts(tmp_path_factory, name: str, **defines):
    """The tilted plane rendered by quadrature (4 cm elements, 2 cells; one laser spot, 5 mm aperture) with
    ``defines`` on top, detected with the paper's detector for 10 ms (seed 0): the counts capture's directory."""
    from spad_detector import detect_stack
    from transient_mi.paper import paper_detector
    from transient_mi.render_capture import render
    from transient_mi.scenes import scene_path

    d = tmp_path_factory.mktemp(name)
    ideal = render(scene_path("nlos_tilted_plane"), d / "ideal", progress=False,
                   defines={"spots_x": "1", "spots_y": "1", "aperture_diameter_m": "0.005", "estimator": "quadrature",
                            "element_size_m": "0.04", "patch_cells": "2", **defines})
    return detect_stack(ideal, d / "counts", paper_detector(), exposure_s=0.01, seed=0, progress=False)


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    return _tilted_plane_counts(tmp_path_factory, "meshcap", width="4", height="4", pixel_footprint_m="0.1",
                                n_bins="300", bin_width_ps="16", t0_ps="9500")


def _fd_check(fun, x, g, h, rel):
    rng = np.random.default_rng(3)
    for _ in range(3):
        d = rng.normal(size=x.shape)
        fd = (fun(x + h * d) - fun(x - h * d)) / (2 * h)
        an = float(np.sum(g * d))
        assert abs(an - fd) <= rel * (abs(fd) + 1e-12), (an, fd)


def test_regularizer_gradient_equals_central_differences():
    """Closed-form gradient of the weighted energies against central differences (float64, step 1e-6 m:
    truncation ~1e-12 relative, rounding ~1e-10; tolerance 1e-6), on a perturbed closed sphere and an open
    grid (boundary-aware Laplacian)."""
    import trimesh

    rng = np.random.default_rng(0)
    s = trimesh.creation.icosphere(1, radius=0.2)
    w = RegularizerWeights(laplacian=1.0, edge=0.5, normal=0.7)
    for v, f in ((s.vertices + 0.01 * rng.normal(size=s.vertices.shape), s.faces),
                 (_grid(4, 0.3)[0] + 0.01 * rng.normal(size=(16, 3)), _grid(4, 0.3)[1])):
        topo = MeshTopology(f, len(v))
        _, g, _ = regularizer(v, topo, 0.1, w)
        _fd_check(lambda x: regularizer(x, topo, 0.1, w)[0], v, g, 1e-6, 1e-6)


def test_a_flat_grid_has_smoothness_energy_at_its_corners_only():
    """The boundary-aware Laplacian: interior vertices and straight boundaries of a flat grid have none, so the
    regulariser does not shrink a flat silhouette (the four corners are the boundary curve's own curvature)."""
    v, f = _grid(5, 0.4)
    topo = MeshTopology(f, len(v))
    lap = np.linalg.norm(topo.uniform @ v, axis=1)
    corners = [0, 4, 20, 24]
    assert np.all(lap[np.setdiff1d(np.arange(25), corners)] < 1e-12)
    assert np.all(lap[corners] > 0.01)
    assert regularizer(v, topo, 0.1, RegularizerWeights(0.0, 0.0, 1.0))[0] < 1e-12  # no folds


def test_large_steps_parametrisation_round_trip_and_chain_rule():
    """``x = M^{-1} u`` inverts ``u = M x``; the gradient in ``theta`` of a linear function of the vertices is
    ``M^{-1}`` times its vertex gradient (central differences, exact for a linear map up to rounding)."""
    v, f = _grid(5, 0.4)
    m = MeshModel(v, f, 0.5, smoothing=10.0, weights=RegularizerWeights(0.0, 0.0, 0.0))
    th = m.initial()
    assert np.allclose(m.vertices(th), v, atol=1e-12)
    c = np.random.default_rng(1).normal(size=v.shape)
    g = m.gradient(th, c, 0.0)
    _fd_check(lambda t: float(np.sum(c * m.vertices(t))), th, g, 1e-4, 1e-8)


def test_regularized_objective_gradient_against_central_differences(capture):
    """d(data + S R)/dtheta (the quadrature's vertex and reflectance derivative through the detector layer, the
    temporal blur and the large-steps map, plus the regularisers) against central differences of the same
    deterministic objective along random directions: steps of 0.25 mm (as the quadrature's own geometry
    tests; float32 histograms) and relative tolerance 2e-3; no occluder, so no visibility sample changes. Along
    the reflectance too: the free-mesh fit's detector layer differentiates its dead time (the whole blind
    cycles' factor ``1 / (1 + m P)``, RenewalExpectedCounts; measured 8e-5 from central differences of step
    0.01, their truncation). """
    v, f = _grid(3, 0.4)
    v = v + np.array([0.01, -0.01, 0.02]) + 0.005 * np.random.default_rng(2).normal(size=v.shape)
    cap = _capture_model(capture, v, f, SETTINGS, 16.0)
    cap.set_element_size(0.05)
    m = MeshModel(v, f, 0.6, smoothing=2.0, reg_scale=1.0)
    m.reg_scale = 0.01 * cap.objective(np.zeros_like(cap.counts), cap.jitter_sigma_ps)[0]
    th = m.initial()
    _, data, reg, g = regularized_objective(m, cap, th, 80.0)
    assert data > 0 and reg > 0

    def j(t):
        return regularized_objective(m, cap, t, 80.0, gradient=False)[0]

    rng = np.random.default_rng(4)
    h = 2.5e-4
    for _ in range(2):
        d = np.concatenate([rng.normal(size=len(th) - 1), [0.0]])
        d /= np.max(np.abs(d))
        fd = (j(th + h * d) - j(th - h * d)) / (2 * h)
        assert abs(float(g @ d) - fd) <= 2e-3 * abs(fd), (float(g @ d), fd)
    d = np.zeros_like(th)
    d[-1] = 1.0
    fd = (j(th + 0.01 * d) - j(th - 0.01 * d)) / 0.02
    assert abs(g[-1] - fd) <= 2e-3 * abs(fd), (g[-1], fd)


def test_fit_recovers_a_displaced_plane(capture, tmp_path):
    """Started from the true square's 4 x 4-vertex grid pushed 4 cm away from the wall (a ``--start-mesh``
    file), 24 iterations of the vertex stage alone (no alignment) bring it back: the surface-to-surface Chamfer distance falls below a third of the
    start's and the counts' Poisson NLL drops; every output is written."""
    from transient_mi.scenes._ply import write_ply

    v, f = _grid(4, 0.4)
    write_ply(tmp_path / "start.ply", v + np.array([0.0, 0.0, 0.04]), f)
    res = fit_capture(capture, tmp_path / "fit", model="mesh", bin_width_ps=16.0, progress=False, log=lambda *a: None,
                      settings=FitSettings(iterations=24, sigma_start_ps=120.0, element_size_m=0.05),
                      mesh=MeshSettings(start_mesh=str(tmp_path / "start.ply"), stages=1, cell_m=0.02,
                                        step_m=0.004, align=0, carve=0))
    m = res["metrics"]
    assert m["fit"]["chamfer_mesh_m"] < m["start"]["chamfer_mesh_m"] / 3, m
    assert res["poisson_nll"]["fit"] < res["poisson_nll"]["start"]
    for name in ("fit.json", "fitted.ply", "start.ply", "loss.png", "fit.png", "views.png", "checkpoint.json"):
        assert (tmp_path / "fit" / name).is_file(), name
    assert json.loads((tmp_path / "fit" / "fit.json").read_text())["estimator"]["used"] == "quadrature"


def test_fit_recovers_a_displaced_plane_from_a_confocal_capture(tmp_path_factory, tmp_path):
    """The same recovery from a confocal capture (each pixel's own patch lit in turn; 4 x 4 pixels): the Chamfer
    distance falls below a third of the start's and the NLL drops (measured 3.5 -> 0.32 cm)."""
    from transient_mi.scenes._ply import write_ply

    counts = _tilted_plane_counts(tmp_path_factory, "meshcap_confocal", capture="confocal", width="4", height="4",
                                  pixel_footprint_m="0.1", n_bins="300", bin_width_ps="16", t0_ps="9500")
    v, f = _grid(4, 0.4)
    write_ply(tmp_path / "start.ply", v + np.array([0.0, 0.0, 0.04]), f)
    res = fit_capture(counts, tmp_path / "fit", model="mesh", bin_width_ps=16.0, progress=False,
                      log=lambda *a: None,
                      settings=FitSettings(iterations=24, sigma_start_ps=120.0, element_size_m=0.05),
                      mesh=MeshSettings(start_mesh=str(tmp_path / "start.ply"), stages=1, cell_m=0.02, step_m=0.004,
                                        align=0, carve=0))
    m = res["metrics"]
    assert m["fit"]["chamfer_mesh_m"] < m["start"]["chamfer_mesh_m"] / 3, m
    assert res["poisson_nll"]["fit"] < res["poisson_nll"]["start"]


def test_resume_after_a_subdivision_stage(capture, tmp_path):
    """Two alignment iterations, two carving iterations (the aligned start grown by a ring of faces, subdivided, its
    dark faces dropped, the carved mesh realigned in one iteration),
    then two iterations in two stages (the carved mesh subdivided after the first); resuming the finished fit
    does nothing more; other settings are refused."""
    out = tmp_path / "fit"
    kw = dict(model="mesh", bin_width_ps=16.0, progress=False, log=lambda *a: None, settings=SETTINGS,
              mesh=MeshSettings(align=2, carve=2, grow=1))
    r1 = fit_capture(capture, out, **kw)
    carve = r1["carve"]
    assert carve["aligned_faces"] == r1["parameters"]["start"]["n_faces"] < carve["grown_faces"]  # (one ring)
    assert carve["subdivided_faces"] == 4 * carve["grown_faces"] and 0 < carve["kept"]
    assert r1["parameters"]["fit"]["n_faces"] == 4 * carve["kept"]
    assert len(r1["align"]["objective"]) == 2 and (out / "aligned.ply").is_file() and (out / "carved.ply").is_file()
    assert "carved" in r1["metrics"]
    # (the carved mesh realigned: one Levenberg-Marquardt iteration, half the alignment's two)
    assert carve["realigned"]["iterations"] == 1 and r1["time_s"]["realign"] > 0
    cj = json.loads((out / "carve.json").read_text())
    assert len(cj["cut_vertices"]) == len(cj["vertices"]) and len(cj["realigned"]["history"]) == 1
    r2 = fit_capture(capture, out, resume=True, **kw)
    assert len(r2["history"]["objective"]) == 2 and r2["carve"] == carve
    with pytest.raises(UserInputError, match="other settings"):
        fit_capture(capture, out, resume=True, **{**kw, "mesh": MeshSettings(stages=1, align=2, carve=2)})


@pytest.fixture(scope="module")
def capture_8x8(tmp_path_factory):
    """The tilted plane on 8 x 8 pixels of 4 cm, one laser spot, 250 bins of 32 ps, the paper's detector for
    10 ms (about 2 s to render)."""
    return _tilted_plane_counts(tmp_path_factory, "meshcap8", width="8", height="8", pixel_footprint_m="0.04",
                                n_bins="250", bin_width_ps="32", t0_ps="10500")


def _tilt_deg_and_depth(v):
    """Tilt about the vertical (degrees) and depth at x = y = 0 (m) of the least-squares plane through ``v``."""
    c = np.linalg.lstsq(np.c_[v[:, 0], v[:, 1], np.ones(len(v))], v[:, 2], rcond=None)[0]
    return math.degrees(math.atan(-c[0])), float(c[2])


def test_alignment_recovers_a_planes_tilt(capture_8x8):
    """The square turned 30 degrees about the vertical, started at half its tilt (15 degrees, same centre,
    same size, the reflectance matched to the counts as the fit does): 6 Levenberg-Marquardt iterations of the
    affine alignment (mesh_align, with the detector's whole-blind-cycles dead time) bring its tilt to within 4
    degrees and its centre's depth within 1.5 cm (measured: 26.9 degrees, 0.489 m, reflectance 0.63, in about
    20 s). The vertex stage (Adam) does not: from the same start 20 iterations (about 15 s) leave the tilt at 15.1
    degrees, move the plane 3 cm nearer and dim it (reflectance 0.52 -> 0.41; docs/fit.md). Deterministic
    (quadrature renders, a fixed detection seed)."""
    from transient_mi.fit.mesh_align import align_affine
    from transient_mi.fit.mesh_fit import _match_albedo, _model

    v, f = _grid(4, 0.4, tilt_deg=15.0)
    st = FitSettings(iterations=10, element_size_m=0.06)
    cap = _capture_model(capture_8x8, v, f, st, 32.0)
    cap.set_element_size(0.06)
    a0 = _match_albedo(_model(v, f, 0.5, MeshSettings(), 1.0), cap, st)
    cap.set_element_size(0.06)
    x, albedo, hist = align_affine(cap, v, a0, iterations=6, sigma_start_ps=120.0, sigma_end_ps=30.0)
    tilt, depth = _tilt_deg_and_depth(x)
    assert abs(tilt - 30.0) <= 4.0 and abs(depth - 0.5) <= 0.015, (tilt, depth, albedo)
    assert hist[-1][0] < hist[0][0]


@pytest.mark.parametrize("mesh,words", [
    (MeshSettings(start="middle"), ["--start", "middle", "front, closed"]),
    (MeshSettings(stages=5), ["stages=5", "1 to 3"]),
    (MeshSettings(align=-1), ["align=-1", "0 to 100"]),
    (MeshSettings(carve=500), ["carve=500", "0 to 200"]),
    (MeshSettings(grow=5), ["grow=5", "0 to 4"]),
    (MeshSettings(grow=True), ["grow=True", "0 to 4"]),
    (MeshSettings(carve_tv=-1.0), ["carve_tv=-1.0", ">= 0"]),
    (MeshSettings(cell_m=0.0), ["cell_m=0.0", "0.005 to 0.5"]),
    (MeshSettings(pixel_step=0), ["pixel_step=0", "1 to 16"]),
    (MeshSettings(pixel_step=3), ["--pixel-step 3", "4 x 4"]),
    (MeshSettings(start_mesh="/nonexistent/surface.ply"), ["--start-mesh", "no such file"]),
])
def test_bad_mesh_settings_are_refused_before_anything_is_written(capture, tmp_path, mesh, words):
    out = tmp_path / "fit"
    with pytest.raises(UserInputError) as e:
        fit_capture(capture, out, model="mesh", mesh=mesh, settings=SETTINGS, bin_width_ps=16.0, progress=False)
    msg = str(e.value)
    assert "\n" not in msg and all(w in msg for w in words), msg
    assert not out.exists() or not any(out.iterdir())


def test_cli_refusal_is_one_line(capture, tmp_path):
    r = subprocess.run([sys.executable, "-m", "transient_mi", "fit", str(capture), "-o", str(tmp_path / "fit"),
                        "--model", "mesh", "--stages", "0"], capture_output=True, text=True, cwd=ROOT)
    lines = [ln for ln in r.stderr.strip().splitlines() if ln]
    assert r.returncode != 0 and len(lines) == 1 and "Traceback" not in r.stderr, r.stderr
    assert "stages=0" in lines[0]


def test_grow_ring_adds_a_consistently_wound_ring_around_the_open_boundary():
    """:func:`~transient_mi.fit.mesh_start.grow_ring` on a 2 x 2 grid of unit squares tilted out of its plane: two
    faces per boundary edge (8 edges, 16 faces), every new vertex ``width`` from the boundary vertex it copies, in
    the surface's plane and outward (an edge vertex straight out, a corner along the diagonal), the winding of the
    old faces (every interior edge used once in each direction), the old vertices and faces first and unchanged;
    the grown mesh's boundary is one ring further out; a closed mesh is returned as it is."""
    from transient_mi.fit.mesh_start import grow_ring

    xs, ys = np.meshgrid(np.arange(3.0), np.arange(3.0), indexing="xy")
    flat = np.stack([xs.ravel(), ys.ravel(), np.zeros(9)], axis=1)
    turn = np.array([[1, 0, 0], [0, np.cos(0.4), -np.sin(0.4)], [0, np.sin(0.4), np.cos(0.4)]])
    v = flat @ turn.T + [0.1, -0.2, 0.5]
    q = [(r * 3 + c, r * 3 + c + 1, r * 3 + c + 4, r * 3 + c + 3) for r in range(2) for c in range(2)]
    f = np.array([t for a, b, c, d in q for t in ((a, b, c), (a, c, d))])
    v2, f2 = grow_ring(v, f, 0.5)
    assert np.array_equal(v2[:9], v) and np.array_equal(f2[:8], f)
    assert len(v2) == 9 + 8 and len(f2) == 8 + 16
    back = (v2[9:] - [0.1, -0.2, 0.5]) @ turn  # (in the grid's own frame)
    assert np.allclose(back[:, 2], 0.0, atol=1e-12)
    centre = np.array([1.0, 1.0])
    for old, new in zip(np.unique(np.concatenate([f[:, :2], f[:, 1:]]).ravel())[[0, 1, 2, 3, 5, 6, 7, 8]], back):
        p = flat[old, :2]
        out = p - centre
        step = new[:2] - p
        assert np.linalg.norm(step) == pytest.approx(0.5)
        # straight out from an edge's middle vertex, along the diagonal from a corner
        unit = np.sign(out) / np.linalg.norm(np.sign(out))
        assert np.allclose(step / 0.5, unit)

    def directed(faces):
        return np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])

    e = directed(f2)
    assert len({tuple(x) for x in e}) == len(e)  # (no edge twice in one direction: a consistent winding)
    normals = np.cross(v2[f2[:, 1]] - v2[f2[:, 0]], v2[f2[:, 2]] - v2[f2[:, 0]])
    assert (normals @ (turn @ [0, 0, 1.0]) > 0).all()
    und = np.sort(e, axis=1)
    _, counts = np.unique(und, axis=0, return_counts=True)
    assert (counts <= 2).all() and (counts == 1).sum() == 8  # (the new boundary: 8 edges, one ring out)
    tet_v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    tet_f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    tv, tf = grow_ring(tet_v, tet_f, 0.5)
    assert np.array_equal(tv, tet_v) and np.array_equal(tf, tet_f)


def test_orient_to_wall_mends_an_inconsistent_winding():
    """A start mesh with faces wound both ways (a box with one face flipped) comes out wound outwards: trimesh
    repairs the winding with networkx, a declared dependency (a fresh install without it failed here)."""
    import trimesh

    from transient_mi.fit.mesh_start import orient_to_wall

    box = trimesh.creation.box(extents=(0.2, 0.2, 0.2))
    v, f = np.asarray(box.vertices), np.asarray(box.faces).copy()
    f[0] = f[0, ::-1]
    assert not trimesh.Trimesh(vertices=v, faces=f, process=False).is_winding_consistent
    out = trimesh.Trimesh(vertices=v, faces=orient_to_wall(v, f), process=False)
    assert out.is_winding_consistent and out.volume > 0


def test_orient_to_wall_winds_a_leaky_closed_surface_outwards_and_a_sheet_towards_the_wall():
    """A closed surface that is not watertight (a sphere with two faces dropped, as clustering or the view check
    leave midpoint-fk's closed surface) wound inwards comes out wound outwards: its normals sum to about zero, so the
    open rule (the mean normal towards the wall) would wind it at random. A sheet facing away from the wall, and a
    bowl, come out facing the wall (-z)."""
    import trimesh

    from transient_mi.fit.mesh_start import CLOSED_NORMAL_SHARE, encloses_volume, orient_to_wall

    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.2)
    v, f = np.asarray(ball.vertices), np.asarray(ball.faces)[2:, ::-1].copy()  # (inwards, two faces gone)
    leaky = trimesh.Trimesh(vertices=v, faces=f, process=False)
    assert not leaky.is_watertight and leaky.volume < 0
    assert np.linalg.norm((leaky.face_normals * leaky.area_faces[:, None]).sum(0)) < CLOSED_NORMAL_SHARE * leaky.area
    assert trimesh.Trimesh(vertices=v, faces=orient_to_wall(v, f), process=False).volume > 0
    assert encloses_volume(v, f)
    sv, sf = _grid(4, 0.4, tilt_deg=20.0)
    assert not encloses_volume(sv, sf)
    for faces in (np.asarray(sf), np.asarray(sf)[:, ::-1]):
        out = trimesh.Trimesh(vertices=sv, faces=orient_to_wall(sv, faces), process=False)
        assert (out.face_normals[:, 2] < 0).all()
    bowl = v[:, 2] < 0.05  # (the sphere's half nearer the wall and a bit more: an open shell)
    bf = f[bowl[f].all(axis=1)]
    out = trimesh.Trimesh(vertices=v, faces=orient_to_wall(v, bf), process=False)
    assert float((out.face_normals[:, 2] * out.area_faces).sum()) < 0 and not encloses_volume(v, bf)


def test_a_closed_start_is_not_carved_by_default(capture, tmp_path):
    """A start mesh that encloses a volume (a closed box given as ``--start-mesh``) skips the carving by default
    (``carve=None``): no ``carve.json``, ``fit.json``'s ``carve`` empty; an explicit ``carve`` still carves it."""
    import trimesh

    from recon.surface import write_ply

    box = trimesh.creation.box(extents=(0.3, 0.3, 0.1))
    box.apply_translation((0.0, 0.0, 0.5))
    write_ply(tmp_path / "box.ply", np.asarray(box.vertices), np.asarray(box.faces))
    st = FitSettings(iterations=2, element_size_m=0.08)
    for carve, carved in ((None, False), (1, True)):
        out = tmp_path / f"fit_{carve}"
        res = fit_capture(capture, out, model="mesh", bin_width_ps=32.0, progress=False, log=lambda *x: None,
                          settings=st, mesh=MeshSettings(start_mesh=str(tmp_path / "box.ply"), cell_m=0.1, align=0,
                                                         stages=1, carve=carve))
        assert (res["carve"] is not None) == carved and (out / "carve.json").is_file() == carved


def test_a_step_into_the_detectors_view_is_halved(capture):
    """An Adam step that would move the mesh into a line of sight from the detector to a wall patch (the scene
    refuses such a mesh) is halved until it does not: the iterate lands on the segment towards the step's end,
    short of it, with every wall patch seen (found when the chair's fit stretched sideways into the view). A
    step that hides nothing is taken whole. Ray tests only (no render)."""
    from transient_mi.fit.mesh_optimize import MAX_STEP_HALVINGS, _keep_the_view, hides_a_wall_patch

    v, f = _grid(3, 0.2, tilt_deg=0.0)
    cap = _capture_model(capture, v, f, SETTINGS, 16.0)
    m = MeshModel(v, f, 0.5, smoothing=10.0)
    th = m.initial()
    # the device stands at (-0.9, -0.05, 1.2): its rays to the top row's wall patch corners (y = 0.2) cross
    # z = 0.8 at y = 0.033, x from -0.67 to -0.53 (the rays to the wall's centre pass below, at y = -0.033)
    into_view = m.theta_of(v + np.array([-0.6, 0.11, 0.3]), 0.5)
    assert not hides_a_wall_patch(cap, m.vertices(th), 0.5)
    assert hides_a_wall_patch(cap, m.vertices(into_view), 0.5)
    got = _keep_the_view(m, cap, th, into_view)
    frac = (got - th)[0] / (into_view - th)[0]
    assert 2.0 ** -MAX_STEP_HALVINGS <= frac < 1.0
    assert np.allclose(got, th + frac * (into_view - th))
    assert not hides_a_wall_patch(cap, m.vertices(got), 0.5)
    aside = m.theta_of(v + np.array([0.0, 0.0, 0.05]), 0.5)
    assert np.array_equal(_keep_the_view(m, cap, th, aside), aside)


def test_a_tail_mean_that_hides_a_wall_patch_gives_way_to_the_last_iterate(capture):
    """The fit is the mean of the tail's iterates; each iterate is kept clear of the detector's view, their mean
    need not be (the scene would refuse it at the final render): then the last iterate is the fit. Ray tests only."""
    from transient_mi.fit.mesh_optimize import fit_parameters, hides_a_wall_patch
    from transient_mi.fit.optimize import FitState

    v, f = _grid(3, 0.2, tilt_deg=0.0)
    cap = _capture_model(capture, v, f, SETTINGS, 16.0)
    m = MeshModel(v, f, 0.5, smoothing=10.0)
    th = m.initial()
    into_view = m.theta_of(v + np.array([-0.6, 0.11, 0.3]), 0.5)  # (as above: hides the top row's patches)
    clear = m.theta_of(v + np.array([0.0, 0.0, 0.05]), 0.5)
    assert hides_a_wall_patch(cap, m.vertices(into_view), 0.5)
    hiding_mean = FitState(theta=th.tolist(), tail_sum=(2 * into_view).tolist(), tail_count=2)
    assert np.array_equal(fit_parameters(m, cap, hiding_mean), th)
    clear_mean = FitState(theta=th.tolist(), tail_sum=(clear + th).tolist(), tail_count=2)
    assert np.array_equal(fit_parameters(m, cap, clear_mean), (clear + th) / 2)


def test_a_start_across_the_devices_view_loses_those_faces(capture):
    """A start mesh partly across the detector's lines of sight to the wall patches (the scene would refuse it)
    loses the faces the lines cross and no others: what is left hides no patch; a start clear of the view comes
    back unchanged (found on a generated chair on 4 x 4 pixels, whose backprojection's front surface reached into
    the view). Ray tests only."""
    from transient_mi.fit.mesh_optimize import hides_a_wall_patch
    from transient_mi.fit.mesh_start import clear_view, device_sight_lines

    v, f = _grid(5, 0.4, tilt_deg=0.0)
    v = v + np.array([-0.6, 0.11, 0.3])  # (as in the test above: across the top row's corners' lines of sight)
    cap = _capture_model(capture, v, f, SETTINGS, 16.0)
    assert hides_a_wall_patch(cap, v, 0.5)
    lines = device_sight_lines(cap.sensor, cap.scene, cap.width, cap.height)
    assert len(lines[0]) == 1 + 16 * 4 + 16 + 1  # (target, corners, centres, one laser spot)
    v1, f1 = clear_view(v, f, *lines)
    assert 0 < len(f1) < len(f)
    cap1 = _capture_model(capture, v1, f1, SETTINGS, 16.0)
    assert not hides_a_wall_patch(cap1, v1, 0.5)
    clear = _grid(5, 0.4)
    v2, f2 = clear_view(*clear, *lines)
    assert v2 is clear[0] and f2 is clear[1]


def _winged_square(wing_m: float = 0.1, cell_m: float = 0.1):
    """The tilted plane's true square (40 cm, turned 30 degrees, centred 50 cm deep) on a grid of ``cell_m``, with a
    coplanar wing of ``wing_m`` beyond its edge at ``+u`` (the edge nearer the wall): ``(vertices, faces, wing)``,
    ``wing`` a bool per face (its centroid beyond the square)."""
    su = np.arange(-0.2, 0.2 + wing_m + 1e-9, cell_m)
    sv = np.arange(-0.2, 0.2 + 1e-9, cell_m)
    u, v = np.meshgrid(su, sv)
    a = math.radians(30.0)
    x = np.stack([u.ravel() * math.cos(a), v.ravel(), 0.5 - u.ravel() * math.sin(a)], axis=1)
    n = len(su)
    f = []
    for j in range(len(sv) - 1):
        for i in range(n - 1):
            q = j * n + i
            f += [[q, q + n + 1, q + 1], [q, q + n, q + n + 1]]
    f = np.array(f)
    u_c = (u.ravel()[f]).mean(axis=1)
    return x, f, u_c > 0.2


def _carve_faces(capture, matched, carved, iterations: int = 40, tv_weight: float | None = None):
    """The carving step by hand: the reflectance matched to the counts on ``matched`` ``(v, f)`` as the fit does,
    then ``iterations`` per-face reflectance steps on ``carved`` ``(v, f)`` with the prior's weight ``tv_weight``
    (default: the fit's): ``(start, rho, history, keep)``."""
    from transient_mi.fit.mesh_carve import TV_WEIGHT, fit_face_reflectance, keep_faces
    from transient_mi.fit.mesh_fit import _match_albedo, _model

    st = FitSettings(iterations=10, element_size_m=0.06)
    a0 = _match_albedo(_model(*matched, 0.5, MeshSettings(), 1.0), _capture_model(capture, *matched, st, 32.0), st)
    cap = _capture_model(capture, *carved, st, 32.0, "face")
    cap.keep_blur(30.0)
    rho, hist = fit_face_reflectance(cap, carved[0], a0, iterations, 30.0, faces=carved[1],
                                     tv_weight=TV_WEIGHT if tv_weight is None else tv_weight)
    return a0, rho, hist, keep_faces(rho)


def test_a_grown_ring_inside_the_square_is_kept_and_the_ring_beyond_it_darkened(capture_8x8):
    """Growing then carving (mesh_start.grow_ring, mesh_carve) from the tilted plane's central 20 cm (2 x 2
    cells of 10 cm, 8 faces, the reflectance matched to the counts as the fit does): two rings of 10 cm, the
    first inside the true 40 cm square, the second outside it; 40 per-face reflectance iterations (L-BFGS-B,
    each reflectance in [0, RHO_MAX], the fit's total-variation prior) keep at least 14 of the first ring's 16
    faces, keep at most 10 of the second's, and leave the second ring's mean reflectance under 0.6 of the
    first's (measured: 16 kept; 8 kept, means 0.38 and 0.80; two of the second ring's faces at 0; without the
    prior the same counts, 0.375 and 0.80). The second ring's faces that stay are the ones this capture barely
    sees (one spot, 8 x 8 pixels): little light to judge them by, the limit docs/fit.md states. Deterministic."""
    from transient_mi.fit.mesh_carve import RHO_MAX
    from transient_mi.fit.mesh_start import grow_ring

    v, f, _ = _winged_square(wing_m=0.0, cell_m=0.1)
    inner = (np.abs(v[:, 1]) < 0.15) & (np.abs(v[:, 0] / math.cos(math.radians(30.0))) < 0.15)  # (|u|, |v| <= 0.1)
    index = np.cumsum(inner) - 1
    v0, f0 = v[inner], index[f[inner[f].all(axis=1)]]
    assert len(f0) == 8
    v1, f1 = grow_ring(v0, f0, 0.1)
    v2, f2 = grow_ring(v1, f1, 0.1)
    first, second = np.arange(8, len(f1)), np.arange(len(f1), len(f2))
    assert len(first) == 16 and len(second) == 16
    a0, rho, hist, keep = _carve_faces(capture_8x8, (v0, f0), (v2, f2))
    msg = (f"start {a0:.3f}; centre {np.round(rho[:8], 3)}; first ring {np.round(rho[first], 3)}; second ring "
           f"{np.round(rho[second], 3)}; objective {hist[0][0]:.4g} -> {hist[-1][0]:.4g}")
    assert hist[-1][0] < hist[0][0], msg
    assert rho.min() >= 0.0 and rho.max() <= RHO_MAX, msg
    assert keep[first].sum() >= 14, msg
    assert keep[second].sum() <= 10, msg
    assert rho[second].mean() < 0.6 * rho[first].mean(), msg


def test_carving_drops_a_spurious_wing_and_keeps_the_square(capture_8x8):
    """The carving step (mesh_carve) on the true square with a coplanar 10 cm wing beyond its near edge (the
    reflectance matched to the counts as the fit does, one per face from there): 40 per-face reflectance iterations
    (L-BFGS-B) lower the objective, darken every wing face below half the square's, and the cut drops all 8 wing faces
    and keeps at least 28 of the square's 32, with the fit's total-variation prior and without it (measured with it:
    wing 0-0.030, square 0.57-0.81 against 0.8, all 32 kept; without: wing 0-0.041, square 0.50-0.96; with the ISRA
    steps of 2026-12-05 after 15: wing 0.006-0.15). The prior evens the square's faces, which are one material:
    their standard deviation with it is under 0.8 of the one without (measured 0.060 against 0.092). Deterministic."""
    from transient_mi.fit.mesh_carve import drop_faces

    v, f, wing = _winged_square()
    assert wing.sum() == 8 and (~wing).sum() == 32
    spread = []
    for tv_weight in (None, 0.0):
        a0, rho, hist, keep = _carve_faces(capture_8x8, (v, f), (v, f), tv_weight=tv_weight)
        msg = (f"prior {tv_weight}: start {a0:.3f}; square {np.round(rho[~wing], 3)}; wing {np.round(rho[wing], 3)}; "
               f"objective {hist[0][0]:.4g} -> {hist[-1][0]:.4g} in {len(hist) - 1} steps")
        assert hist[-1][0] < hist[0][0], msg
        assert rho[wing].max() < 0.5 * np.median(rho[~wing]), msg
        assert not keep[wing].any() and keep[~wing].sum() >= 28, msg
        spread.append(float(np.std(rho[~wing])))
        vk, fk = drop_faces(v, f, keep)
        assert len(fk) == keep.sum() and fk.max() == len(vk) - 1 and np.allclose(vk[fk], v[f[keep]])
    assert spread[0] < 0.8 * spread[1], spread


def test_a_fit_on_every_second_pixel_renders_and_compares_those_pixels_only(capture_8x8, tmp_path):
    """``pixel_step=2`` (``--pixel-step 2``): the fit's capture model holds the 4 x 4 pixels ``(2 j, 2 i)`` of the
    8 x 8 capture (its counts are theirs, bin for bin), renders them exactly as the full model renders those pixels,
    and a short fit runs through alignment, carving and the vertex stage on them and says so in ``fit.json``.
    Deterministic (quadrature renders, a fixed detection seed)."""
    v, f = _grid(4, 0.4, tilt_deg=30.0)
    st = FitSettings(iterations=2, element_size_m=0.06)
    full = _capture_model(capture_8x8, v, f, st, 32.0)
    half = _capture_model(capture_8x8, v, f, st, 32.0, "global", 2)
    assert (half.width, half.height) == (4, 4) and half.pixel_step == 2
    keep = (np.arange(8)[:, None] % 2 == half.pixel_offset) & (np.arange(8)[None, :] % 2 == half.pixel_offset)
    np.testing.assert_array_equal(half.counts, full.counts[:, keep.ravel()])
    for cap in (full, half):
        cap.set_element_size(0.06)
        cap.set_mesh(v, 0.6)
    a = full.ideal(0, 0, full.jitter_sigma_ps)[:, keep.ravel()]
    b = half.ideal(0, 0, half.jitter_sigma_ps)
    assert a.sum() > 0
    np.testing.assert_allclose(b, a, rtol=1e-5, atol=1e-6 * float(a.max()))
    res = fit_capture(capture_8x8, tmp_path / "fit", model="mesh", bin_width_ps=32.0, progress=False,
                      log=lambda *x: None, settings=st, mesh=MeshSettings(align=1, carve=1, grow=0, stages=1,
                                                                           pixel_step=2))
    assert res["config"]["mesh"]["pixel_step"] == 2 and (tmp_path / "fit" / "fitted.ply").is_file()


@pytest.mark.parametrize("width, height, step", [(32, 32, 4), (16, 16, 2), (8, 8, 1), (64, 64, 8), (48, 32, 4),
                                                 (30, 30, 3), (4, 4, 1)])
def test_the_default_pixel_step_keeps_eight_pixels_per_side(width, height, step):
    """``pixel_step=None`` (no ``--pixel-step``): the largest step dividing both sides that keeps
    :data:`~transient_mi.fit.gauss_newton.MIN_PIXELS` (8) pixels along each, as the Gauss-Newton fit; a step given is
    kept."""
    from transient_mi.fit.gauss_newton import MIN_PIXELS
    from transient_mi.fit.mesh_settings import resolve_pixel_step

    assert MIN_PIXELS == 8
    assert resolve_pixel_step(MeshSettings(), width, height).pixel_step == step
    assert resolve_pixel_step(MeshSettings(pixel_step=1), width, height).pixel_step == 1
