"""Procedural mannequin: the hidden object of the paper's NLOS experiment.

One module on purpose (over 500 lines): proportions, poses and the mesh construction share one set of
body constants; split, the figure's definition would be scattered across files.

A stylised human figure (head, neck, torso, two arms, two legs) built from
convex hulls of spheres and ellipsoids and unioned with manifold3d into one
closed, watertight, single-piece triangle mesh. Same parameters, same mesh,
same PLY bytes.

World frame (the frame of every transient-mi scene): the relay wall is the
plane z = 0, the hidden space is z > 0, y is up. The mannequin stands upright
along +y and faces the wall (-z); its right side is +x (seen from the wall it
is on the viewer's left, as in a mirror).

Size: ``height_m`` is the standing height, sole to crown. ``width_m`` is the
full width across the arms (outer edge of one hand to the outer edge of the
other) in the rest pose ``"arms_down"``: the arms hang down and out at the
angle that makes the figure exactly ``width_m`` wide. The paper's mannequin,
"about 60 cm x 70 cm", is ``width_m=0.60, height_m=0.70`` (the defaults):
with human proportions a 70 cm figure is 60 cm wide only with the arms held
out, here 41.8 degrees from vertical. All other dimensions scale with
``height_m``; the other poses move the arms only (same body, same arm
length), so they are not ``width_m`` wide.

``position`` is the body's centre: x on the body's vertical mid-line, y at
mid-height (half-way between sole and crown), z on the coronal plane through
the shoulder and hip joints (the torso's mid-depth). ``rotation_deg`` turns
the figure about the vertical axis through ``position`` (right-hand rule
about +y: at +90 degrees it faces -x).

Arrival times: the arms hang 30 degrees forward (towards the wall) and the
head sits 1.5 % of the height forward of the torso, so that from a laser
spot and a wall point near the wall centre the head, arms and legs return at
clearly separated mean times (a few hundred ps apart at the defaults; see
``docs/mannequin.md`` and :func:`mannequin_part_report`).

The module itself uses trimesh, manifold3d and numpy, not Mitsuba (though
importing it through the ``transient_mi`` package loads Mitsuba). The
depth-map and silhouette helpers live in :mod:`recon.ground_truth`, which
never imports Mitsuba, and are re-exported here.
"""

from __future__ import annotations

import functools
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from transient_core.errors import UserInputError
from recon.ground_truth import ground_truth_depth_map, ground_truth_silhouette
from transient_core.units import C_M_PER_PS

from ._ply import ply_bytes, write_bytes_atomic
from .mannequin_skeleton import JOINTS, parse_joints, resolve_joints, bone_transforms

__all__ = [
    "POSES",
    "PARTS",
    "PART_GROUPS",
    "DEFAULTS",
    "JOINTS",
    "make_mannequin",
    "mannequin_parts",
    "posed_primitives",
    "mannequin_part_report",
    "write_mannequin",
    "rest_arm_angle_deg",
    "width_range_m",
    "ground_truth_depth_map",
    "ground_truth_silhouette",
]

#: Poses, by name: what the arms do (the body and legs never move).
POSES: dict[str, str] = {
    "arms_down": "both arms hang down and out at the rest angle set by width_m, 30 deg towards the wall",
    "arms_raised": "both arms raised above the head, 25 deg out from vertical, 15 deg towards the wall",
    "one_arm_out": "right arm (+x) straight out to the side, horizontal; left arm as in arms_down",
    "arms_forward": "both arms horizontal, pointing at the wall (-z), 10 deg apart from parallel",
    "t_pose": "both arms straight out to the sides, horizontal",
}

#: Part labels of :func:`mannequin_parts`, in build order.
PARTS: tuple[str, ...] = ("head", "neck", "torso", "arm_right", "arm_left", "leg_right", "leg_left")

#: Groups of parts used for reporting (the paper's head / arms / legs).
PART_GROUPS: dict[str, tuple[str, ...]] = {
    "head": ("head",),
    "neck": ("neck",),
    "torso": ("torso",),
    "arms": ("arm_right", "arm_left"),
    "legs": ("leg_right", "leg_left"),
}

#: Default parameters of :func:`make_mannequin`.
DEFAULTS: dict[str, object] = {
    "height_m": 0.70,
    "width_m": 0.60,
    "pose": "arms_down",
    "rotation_deg": 0.0,
    "position": (0.0, 0.0, 0.5),
    "detail": 20,
}

# --- body plan, in units of the height, body frame (y from the sole up) ------
# Each entry is a sphere (centre, radius) or an axis-aligned ellipsoid
# (centre, semi-axes); each primitive is the convex hull of its entries.
_HEAD_Z = -0.015  # head forward of the torso's mid-plane (towards the wall)
_HEAD = ((0.0, 0.93, _HEAD_Z), (0.05, 0.07, 0.06))  # crown at y = 1
_NECK = (((0.0, 0.80, 0.0), 0.03), ((0.0, 0.885, _HEAD_Z), 0.026))
_CHEST = ((0.0, 0.715, 0.0), (0.13, 0.085, 0.068))
_WAIST = ((0.0, 0.60, 0.0), (0.09, 0.05, 0.056))
_PELVIS = ((0.0, 0.50, 0.0), (0.11, 0.065, 0.064))
_SHOULDER = (0.14, 0.745, 0.0)  # right shoulder joint; the left one is mirrored
_DELTOID_R = 0.04
_ARM = ((0.0, 0.036), (0.19, 0.03), (0.35, 0.024), (0.385, 0.032))  # (distance along arm, radius)
_LEG = (((0.06, 0.47, 0.0), 0.056), ((0.07, 0.26, 0.0), 0.042), ((0.08, 0.055, 0.0), 0.03))
_FOOT = (((0.08, 0.03, 0.01), 0.03), ((0.085, 0.026, -0.075), 0.026))  # sole at y = 0
_MAX_REST_DEG = 80.0


def _hand_reach() -> tuple[float, float]:
    s, r = _ARM[-1]
    return s, r


def width_range_m(height_m: float) -> tuple[float, float]:
    """Allowed ``width_m`` for ``height_m``: arms straight down .. arms at 80 degrees.

    The lower end is the width across the shoulders (the hands then hang
    just inside the shoulders' outer edge), the upper end the width with the
    arms raised to 80 degrees from vertical.
    """
    s, r = _hand_reach()
    lo = 2.0 * (_SHOULDER[0] + _DELTOID_R)
    hi = 2.0 * (_SHOULDER[0] + s * math.sin(math.radians(_MAX_REST_DEG)) + r)
    return lo * height_m, hi * height_m


def rest_arm_angle_deg(height_m: float, width_m: float) -> float:
    """Angle of the arms from vertical in ``"arms_down"`` that makes the figure ``width_m`` wide.

    Measured in the frontal plane, before the arms are tilted 30 degrees
    towards the wall (which does not change the width).
    """
    lo, hi = width_range_m(height_m)
    if not lo - 1e-12 <= width_m <= hi + 1e-12:
        raise UserInputError(
            f"width_m={width_m!r} is not possible for height_m={height_m!r}: allowed "
            f"{lo:.3f} to {hi:.3f} m (width/height {lo / height_m:.3f} to {hi / height_m:.3f}), "
            "from arms straight down to arms at 80 degrees"
        )
    s, r = _hand_reach()
    sin_t = (0.5 * width_m / height_m - _SHOULDER[0] - r) / s
    return math.degrees(math.asin(min(max(sin_t, 0.0), 1.0)))


Blob = tuple[tuple[float, float, float], tuple[float, float, float]]  # centre, semi-axes


def _sphere(c, r) -> Blob:
    return (tuple(float(v) for v in c), (float(r),) * 3)


def _rest_plan() -> list[tuple[str, str, tuple[Blob, ...]]]:
    """Primitives ``(part label, bone, blobs to hull)`` of the root and the right limbs in the rest pose (arms
    hanging straight down, legs straight), units of the height, body frame; the left limbs are their mirror
    images (:func:`_rest_primitives`)."""
    plan: list[tuple[str, str, tuple[Blob, ...]]] = []
    plan.append(("head", "root", (_HEAD,)))
    plan.append(("neck", "root", tuple(_sphere(c, r) for c, r in _NECK)))
    plan.append(("torso", "root", (_CHEST, _WAIST)))
    plan.append(("torso", "root", (_WAIST, _PELVIS)))
    j = np.array(_SHOULDER)
    down = np.array([0.0, -1.0, 0.0])
    plan.append(("arm_right", "upper_arm_right", (_sphere(j, _DELTOID_R),)))
    pts = [(j + s * down, r) for s, r in _ARM]
    for k, ((p0, r0), (p1, r1)) in enumerate(zip(pts[:-1], pts[1:])):
        bone = "upper_arm_right" if k == 0 else "forearm_right"
        plan.append(("arm_right", bone, (_sphere(p0, r0), _sphere(p1, r1))))
    legs = [(np.array(c), r) for c, r in _LEG]
    plan.append(("leg_right", "thigh_right", (_sphere(*legs[0]), _sphere(*legs[1]))))
    plan.append(("leg_right", "shin_right", (_sphere(*legs[1]), _sphere(*legs[2]))))
    plan.append(("leg_right", "shin_right", tuple(_sphere(c, r) for c, r in _FOOT)))
    return plan


@functools.lru_cache(maxsize=8)
def _rest_primitives(detail: int) -> tuple[tuple[str, str, np.ndarray, np.ndarray], ...]:
    """Every primitive as ``(part label, bone, vertices [V, 3] float64, faces [F, 3] int64)`` in the rest
    pose (units of the height, body frame): the root's and the right limbs' convex hulls, then the left
    limbs as exact mirror images of the right ones (x -> -x, winding reversed)."""
    out = []
    mirrored = []
    for label, bone, blobs in _rest_plan():
        v, f, _ = _mesh_arrays(_manifold_of(blobs, detail))
        v, f, _ = _canonical(v, f)
        out.append((label, bone, v, f))
        if bone != "root":
            mv = v * np.array([-1.0, 1.0, 1.0])
            mirrored.append((label.replace("right", "left"), bone.replace("right", "left"), mv, f[:, ::-1].copy()))
    for item in out + mirrored:
        for arr in item[2:]:
            arr.setflags(write=False)
    return tuple(out + mirrored)


def posed_primitives(angles: dict[str, float], detail: int) -> list[tuple[str, str, np.ndarray, np.ndarray]]:
    """The primitives posed by the joint ``angles`` (every entry of
    :data:`~transient_mi.scenes.mannequin_skeleton.JOINTS`, degrees): ``(part label, bone, vertices
    [V, 3] float64 (units of the height, body frame), faces [F, 3])``. Each is its rest hull moved
    rigidly by its bone (:func:`~transient_mi.scenes.mannequin_skeleton.bone_transforms`); the
    differentiable twin (:mod:`transient_mi.fit.twin`) computes the same vertices."""
    T = bone_transforms(angles)
    return [(label, bone, v @ T[bone][0].T + T[bone][1], f) for label, bone, v, f in _rest_primitives(detail)]


# --- validation ---------------------------------------------------------------


def _finite_positive(name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise UserInputError(f"{name}={value!r} is not a number; give a length in metres > 0") from None
    if not math.isfinite(v) or v <= 0:
        raise UserInputError(f"{name}={value!r} must be a finite length in metres > 0")
    return v


def _validate(height_m, width_m, pose, rotation_deg, position, detail, joints=None):
    h = _finite_positive("height_m", height_m)
    w = _finite_positive("width_m", width_m)
    if pose not in POSES:
        raise UserInputError(f"pose={pose!r} is not known; allowed: {', '.join(POSES)}")
    try:
        rot = float(rotation_deg)
    except (TypeError, ValueError):
        raise UserInputError(f"rotation_deg={rotation_deg!r} is not a number (degrees)") from None
    if not math.isfinite(rot):
        raise UserInputError(f"rotation_deg={rotation_deg!r} must be a finite angle in degrees")
    try:
        pos = tuple(float(v) for v in position)
    except (TypeError, ValueError):
        raise UserInputError(f"position={position!r}: expected three numbers (x, y, z) in metres") from None
    if len(pos) != 3 or not all(math.isfinite(v) for v in pos):
        raise UserInputError(f"position={position!r}: expected three finite numbers (x, y, z) in metres")
    if isinstance(detail, bool) or not isinstance(detail, (int, np.integer)) or not 8 <= int(detail) <= 128:
        raise UserInputError(f"detail={detail!r}: expected an integer number of segments around each primitive, 8 to 128")
    rest = rest_arm_angle_deg(h, w)  # raises for an impossible width
    if joints is not None and not hasattr(joints, "items"):
        if isinstance(joints, str):
            joints = parse_joints(joints)
        else:
            raise UserInputError(f"joints={joints!r}: expected a mapping of joint name to degrees, e.g. "
                                 "{'elbow_right': 40}")
    angles = resolve_joints(pose, rest, joints)
    return h, w, pose, rot, pos, int(detail), tuple(angles[j] for j in JOINTS)


# --- construction -----------------------------------------------------------


@dataclass(frozen=True)
class _Built:
    vertices: np.ndarray  # [V, 3] float64, world frame
    faces: np.ndarray  # [F, 3] int64
    face_part: np.ndarray  # [F] index into PARTS
    part_solids: tuple[tuple[np.ndarray, np.ndarray], ...]  # per PARTS entry, world frame


def _manifold_of(blobs: tuple[Blob, ...], segments: int):
    import manifold3d as m3d

    pieces = []
    for c, semi in blobs:
        s = m3d.Manifold.sphere(1.0, segments).scale(semi).translate(c)
        pieces.append(s)
    return pieces[0] if len(pieces) == 1 else m3d.Manifold.batch_hull(pieces)


def _canonical(vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray | None = None):
    """Order vertices and faces lexicographically, so the output does not depend on
    the order in which the boolean engine emitted them. Winding is kept."""
    order = np.lexsort((vertices[:, 2], vertices[:, 1], vertices[:, 0]))
    inv = np.empty_like(order)
    inv[order] = np.arange(len(order))
    v = vertices[order]
    f = inv[faces]
    # Rotate each triangle so its smallest index comes first (keeps the winding).
    k = np.argmin(f, axis=1)
    idx = (k[:, None] + np.arange(3)[None, :]) % 3
    f = np.take_along_axis(f, idx, axis=1)
    forder = np.lexsort((f[:, 2], f[:, 1], f[:, 0]))
    f = f[forder]
    lab = None if labels is None else labels[forder]
    return v, f, lab


def _to_world(v_units: np.ndarray, height_m: float, rotation_deg: float, position) -> np.ndarray:
    v = v_units * height_m
    v[:, 1] -= 0.5 * height_m
    a = math.radians(rotation_deg)
    c, s = math.cos(a), math.sin(a)
    rot = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    return v @ rot.T + np.asarray(position, dtype=np.float64)


def _mesh_arrays(man) -> tuple[np.ndarray, np.ndarray, object]:
    mg = man.to_mesh64()
    v = np.asarray(mg.vert_properties, dtype=np.float64)[:, :3].copy()
    f = np.asarray(mg.tri_verts, dtype=np.int64).copy()
    return v, f, mg


@functools.lru_cache(maxsize=16)
def _build(height_m, width_m, pose, rotation_deg, position, detail, angles) -> _Built:
    import manifold3d as m3d

    prims, id_to_part = [], {}
    for label, _, v, f in posed_primitives(dict(zip(JOINTS, angles)), detail):
        man = m3d.Manifold(m3d.Mesh64(vert_properties=np.ascontiguousarray(v), tri_verts=f.astype(np.uint64)))
        if man.status() != m3d.Error.NoError:
            raise RuntimeError(f"mannequin: a posed part is not a closed solid ({man.status()}; please report this)")
        man = man.as_original()
        id_to_part[man.original_id()] = PARTS.index(label)
        prims.append((label, man))
    union = m3d.Manifold.batch_boolean([p for _, p in prims], m3d.OpType.Add)
    if union.status() != m3d.Error.NoError or len(union.decompose()) != 1:
        raise RuntimeError(f"mannequin: the union of the body parts is not one closed solid ({union.status()})")
    v, f, mg = _mesh_arrays(union)
    run_index = np.asarray(mg.run_index, dtype=np.int64) // 3
    run_ids = np.asarray(mg.run_original_id, dtype=np.int64)
    labels = np.empty(len(f), dtype=np.int64)
    for k, oid in enumerate(run_ids):
        labels[run_index[k]:run_index[k + 1]] = id_to_part[int(oid)]
    v, f, labels = _canonical(v, f, labels)
    v = _to_world(v, height_m, rotation_deg, position)
    check = _trimesh(v, f)
    if not (check.is_watertight and check.is_winding_consistent and check.volume > 0):
        raise RuntimeError("mannequin: the mesh is not watertight with outward normals (please report this)")

    solids = []
    for label in PARTS:
        parts = [p for lab, p in prims if lab == label]
        man = parts[0] if len(parts) == 1 else m3d.Manifold.batch_boolean(parts, m3d.OpType.Add)
        pv, pf, _ = _mesh_arrays(man)
        pv, pf, _ = _canonical(pv, pf)
        solids.append((_to_world(pv, height_m, rotation_deg, position), pf))
    for arr in (v, f, labels):
        arr.setflags(write=False)
    return _Built(v, f, labels, tuple(solids))


def _built(height_m=DEFAULTS["height_m"], width_m=DEFAULTS["width_m"], pose=DEFAULTS["pose"],
           rotation_deg=DEFAULTS["rotation_deg"], position=DEFAULTS["position"],
           detail=DEFAULTS["detail"], joints=None) -> _Built:
    return _build(*_validate(height_m, width_m, pose, rotation_deg, position, detail, joints))


def _trimesh(v: np.ndarray, f: np.ndarray) -> trimesh.Trimesh:
    return trimesh.Trimesh(vertices=np.array(v, dtype=np.float64), faces=np.array(f, dtype=np.int64), process=False)


def make_mannequin(height_m: float = 0.70, width_m: float = 0.60, pose: str = "arms_down",
                   rotation_deg: float = 0.0, position=(0.0, 0.0, 0.5), detail: int = 20,
                   joints=None) -> trimesh.Trimesh:
    """Build the mannequin as one watertight triangle mesh.

    Parameters
    ----------
    height_m : float
        Standing height, sole to crown, metres (> 0). Default 0.70.
    width_m : float
        Width across the arms in the rest pose ``"arms_down"``, metres; sets
        the rest angle of the arms (:func:`rest_arm_angle_deg`). Allowed
        range :func:`width_range_m` (0.360 to 1.102 times ``height_m``).
        Default 0.60.
    pose : str
        One of :data:`POSES`: ``arms_down`` (default), ``arms_raised``,
        ``one_arm_out``, ``arms_forward``, ``t_pose``.
    rotation_deg : float
        Turn about the vertical axis through ``position``, degrees,
        right-hand rule about +y (0: facing the wall, -z).
    position : (x, y, z)
        Body centre in metres: mid-line, mid-height, torso mid-depth.
        Default (0, 0, 0.5): 50 cm behind the wall's centre.
    detail : int
        Segments around each sphere (rounded up to a multiple of 4), 8 to
        128. Default 20 gives about 3000 faces.
    joints : mapping or str, optional
        Joint angles in degrees that override the pose's
        (:data:`~transient_mi.scenes.mannequin_skeleton.JOINTS`: shoulder
        abduction and flexion, elbow, hip and knee of each side), e.g.
        ``{"elbow_right": 40, "knee_left": 20}`` or ``"elbow_right=40,knee_left=20"``.
        Every limb is a rigid bone posed about its joint
        (:mod:`~transient_mi.scenes.mannequin_skeleton`).

    Returns
    -------
    trimesh.Trimesh
        Closed, watertight, consistently wound (outward normals), one
        connected piece; vertices in metres in the world frame. Vertices and
        faces are in a canonical (sorted) order, so equal parameters give
        equal arrays. ``mesh.metadata["face_part"]`` holds each face's part
        label (an entry of :data:`PARTS`) and ``mesh.metadata["params"]`` the
        parameters.

    Raises
    ------
    UserInputError
        For a non-positive or non-finite size, an impossible ``width_m``, an
        unknown pose, a bad rotation, position or detail.
    """
    b = _built(height_m, width_m, pose, rotation_deg, position, detail, joints)
    mesh = _trimesh(b.vertices, b.faces)
    mesh.metadata["face_part"] = np.asarray(PARTS, dtype=object)[b.face_part]
    h, w, p, r, pos, d, angles = _validate(height_m, width_m, pose, rotation_deg, position, detail, joints)
    mesh.metadata["params"] = dict(height_m=h, width_m=w, pose=p, rotation_deg=r, position=pos, detail=d,
                                   joints=dict(zip(JOINTS, angles)))
    return mesh


def mannequin_parts(height_m: float = 0.70, width_m: float = 0.60, pose: str = "arms_down",
                    rotation_deg: float = 0.0, position=(0.0, 0.0, 0.5), detail: int = 20,
                    surface: bool = False, joints=None) -> dict[str, trimesh.Trimesh]:
    """The mannequin's parts, by label (:data:`PARTS`), in the world frame.

    Parameters
    ----------
    height_m, width_m, pose, rotation_deg, position, detail
        As in :func:`make_mannequin`.
    surface : bool
        False (default): each part as a closed, watertight solid (the union
        of its primitives); parts overlap where they join (the shoulder
        inside the chest, the neck inside the head). True: the faces of the
        :func:`make_mannequin` mesh that belong to each part, an open
        surface: only what can be seen from outside the figure.

    Returns
    -------
    dict of str to trimesh.Trimesh
        Keys in the order of :data:`PARTS`; group them with
        :data:`PART_GROUPS` (head, neck, torso, arms, legs).
    """
    b = _built(height_m, width_m, pose, rotation_deg, position, detail, joints)
    if not surface:
        return {label: _trimesh(v, f) for label, (v, f) in zip(PARTS, b.part_solids)}
    out = {}
    for k, label in enumerate(PARTS):
        sub = b.faces[b.face_part == k]
        used, inv = np.unique(sub, return_inverse=True)
        out[label] = _trimesh(b.vertices[used], inv.reshape(-1, 3))
    return out


def _three_bounce_path_m(points: np.ndarray, laser_spot_m, wall_point_m) -> np.ndarray:
    s = np.asarray(laser_spot_m, dtype=np.float64)
    p = np.asarray(wall_point_m, dtype=np.float64)
    return np.linalg.norm(points - s, axis=-1) + np.linalg.norm(points - p, axis=-1)


def mannequin_part_report(laser_spot_m=(0.0, 0.0, 0.0), wall_point_m=(0.0, 0.0, 0.0),
                          **params) -> dict[str, dict[str, float]]:
    """Depth and three-bounce arrival time of each part group, as seen from the wall.

    Uses the faces of the :func:`make_mannequin` surface that face the wall
    (outward normal with negative z), area-weighted: these are the surfaces
    that send light back to the wall. Occlusion between parts is ignored.

    Parameters
    ----------
    laser_spot_m, wall_point_m : (x, y, z)
        Laser spot S on the wall and wall point P seen by a pixel, metres.
    **params
        Mannequin parameters as in :func:`make_mannequin`.

    Returns
    -------
    dict of group name (:data:`PART_GROUPS`) to a dict with
        ``area_m2`` (wall-facing area), ``z_min_m``, ``z_mean_m``,
        ``z_max_m`` (depth behind the wall), ``y_min_m``, ``y_max_m``, and
        ``t_min_ps``, ``t_mean_ps``, ``t_max_ps``: time of flight of the
        hidden part of the three-bounce path, (|S - o| + |o - P|) / c, over
        the part's wall-facing surface points o (face centroids for the
        mean, vertices for min and max). Add the laser -> S and P ->
        detector segments for the absolute arrival time.
    """
    mesh = make_mannequin(**params)
    labels = mesh.metadata["face_part"]
    normals = mesh.face_normals
    areas = mesh.area_faces
    centroids = mesh.triangles_center
    report = {}
    for group, members in PART_GROUPS.items():
        sel = np.isin(labels, members) & (normals[:, 2] < 0)
        w = areas[sel]
        cen = centroids[sel]
        verts = mesh.vertices[np.unique(mesh.faces[sel])]
        path_c = _three_bounce_path_m(cen, laser_spot_m, wall_point_m)
        path_v = _three_bounce_path_m(verts, laser_spot_m, wall_point_m)
        report[group] = {
            "area_m2": float(w.sum()),
            "z_min_m": float(verts[:, 2].min()),
            "z_mean_m": float(np.average(cen[:, 2], weights=w)),
            "z_max_m": float(verts[:, 2].max()),
            "y_min_m": float(verts[:, 1].min()),
            "y_max_m": float(verts[:, 1].max()),
            "t_min_ps": float(path_v.min() / C_M_PER_PS),
            "t_mean_ps": float(np.average(path_c, weights=w) / C_M_PER_PS),
            "t_max_ps": float(path_v.max() / C_M_PER_PS),
        }
    return report


def mannequin_ply_bytes(**params) -> bytes:
    """The binary PLY file :func:`write_mannequin` writes, as bytes."""
    b = _built(**params)
    return ply_bytes(b.vertices, b.faces)


def write_mannequin(path: str | os.PathLike, **params) -> Path:
    """Build the mannequin and write it as binary PLY for ``<shape type="ply">``.

    Parameters
    ----------
    path : path-like
        Output file. Written under a temporary name in the same folder and
        renamed into place: never half-written.
    **params
        As in :func:`make_mannequin` (``height_m``, ``width_m``, ``pose``,
        ``rotation_deg``, ``position``, ``detail``).

    Returns
    -------
    pathlib.Path
        The path written. The file holds float32 positions (metres) and
        int32 triangles only; equal parameters give equal bytes.

    Raises
    ------
    UserInputError
        Bad parameters, or an output that cannot be written (missing
        folder, a folder given as the file, no permission). The parameters
        are checked before anything is written.
    """
    data = mannequin_ply_bytes(**params)
    return write_bytes_atomic(path, data, what="output mesh")
