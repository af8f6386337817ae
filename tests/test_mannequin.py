"""The procedural mannequin, its PLY output, the ground-truth depth/silhouette
helpers and the ``transient-mi mannequin`` command."""

from __future__ import annotations

import itertools
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from transient_core.errors import UserInputError
from recon.ground_truth import ground_truth_depth_map, ground_truth_silhouette
from transient_core.units import C_M_PER_PS
from transient_mi.fit.mesh_start import ray_triangles
from transient_mi.scenes import mannequin as mq

ROOT = Path(__file__).resolve().parents[1]

# The figure's extreme points along y are vertices of the primitives (poles of
# axis-aligned spheres and ellipsoids: the crown, the soles), so the height
# equals the requested one up to float64 rounding of a few operations on numbers
# of order 1 m: 1e-9 m is a thousand times that rounding and a million times
# smaller than anything a renderer resolves.
EXACT_M = 1e-9


def _hand_sagitta_m(height_m: float, detail: int = 20) -> float:
    """How much narrower than ``width_m`` the tessellated figure may be: the arms are rigid bones rotated
    about the shoulder, so the hand's tessellated sphere (radius ``r``, ``n`` segments around; every
    direction lies within ``2 pi / n`` of one of its vertices) reaches at least ``r cos(2 pi / n)`` along
    +-x, not ``r``: per side at most ``r (1 - cos(2 pi / n))``."""
    n = 4 * math.ceil(detail / 4)
    return height_m * mq._ARM[-1][1] * (1.0 - math.cos(2.0 * math.pi / n))


def _width_ok(extent_x: float, width_m: float, height_m: float) -> bool:
    return -EXACT_M <= width_m - extent_x <= 2.0 * _hand_sagitta_m(height_m) + EXACT_M
# float32 positions in the PLY file: 0.5 ulp at 0.6 m is 3e-8 m.
FLOAT32_M = 1e-7


def _arrays_equal(a: trimesh.Trimesh, b: trimesh.Trimesh) -> bool:
    return a.vertices.shape == b.vertices.shape and np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)


# --- the mesh -----------------------------------------------------------------


@pytest.mark.parametrize("pose", list(mq.POSES))
def test_every_pose_is_one_watertight_outward_solid(pose):
    m = mq.make_mannequin(pose=pose)
    assert m.is_watertight and m.is_winding_consistent
    assert m.body_count == 1
    assert m.volume > 0  # outward normals
    assert m.euler_number == 2  # a sphere-like surface: no handles, no holes
    assert 1000 <= len(m.faces) <= 6000  # "a few thousand faces" at the default detail
    assert len(m.metadata["face_part"]) == len(m.faces)
    assert set(m.metadata["face_part"]) == set(mq.PARTS)


def test_default_is_the_papers_60_by_70_cm_mannequin_50_cm_behind_the_wall():
    m = mq.make_mannequin()
    (x0, y0, z0), (x1, y1, z1) = m.bounds
    assert _width_ok(x1 - x0, 0.60, 0.70)  # width across the arms (up to the hands' tessellation)
    assert abs((y1 - y0) - 0.70) < EXACT_M  # sole to crown
    assert abs((x1 + x0) / 2) < EXACT_M and abs((y1 + y0) / 2) < EXACT_M  # centred on (0, 0)
    assert 0.10 < z1 - z0 < 0.25  # a body, not a cut-out
    assert 0.35 < z0 < 0.45 < 0.5 < z1 < 0.6  # about 50 cm behind the wall, all in z > 0
    torso = mq.mannequin_parts()["torso"]
    assert abs(torso.bounds[:, 2].mean() - 0.5) < EXACT_M  # position z is the torso's mid-depth


@pytest.mark.parametrize("height_m,width_m", [(1.8, 1.2), (0.5, 0.2), (0.7, 0.7)])
def test_extents_follow_height_and_width(height_m, width_m):
    m = mq.make_mannequin(height_m=height_m, width_m=width_m, position=(0.1, 0.2, 1.5))
    ext = m.extents
    assert _width_ok(ext[0], width_m, height_m) and abs(ext[1] - height_m) < EXACT_M
    assert abs(m.bounds[:, 1].mean() - 0.2) < EXACT_M and abs(m.bounds[:, 0].mean() - 0.1) < EXACT_M


def test_rest_arm_angle_gives_the_width_and_is_monotonic():
    lo, hi = mq.width_range_m(0.7)
    assert mq.rest_arm_angle_deg(0.7, lo) < 2.0
    assert abs(mq.rest_arm_angle_deg(0.7, hi) - 80.0) < 1e-9
    widths = np.linspace(lo, hi, 7)
    angles = [mq.rest_arm_angle_deg(0.7, w) for w in widths]
    assert np.all(np.diff(angles) > 0)
    assert 35 < mq.rest_arm_angle_deg(0.7, 0.6) < 50  # the paper's size: arms out, not horizontal


def test_same_parameters_same_bytes(tmp_path):
    params = dict(pose="one_arm_out", rotation_deg=17.0, position=(0.05, -0.02, 0.55))
    a = mq.write_mannequin(tmp_path / "a.ply", **params)
    mq._build.cache_clear()  # rebuild from scratch, not from the cache
    b = mq.write_mannequin(tmp_path / "b.ply", **params)
    assert a.read_bytes() == b.read_bytes()
    # and in a fresh process
    code = ("import sys; from transient_mi.scenes.mannequin import write_mannequin; "
            "write_mannequin(sys.argv[1], pose='one_arm_out', rotation_deg=17.0, position=(0.05, -0.02, 0.55))")
    r = subprocess.run([sys.executable, "-c", code, str(tmp_path / "c.ply")], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "c.ply").read_bytes() == a.read_bytes()
    other = mq.write_mannequin(tmp_path / "d.ply", pose="one_arm_out", rotation_deg=18.0, position=(0.05, -0.02, 0.55))
    assert other.read_bytes() != a.read_bytes()


def test_ply_round_trips_and_loads_in_mitsuba(tmp_path):
    path = mq.write_mannequin(tmp_path / "m.ply")
    assert not [p for p in tmp_path.iterdir() if p.name != "m.ply"]  # no temporary left
    mesh = mq.make_mannequin()
    back = trimesh.load(path, process=False)
    assert np.array_equal(back.faces, mesh.faces)
    assert np.max(np.abs(back.vertices - mesh.vertices)) < FLOAT32_M
    assert back.is_watertight
    assert path.stat().st_size < 200_000  # small: a few thousand faces

    import mitsuba as mi  # the variant was selected by importing transient_mi

    shape = mi.load_dict({"type": "ply", "filename": str(path)})
    assert shape.face_count() == len(mesh.faces) and shape.vertex_count() == len(mesh.vertices)
    bb = shape.bbox()
    assert np.allclose([bb.min.x, bb.min.y, bb.max.x, bb.max.y], [mesh.bounds[0, 0], -0.35, mesh.bounds[1, 0], 0.35],
                       atol=FLOAT32_M)
    assert _width_ok(bb.max.x - bb.min.x, 0.60, 0.70)
    assert math.isclose(shape.surface_area()[0], mesh.area, rel_tol=1e-5)


# --- parts, depths and arrival times ------------------------------------------------


def _group(parts: dict, names) -> trimesh.Trimesh:
    return trimesh.util.concatenate([parts[n] for n in names])


def _mean_three_bounce_ps(mesh: trimesh.Trimesh, spot, wall_point) -> float:
    """Area-weighted mean of (|S - o| + |o - P|) / c over the faces facing the wall (n_z < 0)."""
    sel = mesh.face_normals[:, 2] < 0
    o = mesh.triangles_center[sel]
    w = mesh.area_faces[sel]
    path = np.linalg.norm(o - spot, axis=1) + np.linalg.norm(o - wall_point, axis=1)
    return float(np.average(path, weights=w) / C_M_PER_PS)


def test_parts_are_watertight_and_cover_the_mannequin():
    parts = mq.mannequin_parts()
    assert list(parts) == list(mq.PARTS)
    for name, p in parts.items():
        assert p.is_watertight and p.volume > 0, name
    union = mq.make_mannequin()
    lo = np.min([p.bounds[0] for p in parts.values()], axis=0)
    hi = np.max([p.bounds[1] for p in parts.values()], axis=0)
    assert np.allclose(lo, union.bounds[0], atol=EXACT_M) and np.allclose(hi, union.bounds[1], atol=EXACT_M)
    surf = mq.mannequin_parts(surface=True)
    assert sum(len(s.faces) for s in surf.values()) == len(union.faces)
    assert math.isclose(sum(s.area for s in surf.values()), union.area, rel_tol=1e-12)


def test_head_arms_legs_arrive_at_least_100_ps_apart_from_the_wall_centre():
    """The paper separates head, arms and legs in arrival time; the figure is built so
    that the mean three-bounce times (laser spot S and wall point P at the wall
    centre) differ by >= 100 ps pairwise, computed in closed form from the parts."""
    parts = mq.mannequin_parts()
    centre = np.zeros(3)
    t = {g: _mean_three_bounce_ps(_group(parts, mq.PART_GROUPS[g]), centre, centre) for g in ("head", "arms", "legs")}
    for a, b in itertools.combinations(t, 2):
        assert abs(t[a] - t[b]) >= 100.0, (a, b, t)
    # the published report (visible surface only) agrees on the separations
    rep = mq.mannequin_part_report()
    for a, b in itertools.combinations(("head", "arms", "legs"), 2):
        assert abs(rep[a]["t_mean_ps"] - rep[b]["t_mean_ps"]) >= 100.0


def test_arms_hang_forward_of_the_torso_and_head_is_forward():
    parts = mq.mannequin_parts()
    arms = _group(parts, mq.PART_GROUPS["arms"])
    torso, head = parts["torso"], parts["head"]
    assert arms.bounds[0, 2] < torso.bounds[0, 2] - 0.05  # hands at least 5 cm nearer the wall than the chest
    assert head.bounds[:, 2].mean() < torso.bounds[:, 2].mean()


def test_report_has_every_group_and_sane_numbers():
    rep = mq.mannequin_part_report()
    assert set(rep) == set(mq.PART_GROUPS)
    for g, r in rep.items():
        assert r["area_m2"] > 0
        assert r["z_min_m"] <= r["z_mean_m"] <= r["z_max_m"]
        assert r["t_min_ps"] <= r["t_mean_ps"] <= r["t_max_ps"]
        # nearest possible hidden path: straight out and back to the nearest depth
        assert r["t_min_ps"] >= 2 * r["z_min_m"] / C_M_PER_PS - 1e-6


# --- poses and rotation -------------------------------------------------------------


def test_poses_move_only_the_arms():
    base = mq.mannequin_parts()
    for pose in mq.POSES:
        parts = mq.mannequin_parts(pose=pose)
        for name in ("head", "neck", "torso", "leg_right", "leg_left"):
            assert _arrays_equal(parts[name], base[name]), (pose, name)


def test_arms_raised_puts_the_hands_above_the_head():
    parts = mq.mannequin_parts(pose="arms_raised")
    crown = parts["head"].bounds[1, 1]
    for arm in ("arm_right", "arm_left"):
        assert parts[arm].bounds[1, 1] > crown + 0.05
    down = mq.mannequin_parts(pose="arms_down")
    for arm in ("arm_right", "arm_left"):
        assert down[arm].bounds[1, 1] < down["head"].bounds[0, 1]  # arms down: below the chin


def test_one_arm_out_raises_the_right_arm_only():
    out = mq.mannequin_parts(pose="one_arm_out")
    down = mq.mannequin_parts(pose="arms_down")
    assert _arrays_equal(out["arm_left"], down["arm_left"])
    right = out["arm_right"]
    h = 0.70
    shoulder_y = mq._SHOULDER[1] * h - h / 2
    # horizontal: the whole arm within one deltoid radius (its thickest sphere) of the shoulder height
    assert np.all(np.abs(right.vertices[:, 1] - shoulder_y) <= mq._DELTOID_R * h + EXACT_M)
    assert right.bounds[1, 0] > down["arm_right"].bounds[1, 0] + 0.03  # reaches further out (+x, its right)


def test_arms_forward_reach_towards_the_wall_and_t_pose_to_the_sides():
    fwd = mq.mannequin_parts(pose="arms_forward")
    torso = fwd["torso"]
    for arm in ("arm_right", "arm_left"):
        assert fwd[arm].bounds[0, 2] < torso.bounds[0, 2] - 0.15
    t = mq.make_mannequin(pose="t_pose")
    assert t.extents[0] > 0.70 and abs(t.bounds[:, 0].mean()) < EXACT_M
    assert t.extents[2] < mq.make_mannequin().extents[2]  # arms in the frontal plane: thinner


def test_rotation_turns_about_the_vertical_axis_through_position():
    pos = (0.1, 0.0, 0.6)
    a = mq.make_mannequin(pose="arms_forward", position=pos)
    b = mq.make_mannequin(pose="arms_forward", position=pos, rotation_deg=90.0)
    # +90 deg about +y: the arms that pointed at the wall (-z) now point to -x
    assert b.bounds[0, 0] < pos[0] - 0.15
    assert abs(b.bounds[0, 0] - (pos[0] - (pos[2] - a.bounds[0, 2]))) < 1e-9
    assert abs(b.extents[1] - a.extents[1]) < EXACT_M
    assert math.isclose(a.volume, b.volume, rel_tol=1e-9)
    c = mq.make_mannequin(rotation_deg=360.0)
    assert np.allclose(c.vertices, mq.make_mannequin().vertices, atol=1e-12)


# --- bad input ----------------------------------------------------------------------


@pytest.mark.parametrize("kwargs,words", [
    (dict(pose="wave"), ["pose", "wave", "arms_down", "arms_raised", "one_arm_out"]),
    (dict(height_m=0.0), ["height_m", "> 0"]),
    (dict(height_m=-0.7), ["height_m", "> 0"]),
    (dict(width_m=float("nan")), ["width_m"]),
    (dict(width_m=2.0), ["width_m", "2.0", "allowed"]),
    (dict(width_m=0.1), ["width_m", "allowed"]),
    (dict(position=(0.0, 0.5)), ["position", "three"]),
    (dict(position=(0.0, "a", 0.5)), ["position"]),
    (dict(rotation_deg=float("inf")), ["rotation_deg"]),
    (dict(detail=4), ["detail", "8 to 128"]),
    (dict(detail=20.5), ["detail"]),
])
def test_bad_parameters_are_named(kwargs, words):
    with pytest.raises(UserInputError) as e:
        mq.make_mannequin(**kwargs)
    for w in words:
        assert w in str(e.value)


def test_unwritable_output_is_an_error_and_leaves_nothing(tmp_path):
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    with pytest.raises(UserInputError, match="does not exist"):
        mq.write_mannequin(tmp_path / "missing" / "m.ply")
    with pytest.raises(UserInputError, match="is a directory"):
        mq.write_mannequin(tmp_path)
    with pytest.raises(UserInputError, match="does not exist"):
        mq.write_mannequin(blocker / "m.ply")
    with pytest.raises(UserInputError, match="pose"):
        mq.write_mannequin(tmp_path / "bad.ply", pose="nope")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file.txt"]


# --- ground truth -------------------------------------------------------------------


def _brute_force_depth(mesh, x, y):
    """Möller-Trumbore along +z against every triangle: independent of the rasteriser."""
    tri = mesh.vertices[mesh.faces]
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    e1, e2 = b - a, c - a
    d = np.array([0.0, 0.0, 1.0])
    out = np.full((len(y), len(x)), np.nan)
    for i, yy in enumerate(y):
        for j, xx in enumerate(x):
            o = np.array([xx, yy, -10.0])
            hit, t = ray_triangles(a, e1, e2, o, d)
            if hit.any():
                out[i, j] = o[2] + t[hit].min()
    return out


def test_depth_map_of_a_tilted_box_is_its_front_plane():
    box = trimesh.creation.box(extents=(0.4, 0.3, 0.2))
    ang = math.radians(20.0)
    box.apply_transform(trimesh.transformations.rotation_matrix(ang, [1, 0, 0]))
    box.apply_translation((0.0, 0.0, 0.6))
    x = np.linspace(-0.3, 0.3, 61)
    y = np.linspace(-0.25, 0.25, 51)
    depth = ground_truth_depth_map(box, x, y)
    assert depth.shape == (51, 61)
    # closed form: the front face z = 0.6 - 0.1 / cos(a) + y tan(a) for |y| inside the face's
    # projection; the x range is |x| <= 0.2
    X, Y = np.meshgrid(x, y)
    front_half = 0.15 * math.cos(ang) - 0.1 * math.sin(ang)  # |y| where the front face ends (bottom/top edges)
    inner = (np.abs(X) < 0.2 - 1e-9) & (np.abs(Y) < front_half - 1e-9)
    expect = 0.6 - 0.1 / math.cos(ang) + Y * math.tan(ang)
    assert np.allclose(depth[inner], expect[inner], atol=1e-12)
    assert np.all(np.isnan(depth[np.abs(X) > 0.2 + 1e-9]))
    sil = ground_truth_silhouette(box, x, y)
    assert sil.dtype == bool and np.array_equal(sil, np.isfinite(depth))


def test_mannequin_depth_map_matches_brute_force_ray_casting():
    m = mq.make_mannequin(detail=8)
    x = np.linspace(-0.32, 0.32, 17)
    y = np.linspace(-0.37, 0.37, 19)
    fast = ground_truth_depth_map(m, x, y)
    slow = _brute_force_depth(m, x, y)
    assert np.array_equal(np.isnan(fast), np.isnan(slow))
    assert np.allclose(fast[~np.isnan(fast)], slow[~np.isnan(slow)], atol=1e-12)
    assert np.isfinite(fast).sum() > 20


def test_mannequin_silhouette_has_head_arms_and_a_gap_between_the_legs():
    m = mq.make_mannequin()
    x = np.linspace(-0.5, 0.5, 201)  # 5 mm grid
    y = np.linspace(-0.5, 0.5, 201)
    sil = ground_truth_silhouette(m, x, y)
    cols = np.flatnonzero(sil.any(axis=0))
    rows = np.flatnonzero(sil.any(axis=1))
    step = x[1] - x[0]
    (x0, y0, _), (x1, y1, _) = m.bounds
    assert abs(x[cols[0]] - x0) <= step and abs(x[cols[-1]] - x1) <= step
    assert abs(y[rows[0]] - y0) <= step and abs(y[rows[-1]] - y1) <= step

    def at(xx, yy):
        return sil[np.argmin(np.abs(y - yy)), np.argmin(np.abs(x - xx))]

    assert at(0.0, 0.30)  # head
    assert at(0.0, 0.10)  # chest
    assert not at(0.0, -0.30)  # between the shins
    assert at(0.056, -0.30)  # right shin
    assert not at(0.0, 0.45) and not at(0.45, 0.0)
    depth = ground_truth_depth_map(m, x, y)
    assert abs(np.nanmin(depth) - m.bounds[0, 2]) < 0.01  # nearest point: the hands, 5 mm grid


def test_ground_truth_rejects_bad_grids():
    m = mq.make_mannequin(detail=8)
    with pytest.raises(UserInputError, match="x_m"):
        ground_truth_depth_map(m, [0.1, 0.0], [0.0])
    with pytest.raises(UserInputError, match="y_m"):
        ground_truth_depth_map(m, [0.0], np.zeros((2, 2)))
    with pytest.raises(UserInputError, match="mesh"):
        ground_truth_depth_map("mesh.ply", [0.0], [0.0])
    assert np.isnan(ground_truth_depth_map((np.zeros((0, 3)), np.zeros((0, 3), int)), [0.0], [0.0])).all()


def test_ground_truth_imports_without_mitsuba():
    code = "import recon.ground_truth, sys; assert 'mitsuba' not in sys.modules and 'drjit' not in sys.modules"
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr


# --- the command --------------------------------------------------------------------


def _cli(*args):
    env = dict(os.environ, TRANSIENT_MI_PROGRESS="0")
    return subprocess.run([sys.executable, "-m", "transient_mi", "mannequin", *args], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=120)


def test_cli_writes_the_same_mesh_as_the_api(tmp_path):
    out = tmp_path / "m.ply"
    r = _cli("-o", str(out), "--pose", "arms_raised", "--rotation-deg", "30", "--position", "0.1,0,0.6",
             "--height-m", "0.72", "--width-m", "0.58", "--report")
    assert r.returncode == 0, r.stderr
    assert "watertight" in r.stdout and "head" in r.stdout and "legs" in r.stdout
    ref = mq.mannequin_ply_bytes(height_m=0.72, width_m=0.58, pose="arms_raised", rotation_deg=30.0,
                                 position=(0.1, 0.0, 0.6))
    assert out.read_bytes() == ref


@pytest.mark.parametrize("args,words", [
    (["--pose", "wave"], ["pose", "wave", "arms_down", "t_pose"]),
    (["--height-m", "0"], ["height_m", "> 0"]),
    (["--position", "0,0"], ["--position", "x,y,z"]),
])
def test_cli_bad_input_is_one_line_and_writes_nothing(tmp_path, args, words):
    out = tmp_path / "m.ply"
    r = _cli("-o", str(out), *args)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and "Traceback" not in r.stderr
    for w in words:
        assert w in lines[0]
    assert list(tmp_path.iterdir()) == []


def test_cli_unwritable_output(tmp_path):
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    r = _cli("-o", str(blocker / "m.ply"))
    assert r.returncode == 2 and r.stderr.startswith("error: ") and "Traceback" not in r.stderr
    assert str(blocker) in r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file.txt"]
