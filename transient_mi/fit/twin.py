"""The mannequin's differentiable twin: its vertex positions as a Dr.Jit function of the pose.

:func:`transient_mi.scenes.mannequin.make_mannequin` poses rigid primitives (convex hulls) with the skeleton
of :mod:`transient_mi.scenes.mannequin_skeleton` and unions them into one watertight mesh. The twin keeps the
posed primitives as they are, *not* unioned (a union's vertices are not a smooth function of the pose), so

* its vertices are the same rest vertices moved by the same bone transforms, evaluated in Dr.Jit with the
  joint angles, position, rotation and height as (differentiable) variables; for equal parameters they
  equal :func:`~transient_mi.scenes.mannequin.posed_primitives` in the world frame to float32 rounding
  (tested), and
* the union of its primitives is the solid :func:`~transient_mi.scenes.mannequin.make_mannequin` builds:
  its outer surface, the only surface light reaches, is the mannequin's. The primitives' parts inside other
  primitives (the shoulder inside the chest) are hidden: they receive and send no light in a render.
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from transient_mi._upload import upload
from transient_mi.scenes.mannequin import _rest_primitives, _to_world, posed_primitives
from transient_mi.scenes.mannequin_skeleton import BONES, ELBOW_DROP, HIP, JOINTS, KNEE, SHOULDER

__all__ = ["MannequinTwin"]


def _rot_x(a):
    c, s = dr.cos(a), dr.sin(a)
    one, zero = mi.Float(1.0), mi.Float(0.0)
    return [[one, zero, zero], [zero, c, -s], [zero, s, c]]


def _rot_z(a):
    c, s = dr.cos(a), dr.sin(a)
    one, zero = mi.Float(1.0), mi.Float(0.0)
    return [[c, -s, zero], [s, c, zero], [zero, zero, one]]


def _matmul(a, b):
    return [[a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j] for j in range(3)] for i in range(3)]


def _matvec(a, v):
    return [a[i][0] * v[0] + a[i][1] * v[1] + a[i][2] * v[2] for i in range(3)]


def _about(R, pivot):
    p = [mi.Float(float(x)) for x in pivot]
    Rp = _matvec(R, p)
    return R, [p[i] - Rp[i] for i in range(3)]


def _compose(a, b):
    Rb = _matvec(a[0], b[1])
    return _matmul(a[0], b[0]), [Rb[i] + a[1][i] for i in range(3)]


def _bone_transforms(angles_rad: dict):
    """The skeleton's :func:`~transient_mi.scenes.mannequin_skeleton.bone_transforms`, in Dr.Jit (radians)."""
    one, zero = mi.Float(1.0), mi.Float(0.0)
    out = {"root": ([[one, zero, zero], [zero, one, zero], [zero, zero, one]], [zero, zero, zero])}
    for side, sign in (("right", 1.0), ("left", -1.0)):
        shoulder = (sign * SHOULDER[0], SHOULDER[1], SHOULDER[2])
        elbow = (shoulder[0], shoulder[1] - ELBOW_DROP, shoulder[2])
        R_sh = _matmul(_rot_x(angles_rad[f"shoulder_flexion_{side}"]),
                       _rot_z(sign * angles_rad[f"shoulder_abduction_{side}"]))
        upper = _about(R_sh, shoulder)
        out[f"upper_arm_{side}"] = upper
        out[f"forearm_{side}"] = _compose(upper, _about(_rot_x(angles_rad[f"elbow_{side}"]), elbow))
        thigh = _about(_rot_x(angles_rad[f"hip_{side}"]), (sign * HIP[0], HIP[1], HIP[2]))
        out[f"thigh_{side}"] = thigh
        out[f"shin_{side}"] = _compose(thigh, _about(_rot_x(-angles_rad[f"knee_{side}"]),
                                                     (sign * KNEE[0], KNEE[1], KNEE[2])))
    return out


class MannequinTwin:
    """Vertex positions of the posed (not unioned) primitives of the mannequin, differentiable in the pose.

    Parameters
    ----------
    detail : int
        Tessellation, as in :func:`~transient_mi.scenes.mannequin.make_mannequin` (default 20).

    Attributes
    ----------
    faces : numpy.ndarray
        ``[F, 3]`` uint32 triangles into the twin's vertices (every primitive's, concatenated).
    n_vertices : int
        Number of vertices ``V``.
    """

    def __init__(self, detail: int = 20):
        prims = _rest_primitives(int(detail))
        self.detail = int(detail)
        verts, faces, bones, offset = [], [], [], 0
        for _, bone, v, f in prims:
            verts.append(v)
            faces.append(f + offset)
            bones.append(np.full(len(v), BONES.index(bone), dtype=np.uint32))
            offset += len(v)
        self.rest = np.concatenate(verts)  # [V, 3] float64, body frame, units of the height
        self.faces = np.concatenate(faces).astype(np.uint32)
        self.n_vertices = len(self.rest)
        self._bone = upload(mi.UInt32, np.concatenate(bones))
        self._rest = mi.Point3f(*(upload(mi.Float, self.rest[:, k]) for k in range(3)))

    def vertices(self, joints_deg: dict, position, rotation_deg, height_m) -> mi.Point3f:
        """World-frame vertex positions ``[V]`` (metres) as a Dr.Jit expression of the parameters.

        Parameters
        ----------
        joints_deg : dict
            Every entry of :data:`~transient_mi.scenes.mannequin_skeleton.JOINTS` -> ``mi.Float`` (one value,
            degrees; gradients flow through it).
        position : sequence of three ``mi.Float``
            Body centre (mid-line, mid-height, torso mid-depth), metres.
        rotation_deg : mi.Float
            Turn about the vertical axis through ``position``, degrees (right-hand rule about +y).
        height_m : mi.Float
            Standing height, metres (scales the whole figure).
        """
        rad = {j: mi.Float(joints_deg[j]) * (math.pi / 180.0) for j in JOINTS}
        T = _bone_transforms(rad)
        # per-vertex rows of its bone's transform (select chains: a handful of bones)
        M = [[mi.Float(0.0) for _ in range(4)] for _ in range(3)]
        for k, bone in enumerate(BONES):
            sel = self._bone == k
            R, t = T[bone]
            for i in range(3):
                for j in range(3):
                    M[i][j] = dr.select(sel, R[i][j], M[i][j])
                M[i][3] = dr.select(sel, t[i], M[i][3])
        r = self._rest
        body = [M[i][0] * r.x + M[i][1] * r.y + M[i][2] * r.z + M[i][3] for i in range(3)]
        h = mi.Float(height_m)
        x, y, z = body[0] * h, (body[1] - 0.5) * h, body[2] * h
        a = mi.Float(rotation_deg) * (math.pi / 180.0)
        c, s = dr.cos(a), dr.sin(a)
        px, py, pz = (mi.Float(p) for p in position)
        return mi.Point3f(c * x + s * z + px, y + py, -s * x + c * z + pz)

    def vertices_numpy(self, joints_deg: dict, position, rotation_deg: float, height_m: float) -> np.ndarray:
        """The same vertices in float64 numpy from :func:`~transient_mi.scenes.mannequin.posed_primitives`
        (the generator's own code path), ``[V, 3]`` metres."""
        prims = posed_primitives({j: float(joints_deg[j]) for j in JOINTS}, self.detail)
        body = np.concatenate([v for _, _, v, _ in prims])
        return _to_world(body, float(height_m), float(rotation_deg), tuple(float(p) for p in position))
