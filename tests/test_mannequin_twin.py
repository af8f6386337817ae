"""The articulated mannequin (joints) and its differentiable twin (transient_mi.fit.twin)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import transient_mi  # noqa: F401  (LLVM and the variant before mitsuba/drjit)
import drjit as dr
import mitsuba as mi

from transient_core.errors import UserInputError
from transient_mi.fit.twin import MannequinTwin
from transient_mi.scenes import mannequin as mq
from transient_mi.scenes.mannequin_skeleton import JOINTS, bone_transforms, parse_joints, pose_joint_angles

# float32 positions of numbers of order 1 m: 0.5 ulp is 6e-8 m; a few operations: 1e-6 m bounds them.
FLOAT32_M = 1e-6

POSED = {"elbow_right": 50.0, "shoulder_abduction_left": 70.0, "knee_left": 35.0, "hip_left": 25.0,
         "shoulder_flexion_right": 50.0}


def _angles(**over):
    a = pose_joint_angles("arms_down", mq.rest_arm_angle_deg(0.7, 0.6))
    a.update(over)
    return a


def test_named_poses_are_joint_angles_and_arms_down_keeps_the_width():
    """Each pose is a set of joint angles; the legs stand straight in all of them."""
    for pose in mq.POSES:
        a = pose_joint_angles(pose, 40.0)
        assert set(a) == set(JOINTS)
        assert all(a[f"{j}_{s}"] == 0.0 for j in ("elbow", "hip", "knee") for s in ("right", "left"))
    m = mq.make_mannequin(joints={})
    assert np.array_equal(m.vertices, mq.make_mannequin().vertices)


def test_bone_transforms_are_rotations_about_their_pivots():
    T = bone_transforms(_angles(**POSED))
    for bone, (R, t) in T.items():
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-12) and math.isclose(np.linalg.det(R), 1.0, abs_tol=1e-12)
    R, t = T["forearm_right"]
    Ru, tu = T["upper_arm_right"]
    elbow = np.array([0.14, 0.745 - 0.19, 0.0])
    assert np.allclose(R @ elbow + t, Ru @ elbow + tu, atol=1e-12)  # the elbow stays on the upper arm


def test_left_side_mirrors_the_right_for_equal_angles():
    a = _angles(**{f"{k}_{s}": v for k, v in (("elbow", 40.0), ("hip", 20.0), ("knee", 30.0)) for s in ("right", "left")})
    m = mq.make_mannequin(joints=a)
    v = m.vertices - np.array([0.0, 0.0, 0.5])
    mirrored = v * np.array([-1.0, 1.0, 1.0])
    from scipy.spatial import cKDTree

    d, _ = cKDTree(v).query(mirrored)
    assert d.max() < 1e-9


def test_a_joint_moves_only_its_limb():
    base = mq.mannequin_parts()
    bent = mq.mannequin_parts(joints={"knee_left": 60.0})
    for name in ("head", "neck", "torso", "arm_right", "arm_left", "leg_right"):
        assert np.array_equal(bent[name].vertices, base[name].vertices), name
    assert not np.array_equal(bent["leg_left"].vertices, base["leg_left"].vertices)
    # a bent knee takes the foot backwards (+z, away from the wall) and up
    assert bent["leg_left"].bounds[1, 2] > base["leg_left"].bounds[1, 2] + 0.05
    assert bent["leg_left"].bounds[0, 1] > base["leg_left"].bounds[0, 1] + 0.02


def test_elbow_bends_the_forearm_towards_the_wall_and_hip_lifts_the_leg_forward():
    base = mq.mannequin_parts()
    elbow = mq.mannequin_parts(joints={"elbow_right": 90.0})
    assert elbow["arm_right"].bounds[0, 2] < base["arm_right"].bounds[0, 2] - 0.03
    hip = mq.mannequin_parts(joints={"hip_right": 60.0})
    assert hip["leg_right"].bounds[0, 2] < base["leg_right"].bounds[0, 2] - 0.1


@pytest.mark.parametrize("joints,words", [
    ({"elbow_rihgt": 10}, ["elbow_rihgt", "not known", "elbow_right"]),
    ({"knee_left": 200}, ["knee_left", "200", "[0, 150]"]),
    ({"hip_right": float("nan")}, ["hip_right", "nan"]),
    ("elbow_right40", ["name=degrees"]),
    ("elbow_right=abc", ["elbow_right", "abc", "not a number"]),
])
def test_bad_joints_are_one_line_errors(joints, words):
    with pytest.raises(UserInputError) as e:
        mq.make_mannequin(joints=joints)
    msg = str(e.value)
    assert "\n" not in msg and all(w in msg for w in words), msg


def test_joints_as_text_equal_joints_as_mapping():
    a = mq.make_mannequin(joints="elbow_right=50, knee_left=35")
    b = mq.make_mannequin(joints={"elbow_right": 50, "knee_left": 35})
    assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
    assert parse_joints("") == {}


def test_twin_vertices_equal_the_generators_posed_primitives():
    """Same parameters: the Dr.Jit twin's vertices are the generator's (float32 rounding)."""
    twin = MannequinTwin()
    angles = _angles(**POSED)
    ref = twin.vertices_numpy(angles, (0.1, -0.05, 0.55), 17.0, 0.72)
    v = twin.vertices({j: mi.Float(angles[j]) for j in JOINTS}, [mi.Float(0.1), mi.Float(-0.05), mi.Float(0.55)],
                      mi.Float(17.0), mi.Float(0.72))
    got = np.stack([np.asarray(v.x), np.asarray(v.y), np.asarray(v.z)], axis=1)
    assert got.shape == ref.shape == (twin.n_vertices, 3)
    assert np.max(np.abs(got - ref)) < FLOAT32_M


def _point_triangles_distance(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Distance from point ``p`` to each triangle ``tri [n, 3, 3]`` (closest point by region, Ericson 2005)."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, ac, ap = b - a, c - a, p - a
    n = np.cross(ab, ac)
    nn = np.einsum("ij,ij->i", n, n)
    # barycentric coordinates of the projection onto the plane
    v = np.einsum("ij,ij->i", np.cross(ap, ac), n) / nn
    w = np.einsum("ij,ij->i", np.cross(ab, ap), n) / nn
    inside = (v >= 0) & (w >= 0) & (v + w <= 1)
    d_plane = np.abs(np.einsum("ij,ij->i", ap, n)) / np.sqrt(nn)

    def seg(p0, p1):
        d = p1 - p0
        t = np.clip(np.einsum("ij,ij->i", p - p0, d) / np.einsum("ij,ij->i", d, d), 0.0, 1.0)
        return np.linalg.norm(p - (p0 + t[:, None] * d), axis=1)

    d_edge = np.minimum(np.minimum(seg(a, b), seg(b, c)), seg(c, a))
    return np.where(inside, d_plane, d_edge)


def test_twin_union_is_the_mannequin():
    """The union of the twin's posed primitives is the solid make_mannequin writes: same volume, and every
    vertex of the mannequin lies on the surface of one of the twin's primitives."""
    import trimesh

    twin = MannequinTwin()
    angles = _angles(**POSED)
    v = twin.vertices_numpy(angles, (0.0, 0.0, 0.5), 0.0, 0.7)
    m = mq.make_mannequin(joints=POSED)
    parts = trimesh.Trimesh(vertices=v, faces=twin.faces.astype(np.int64), process=False)
    # the union's surface is made of pieces of the primitives' surfaces (and their intersection curves)
    pts = m.vertices[:: max(1, len(m.vertices) // 300)]
    dist = np.array([_point_triangles_distance(p, parts.triangles).min() for p in pts])
    assert dist.max() < 1e-7
    # its volume is at most the primitives' total (they overlap) and at least the largest primitive's
    assert m.volume <= parts.volume + 1e-12


def test_twin_gradient_equals_finite_differences():
    """d(sum w . v)/d(angle, position, rotation, height) by AD equals central differences of the numpy path."""
    twin = MannequinTwin(detail=12)
    angles = _angles(**POSED)
    rng = np.random.default_rng(3)
    w = rng.normal(size=(twin.n_vertices, 3))
    params = [mi.Float(angles[j]) for j in JOINTS] + [mi.Float(0.1), mi.Float(0.0), mi.Float(0.5), mi.Float(10.0),
                                                      mi.Float(0.7)]
    for p in params:
        dr.enable_grad(p)
    v = twin.vertices(dict(zip(JOINTS, params[:10])), params[10:13], params[13], params[14])
    dr.backward_from(dr.sum(v.x * mi.Float(w[:, 0]) + v.y * mi.Float(w[:, 1]) + v.z * mi.Float(w[:, 2])))
    ad = np.array([dr.grad(p)[0] for p in params])
    base = [angles[j] for j in JOINTS] + [0.1, 0.0, 0.5, 10.0, 0.7]

    def f(x):
        return float(np.sum(w * twin.vertices_numpy(dict(zip(JOINTS, x[:10])), x[10:13], x[13], x[14])))

    for k in range(len(base)):
        h = 1e-3 if k != 14 else 1e-5
        xp, xm = list(base), list(base)
        xp[k] += h
        xm[k] -= h
        fd = (f(xp) - f(xm)) / (2 * h)
        # float32 AD against float64 differences: relative 1e-3 of the largest gradient bounds the rounding
        assert abs(ad[k] - fd) <= 1e-3 * np.max(np.abs(ad)) + 1e-4, (k, ad[k], fd)
