r"""The free-mesh model of ``transient-mi fit --model mesh``: every vertex position and one reflectance.

Parameters and the "large steps" parametrisation
------------------------------------------------
``theta = [u (V x 3, row-major, m), rho]``: ``u = M x`` with ``M = I + lambda L`` (``L`` the boundary-aware
combinatorial Laplacian of :func:`~transient_mi.fit.mesh_regularizers.laplacian_matrix`, ``lambda`` the
``smoothing``), ``x`` the vertices. The optimiser moves ``u``; the vertices are ``x = M^{-1} u`` (a sparse LU
factorisation made once per mesh). A gradient ``dL/dx`` becomes ``dL/du = M^{-1} dL/dx`` (``M`` is
symmetric): the step is a smoothed, diffused version of the raw vertex gradient, so a vertex whose elements
receive little light still moves with its neighbours, and high-frequency noise in the gradient does not
crumple the surface (Nicolet, Jacobson and Jakob 2021, "Large steps in inverse rendering of geometry"). At
``lambda = 0`` it is plain per-vertex descent.

Reflectance: one for the whole mesh by default (``reflectance="global"``: the capture model's single diffuse
BSDF), or one per face (``reflectance="face"``: ``theta = [u, rho_1 .. rho_F]``, a diffuse BSDF whose reflectance
is the mesh's face attribute ``face_reflectance``), held smooth across edges by
:func:`~transient_mi.fit.mesh_regularizers.albedo_regularizer`. At three-bounce light a brighter patch and a larger
or nearer one are nearly the same data: per-face reflectance is for hidden objects whose reflectance varies (two
materials), and its smoothness weight (``albedo``, 1 by default) says how much of a change the data must carry.
At a stage's subdivision each face's four children inherit its reflectance.

The objective the gradient belongs to
-------------------------------------
:meth:`MeshModel.gradient` returns the gradient of ``data + S * R(x)``: the capture's objective
(:mod:`~transient_mi.fit.capture_model`) plus the regularisers of :mod:`~transient_mi.fit.mesh_regularizers`
times ``S`` (:attr:`MeshModel.reg_scale`, the capture's *signal energy* ``0.5 sum k^2 / (k + k_floor)``, the
objective of an empty model, so the regularisers' weights are fractions of the data term whatever the
photon budget). :meth:`MeshModel.regularized` gives both values.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from .mesh_regularizers import MeshTopology, RegularizerWeights, albedo_regularizer, laplacian_matrix, regularizer

__all__ = ["MeshModel", "REFLECTANCES"]

#: The reflectance models: one for the whole mesh, or one per face.
REFLECTANCES = ("global", "face")


class MeshModel:
    """A triangle mesh whose vertices and reflectance are fitted (see the module docstring).

    Parameters
    ----------
    vertices : numpy.ndarray
        ``[V, 3]`` start vertices, m (world frame: the relay wall at z = 0, the hidden space at z > 0).
    faces : numpy.ndarray
        ``[F, 3]`` vertex indices, wound so that the normals face the wall (a diffuse surface reflects on its
        front side only).
    albedo : float or numpy.ndarray
        Start reflectance: one value, or ``[F]`` (one per face, with ``reflectance="face"``).
    reflectance : str
        ``global`` (one reflectance) or ``face`` (one per face; a single ``albedo`` is given to every face).
    smoothing : float
        ``lambda`` of ``M = I + lambda L`` (0: per-vertex steps).
    weights : RegularizerWeights
        The regularisers' weights (fractions of :attr:`reg_scale`).
    step_m : float
        Adam's step in ``u`` per iteration at the start, m.
    reg_scale : float
        ``S`` (module docstring); set by the fit from the capture.
    """

    name = "mesh"

    def __init__(self, vertices, faces, albedo=0.5, *, smoothing: float = 10.0,
                 weights: RegularizerWeights | None = None, step_m: float = 0.003, reg_scale: float = 1.0,
                 reflectance: str = "global"):
        x = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
        self.faces = np.asarray(faces, dtype=np.uint32).reshape(-1, 3)
        self.n_vertices = len(x)
        self.topology = MeshTopology(self.faces, self.n_vertices)
        e = self.topology.edges
        self.h0 = float(np.mean(np.linalg.norm(x[e[:, 1]] - x[e[:, 0]], axis=1))) if len(e) else 1.0
        self.smoothing = float(smoothing)
        self.weights = weights or RegularizerWeights()
        self.reg_scale = float(reg_scale)
        M = (sp.identity(self.n_vertices) + self.smoothing * laplacian_matrix(self.topology)).tocsc()
        self._M = M
        self._lu = splu(M)
        if reflectance not in REFLECTANCES:
            raise ValueError(f"reflectance={reflectance!r}: expected {' or '.join(REFLECTANCES)}")
        self.reflectance = reflectance
        self.names = ["u", "albedo"]  # (theta is long: fit.json summarises it, the meshes are in PLY files)
        n = 3 * self.n_vertices
        #: The vertex block's length in ``theta`` (the reflectance follows: 1 value, or one per face).
        self.n_u = n
        na = len(self.faces) if reflectance == "face" else 1
        a = np.asarray(albedo, dtype=np.float64).ravel()
        if a.size not in (1, na):
            raise ValueError(f"albedo: {a.size} values for {na} reflectance parameters")
        self.lower = np.concatenate([np.full(n, -np.inf), np.full(na, 0.01)])
        self.upper = np.concatenate([np.full(n, np.inf), np.full(na, 1.0)])
        self.step = np.concatenate([np.full(n, float(step_m)), np.full(na, 0.01)])
        self.start_vertices = x.copy()
        self.start_albedo = np.broadcast_to(a, (na,)).copy()
        #: The reflectance the smoothness energy measures changes against (the start's mean).
        self.albedo_ref = float(self.start_albedo.mean())

    # --- parametrisation --------------------------------------------------------------------------------

    def initial(self) -> np.ndarray:
        """``theta`` of the start mesh."""
        return self.theta_of(self.start_vertices, self.start_albedo)

    def theta_of(self, vertices, albedo) -> np.ndarray:
        x = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
        na = len(self.start_albedo)
        return np.concatenate([(self._M @ x).ravel(),
                               np.broadcast_to(np.asarray(albedo, dtype=np.float64).ravel(), (na,))])

    def vertices(self, theta) -> np.ndarray:
        """``[V, 3]`` vertices (m) of ``theta``."""
        u = np.asarray(theta[:self.n_u], dtype=np.float64).reshape(-1, 3)
        return self._lu.solve(u)

    def albedo(self, theta):
        """The reflectance of ``theta``: a float (``reflectance="global"``) or ``[F]`` (``"face"``)."""
        a = np.asarray(theta[self.n_u:], dtype=np.float64)
        return float(a[0]) if self.reflectance == "global" else a.copy()

    def as_dict(self, theta) -> dict:
        x = self.vertices(theta)
        lo, hi = x.min(axis=0), x.max(axis=0)
        a = np.asarray(theta[self.n_u:], dtype=np.float64)
        out = {"albedo": float(a.mean()), "n_vertices": int(self.n_vertices), "n_faces": int(len(self.faces)),
               "bbox_min_m": lo.tolist(), "bbox_max_m": hi.tolist(), "reflectance": self.reflectance}
        if self.reflectance == "face":  # (the values: fitted.ply's face property, mesh_fit.FACE_PLY_PROPERTY)
            out.update(albedo_min=float(a.min()), albedo_max=float(a.max()),
                       albedo_p10_p90=[float(np.percentile(a, 10)), float(np.percentile(a, 90))])
        return out

    # --- objective --------------------------------------------------------------------------------------

    def regularization(self, x) -> tuple[float, np.ndarray, dict]:
        """``(S R(x), S dR/dx [V, 3], parts)`` (parts unweighted and unscaled)."""
        r, g, parts = regularizer(x, self.topology, self.h0, self.weights)
        return self.reg_scale * r, self.reg_scale * g, parts

    def albedo_regularization(self, theta) -> tuple[float, np.ndarray, float]:
        """``(S w E_albedo, S w dE/drho [F], E_albedo)`` of a per-face reflectance (zeros for a global one: it has
        no neighbours)."""
        if self.reflectance == "global":
            return 0.0, np.zeros(1), 0.0
        e, g = albedo_regularizer(np.asarray(theta[self.n_u:], dtype=np.float64), self.topology.face_pairs,
                                  self.albedo_ref)
        w = self.reg_scale * self.weights.albedo
        return w * e, w * g, e

    def total_regularization(self, theta, x=None) -> tuple[float, dict]:
        """``(S R, parts)``: the vertices' regularisers and, with per-face reflectance, its smoothness (parts
        unweighted and unscaled); ``x``: ``theta``'s vertices where the caller has them."""
        r, _, parts = self.regularization(self.vertices(theta) if x is None else x)
        ra, _, ea = self.albedo_regularization(theta)
        if self.reflectance == "face":
            parts = dict(parts, albedo=ea)
        return r + ra, parts

    def gradient(self, theta, grad_vertices: np.ndarray, grad_albedo, area_term: bool = False) -> np.ndarray:
        """``d(data + S R)/dtheta`` from the data term's gradient with respect to the vertices ``[V, 3]`` and the
        reflectance (a float, or ``[F]`` per face). ``area_term`` must be False: a free mesh's area change is in
        the vertex gradient only with the quadrature's (the Monte Carlo renderer's lacks it, and no closed form
        exists for a free deformation)."""
        if area_term:
            raise ValueError("--model mesh needs the quadrature's vertex gradient (area changes included)")
        x = self.vertices(theta)
        _, gr, _ = self.regularization(x)
        gx = np.asarray(grad_vertices, dtype=np.float64).reshape(-1, 3) + gr
        ga = np.asarray(grad_albedo, dtype=np.float64).ravel() + self.albedo_regularization(theta)[1]
        return np.concatenate([self._lu.solve(gx).ravel(), ga])

    def mesh(self, theta):
        import trimesh

        return trimesh.Trimesh(vertices=self.vertices(theta), faces=self.faces.astype(np.int64), process=False)
