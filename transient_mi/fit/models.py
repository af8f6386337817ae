"""What a fit optimises: a parameter vector, its meaning, and the mesh it makes.

Two models:

``mannequin`` (:class:`MannequinModel`)
    The procedural mannequin's pose and placement: the ten joint angles of
    :data:`~transient_mi.scenes.mannequin_skeleton.JOINTS` (degrees), the body centre ``x, y, z`` (m),
    the rotation about the vertical axis (degrees), the height (m) and the reflectance; the mesh is the
    differentiable twin (:class:`~transient_mi.fit.twin.MannequinTwin`).
``patches`` (:class:`PatchesModel`)
    ``K`` square Lambertian patches of fixed side: each patch's centre ``x, y, z`` (m) and its normal's
    two angles (yaw about y, pitch about x, degrees; 0, 0 faces the wall), one shared reflectance.

Each model maps its parameter vector ``theta`` (float64, the units above) to vertices (Dr.Jit, so the
vertex gradient a render gives becomes a gradient in ``theta``) and gives per-parameter Adam step sizes
and bounds.

Gradient of the size (the mannequin's height): the Monte Carlo renderer differentiates a rigidly moving hidden
surface, not a change of its area (``docs/differentiable.md``); the hidden light is proportional to the
hidden area ``A`` at fixed samples (area sampling, three-bounce light) and to the reflectance ``rho``, so
the missing term of a uniform scale ``s`` is ``(2 / s) ds sum(g . H) = (2 rho / s) (dL / d rho) ds``,
which :meth:`MannequinModel.gradient` adds (not with the quadrature, whose vertex gradient holds the area's
change).
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from transient_mi._upload import upload
from transient_mi.scenes.mannequin_skeleton import JOINT_RANGES_DEG, JOINTS, pose_joint_angles

__all__ = ["MannequinModel", "PatchesModel", "MODELS"]


def _chain(vertices, theta, grad_vertices: np.ndarray, grad_albedo: float) -> np.ndarray:
    """``dL/dtheta``: the vertex gradient ``[V, 3]`` pulled back through ``vertices(theta) -> mi.Point3f`` (Dr.Jit
    reverse mode); the last parameter (the reflectance) takes ``grad_albedo``."""
    t = [mi.Float(float(x)) for x in theta]
    for x in t:
        dr.enable_grad(x)
    v = vertices(t)
    g = np.asarray(grad_vertices, dtype=np.float32)
    gx, gy, gz = (upload(mi.Float, g[:, k]) for k in range(3))
    dr.backward_from(dr.sum(v.x * gx + v.y * gy + v.z * gz))
    out = np.array([float(dr.grad(x)[0]) for x in t])
    out[-1] = grad_albedo
    return out


class MannequinModel:
    """Pose, placement, size and reflectance of the procedural mannequin (see the module docstring)."""

    name = "mannequin"

    def __init__(self, detail: int = 20):
        from transient_mi.fit.twin import MannequinTwin

        self.twin = MannequinTwin(detail)
        self.names = list(JOINTS) + ["x_m", "y_m", "z_m", "rotation_deg", "height_m", "albedo"]
        self.faces = self.twin.faces
        self.n_vertices = self.twin.n_vertices
        lo = [JOINT_RANGES_DEG[j.rsplit("_", 1)[0]][0] for j in JOINTS]
        hi = [JOINT_RANGES_DEG[j.rsplit("_", 1)[0]][1] for j in JOINTS]
        self.lower = np.array(lo + [-2.0, -2.0, 0.05, -180.0, 0.2, 0.01])
        self.upper = np.array(hi + [2.0, 2.0, 5.0, 180.0, 3.0, 1.0])
        #: Adam step sizes (per iteration, parameter units).
        self.step = np.array([1.5] * len(JOINTS) + [0.004, 0.004, 0.004, 1.0, 0.004, 0.01])
        #: Gauss-Newton's forward-difference steps (parameter units).
        self.fd_step = np.array([1.0] * len(JOINTS) + [0.003, 0.003, 0.003, 1.0, 0.003, 0.01])

    def initial(self, position, height_m: float = 0.70, width_m: float = 0.60, albedo: float = 0.5) -> np.ndarray:
        """``arms_down`` at ``position`` (the rest angle of ``width_m``), facing the wall."""
        from transient_mi.scenes.mannequin import rest_arm_angle_deg

        j = pose_joint_angles("arms_down", rest_arm_angle_deg(height_m, width_m))
        return np.array([j[k] for k in JOINTS] + list(map(float, position)) + [0.0, float(height_m), float(albedo)])

    def as_dict(self, theta) -> dict:
        return {n: float(v) for n, v in zip(self.names, theta)}

    def mesh_kwargs(self, theta) -> dict:
        """Keyword arguments of :func:`~transient_mi.scenes.mannequin.make_mannequin` for ``theta``."""
        d = self.as_dict(theta)
        return dict(height_m=d["height_m"], pose="arms_down", rotation_deg=d["rotation_deg"],
                    position=(d["x_m"], d["y_m"], d["z_m"]), joints={j: d[j] for j in JOINTS})

    def _vertices(self, t):
        n = len(JOINTS)
        return self.twin.vertices({j: t[k] for k, j in enumerate(JOINTS)}, (t[n], t[n + 1], t[n + 2]), t[n + 3],
                                  t[n + 4])

    def vertices(self, theta) -> np.ndarray:
        v = self._vertices([mi.Float(float(x)) for x in theta])
        return np.stack([np.asarray(v.x), np.asarray(v.y), np.asarray(v.z)], axis=1)

    def albedo(self, theta) -> float:
        return float(theta[-1])

    def gradient(self, theta, grad_vertices: np.ndarray, grad_albedo: float, area_term: bool = True) -> np.ndarray:
        """``dL/dtheta`` from the gradient with respect to the vertices ``[V, 3]`` and the reflectance;
        ``area_term``: add the size's area term (the Monte Carlo renderer's vertex gradient lacks it; the
        quadrature's holds it)."""
        out = _chain(self._vertices, theta, grad_vertices, grad_albedo)
        if area_term:  # the hidden area's share of a change of size (see the module docstring)
            out[-2] += 2.0 * float(theta[-1]) / float(theta[-2]) * grad_albedo
        return out


class PatchesModel:
    """``K`` square patches of side ``side_m`` (see the module docstring)."""

    name = "patches"

    def __init__(self, n_patches: int = 3, side_m: float = 0.2):
        self.K, self.side = int(n_patches), float(side_m)
        self.names = [f"patch{k}_{q}" for k in range(self.K) for q in ("x_m", "y_m", "z_m", "yaw_deg", "pitch_deg")]
        self.names.append("albedo")
        # wound so that the normal faces the wall (-z at zero angles): a diffuse surface reflects on its front only
        self.faces = np.array([[4 * k + 0, 4 * k + 2, 4 * k + 1] for k in range(self.K)]
                              + [[4 * k + 0, 4 * k + 3, 4 * k + 2] for k in range(self.K)], dtype=np.uint32)
        self.n_vertices = 4 * self.K
        self.lower = np.array([-2.0, -2.0, 0.05, -80.0, -80.0] * self.K + [0.01])
        self.upper = np.array([2.0, 2.0, 5.0, 80.0, 80.0] * self.K + [1.0])
        self.step = np.array([0.004, 0.004, 0.004, 1.0, 1.0] * self.K + [0.01])
        self.fd_step = np.array([0.003, 0.003, 0.003, 1.0, 1.0] * self.K + [0.01])

    def initial(self, centres, albedo: float = 0.5) -> np.ndarray:
        c = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
        if len(c) != self.K:
            raise ValueError(f"{len(c)} initial centres for {self.K} patches")
        return np.concatenate([np.concatenate([ck, [0.0, 0.0]]) for ck in c] + [[float(albedo)]])

    def as_dict(self, theta) -> dict:
        return {n: float(v) for n, v in zip(self.names, theta)}

    def _vertices(self, t):
        h = 0.5 * self.side
        corners = [(-h, -h), (h, -h), (h, h), (-h, h)]  # (u, v) in the patch plane; normal -z (to the wall)
        xs, ys, zs = [], [], []
        for k in range(self.K):
            cx, cy, cz, yaw, pitch = t[5 * k: 5 * k + 5]
            a, b = yaw * (math.pi / 180.0), pitch * (math.pi / 180.0)
            ca, sa, cb, sb = dr.cos(a), dr.sin(a), dr.cos(b), dr.sin(b)
            for u, v in corners:
                # rotate (u, v, 0) by Rx(pitch) then Ry(yaw)
                x1, y1, z1 = u, v * cb, v * sb
                xs.append(ca * x1 + sa * z1 + cx)
                ys.append(y1 + cy)
                zs.append(-sa * x1 + ca * z1 + cz)
        return xs, ys, zs

    def vertices(self, theta) -> np.ndarray:
        xs, ys, zs = self._vertices([mi.Float(float(x)) for x in theta])
        return np.array([[float(x[0]), float(y[0]), float(z[0])] for x, y, z in zip(xs, ys, zs)])

    def albedo(self, theta) -> float:
        return float(theta[-1])

    def gradient(self, theta, grad_vertices: np.ndarray, grad_albedo: float, area_term: bool = True) -> np.ndarray:
        return _chain(lambda t: mi.Point3f(*(dr.concat(list(c)) for c in self._vertices(t))), theta, grad_vertices,
                      grad_albedo)

    def mesh(self, theta):
        import trimesh

        return trimesh.Trimesh(vertices=self.vertices(theta), faces=self.faces.astype(np.int64), process=False)


MODELS = ("mannequin", "patches", "mesh")  # (mesh: transient_mi.fit.mesh_model)
