"""Mitsuba queries of the deterministic NLOS estimator (:mod:`transient_mi.integrators._nlos_quadrature`).

Visibility of element samples (ray casts built in Dr.Jit from float64 positions, one launch per batch), the
surface interactions at the elements' centroids and at the wall cells, and the BSDF values the pairs' weights
read, all through Mitsuba's own ``ray_intersect`` and ``bsdf.eval``.

**Lambertian BSDFs.** A pair's BSDF value at the element ``f_x(wi, wo)`` (``wi`` towards the cell, ``wo``
towards the spot) depends on the pair through ``wi`` alone. For Mitsuba's ``diffuse`` (and a ``twosided`` of
``diffuse``) ``wi`` enters only through the hemisphere test: ``f(wi, wo) = f(wo, wo)`` when ``wi`` and ``wo``
lie on the same side of the shading normal, 0 otherwise (``diffuse``: ``rho / pi cos(wo)`` when both lie in
front; ``twosided``: the BSDF of ``wi``'s side, mirrored). So ``f_x`` is evaluated once per (element, spot)
with ``wi = wo``, and each pair applies the side test. At the wall, ``f_p(wi, wo)`` (``wi`` towards the detector,
``wo`` towards the element) is ``f(wi, n_wi) |cos(wo)|`` for ``wo`` on ``wi``'s side, with ``n_wi`` the shading
normal on ``wi``'s side: evaluated once per cell. Other BSDFs (:func:`is_lambertian` false) are evaluated per
pair (:func:`pair_bsdf`).
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from transient_mi import _visibility_memo
from transient_mi._upload import upload
from transient_mi.integrators._lanes import to_mono

#: Relative tolerance on a hit distance for a point to count as visible (as the Monte Carlo estimator).
VISIBILITY_REL_TOL = 1e-4
#: Offset of ray origins on the relay wall along its normal (m): no self-hit.
WALL_OFFSET_M = 1e-6


def _f(a) -> "mi.Float":
    return upload(mi.Float, a, np.float32)


def _u(a) -> "mi.UInt32":
    return upload(mi.UInt32, a, np.uint32)


def _v3(a) -> "mi.Vector3f":
    a = np.asarray(a)
    return mi.Vector3f(_f(a[:, 0]), _f(a[:, 1]), _f(a[:, 2]))


def _d3(a) -> list:
    """``[n, 3]`` float64 numpy -> three ``mi.Float64`` columns (positions kept in double precision)."""
    a = np.asarray(a, dtype=np.float64)
    return [upload(mi.Float64, a[:, i], np.float64) for i in range(3)]


def _gather3(cols: list, index) -> list:
    return [dr.gather(mi.Float64, c, index) for c in cols]


def _unit32(v: list):
    """Unit vector (float32) and length (float64) of a float64 vector given as three columns."""
    r = dr.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    return mi.Vector3f(mi.Float(v[0] / r), mi.Float(v[1] / r), mi.Float(v[2] / r)), r


def is_lambertian(bsdf) -> bool:
    """True for Mitsuba's ``diffuse`` and for a ``twosided`` whose BSDFs are all ``diffuse`` (see the module
    docstring: their value depends on ``wi`` only through the hemisphere test)."""
    name = bsdf.class_name()
    if name == "SmoothDiffuse":
        return True
    if name != "TwoSided":
        return False
    children = []

    class _Children(mi.TraversalCallback):
        def put(self, name, obj, flags=None, *rest):
            if isinstance(obj, mi.BSDF):
                children.append(obj)

    bsdf.traverse(_Children())
    return bool(children) and all(c.class_name() == "SmoothDiffuse" for c in children)


def bsdf_value(si, wo) -> "mi.Float":
    """``f cos`` of the BSDF at ``si`` (``wi`` as set) towards the world directions ``wo`` (numpy ``[n, 3]`` or a
    ``mi.Vector3f``), mono (Mitsuba's ``bsdf.eval``: attached to the BSDF's parameters inside ``dr.resume_grad``)."""
    w = wo if isinstance(wo, mi.Vector3f) else _v3(wo)
    return to_mono(si.bsdf().eval(mi.BSDFContext(), si, si.to_local(w)), si.wavelengths)


def spot_intensities(scene, laser_origin: np.ndarray, beam_dir: np.ndarray, spots: np.ndarray,
                     targets: np.ndarray) -> "mi.Float":
    """``f_S cos(theta_SX)`` of the wall at each laser spot ``spots [G, 3]`` (hit along ``beam_dir [G, 3]`` from
    ``laser_origin``, ``wi`` towards the laser) towards every target ``targets [n, 3]`` (radiant intensity per
    photon), target-major ``[n * G]``. One laser ray per spot: the wall's interaction there is gathered for each
    (target, spot), not traced again (a confocal capture has a spot per pixel: n x G rays before)."""
    G, n = len(spots), len(targets)
    ray = mi.Ray3f(mi.Point3f(_v3(np.broadcast_to(laser_origin, (G, 3)))), _v3(beam_dir))
    sig = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=True)
    si = dr.gather(type(sig), sig, dr.arange(mi.UInt32, n * G) % dr.opaque(mi.UInt32, G))
    i = dr.arange(mi.UInt32, n * G)
    t = i // dr.opaque(mi.UInt32, G)
    w, _ = _unit32([a - b for a, b in zip(_gather3(_d3(targets), t), _gather3(_d3(spots), i - t * G))])
    return bsdf_value(si, w)


def visibility_masks(scene, origins: np.ndarray, normal: np.ndarray, pts: np.ndarray, e0: int, e1: int,
                     pairs: np.ndarray | None = None, element_major: bool = False) -> np.ndarray:
    """Visibility of the elements ``e0:e1``'s four samples from every origin (on the relay wall: cell centres,
    laser spots) as masks, ``uint8 [n_pairs]``: bit ``j`` set when sample ``j`` (0 the centroid) is visible. Pairs
    origin-major (pair ``o * (e1 - e0) + e - e0``; with ``pairs``, indices in that order, only those), or with
    ``element_major`` every (element, origin) combination element-major (pair ``(e - e0) * n_origins + o``: the
    laser side's ``[n, G]`` layout).

    A sample is visible when Mitsuba's shadow-ray test (``scene.ray_test``) finds no surface along the ray from
    the origin (offset ``WALL_OFFSET_M`` along the wall's ``normal``) before ``1 - VISIBILITY_REL_TOL`` of the
    distance to the sample (the sample lies on its own surface, so the ray is not tested there). The rays are
    built in float64 from ``pts`` (``[n, 4, 3]``, all elements' samples, centroid first) and cast to float32 in
    the launch that traces them; the four bits are combined there too. Inside an active
    :class:`~transient_mi._visibility_memo.VisibilityMemo` (a fit's renders of one geometry) a call already traced is
    served from it (the same bytes).
    """
    ne, no = e1 - e0, len(origins)
    n_pairs = no * ne if pairs is None else len(pairs)
    if n_pairs == 0:
        return np.zeros(0, dtype=np.uint8)
    memo = _visibility_memo.current()  # (a fit's renders of one geometry: the masks traced once)
    key = None if memo is None else memo.key(scene, origins, normal, pts[e0:e1], pairs, element_major)
    kept = None if memo is None else memo.get(key)
    if kept is not None:
        return kept
    org = _d3(np.asarray(origins, dtype=np.float64) + WALL_OFFSET_M * np.asarray(normal, dtype=np.float64))
    tgt = _d3(pts[e0:e1].reshape(-1, 3))
    pair = dr.arange(mi.UInt32, n_pairs) if pairs is None else _u(pairs)
    if element_major:
        no_o = dr.opaque(mi.UInt32, no)
        e_i = pair // no_o
        o_i = pair - e_i * no_o
    else:
        ne_o = dr.opaque(mi.UInt32, ne)
        o_i = pair // ne_o
        e_i = pair - o_i * ne_o
    o = _gather3(org, o_i)
    mask = mi.UInt32(0)
    for j in range(4):
        t = _gather3(tgt, e_i * 4 + j)
        d, r = _unit32([t[0] - o[0], t[1] - o[1], t[2] - o[2]])
        ray = mi.Ray3f(mi.Point3f(mi.Float(o[0]), mi.Float(o[1]), mi.Float(o[2])), d,
                       mi.Float(r) * (1.0 - VISIBILITY_REL_TOL), 0.0, [])
        mask |= dr.select(scene.ray_test(ray), 0, 1 << j)
    out = np.asarray(mask).astype(np.uint8)
    if memo is not None:
        memo.put(key, out)
    return out


class ElementSurfaces:
    """The surface interaction at every element's centroid, constructed from the element's source triangle
    (Mitsuba's ``compute_surface_interaction`` at the centroid's barycentric coordinates: no ray cast, so an
    occluder cannot stand in for the element), and what the pairs need of the element's BSDF.

    ``n_sh``: the shading normals ``[n, 3]`` (float64 of Mitsuba's float32); ``lambertian``: every element's
    BSDF is Lambertian (:func:`is_lambertian`).
    """

    def __init__(self, hidden_shapes, hidden_ptrs, faces, tri: np.ndarray, src: np.ndarray):
        self.n = n = len(tri)
        X0 = tri.mean(axis=1)
        t0 = faces.tri[src]  # the source triangles [n, 3, 3]
        e1, e2, q = t0[:, 1] - t0[:, 0], t0[:, 2] - t0[:, 0], X0 - t0[:, 0]
        g11, g12, g22 = (e1 * e1).sum(1), (e1 * e2).sum(1), (e2 * e2).sum(1)
        r1, r2 = (q * e1).sum(1), (q * e2).sum(1)
        det = g11 * g22 - g12 * g12
        b1 = (g22 * r1 - g12 * r2) / det
        b2 = (g11 * r2 - g12 * r1) / det
        nrm = np.cross(e1, e2)
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        shape = faces.shape[src]
        pi = dr.zeros(mi.PreliminaryIntersection3f, n)
        pi.t = dr.full(mi.Float, 1.0, n)
        pi.prim_uv = mi.Point2f(_f(b1), _f(b2))
        pi.prim_index = _u(faces.face[src])
        pi.shape = dr.gather(mi.ShapePtr, hidden_ptrs, _u(shape))
        pi.valid = mi.Bool(True)
        ray = mi.Ray3f(mi.Point3f(_v3(X0 + nrm)), _v3(-nrm))  # (wi along the normal; replaced per use)
        self.si = pi.compute_surface_interaction(ray, mi.RayFlags.All)
        dr.eval(self.si)
        self.X0 = X0
        self.n_sh = np.ascontiguousarray(np.asarray(self.si.sh_frame.n, dtype=np.float64).reshape(3, -1).T)
        self.lambertian = all(is_lambertian(s.bsdf()) for s in hidden_shapes)

    def toward(self, S: np.ndarray, e0: int = 0, e1: int | None = None):
        """``(value [k, G], side [k, G] int8)`` of the elements ``e0:e1`` (default: every one): ``f cos`` with ``wi
        = wo`` = the direction to each spot ``S`` ``[G, 3]`` (the Lambertian value of every pair on that side,
        module docstring), and the side of the shading normal the spot lies on (+1, -1; 0 in the plane)."""
        e1 = self.n if e1 is None else e1
        si = self._towards(S, e0, e1)
        v = np.asarray(_eval_local(si, si.wi), dtype=np.float64).reshape(e1 - e0, len(S))
        return v, np.sign(np.asarray(si.wi.z)).astype(np.int8).reshape(e1 - e0, len(S))

    def toward_ad(self, S: np.ndarray) -> "mi.Float":
        """:meth:`toward`'s values, element-major ``[n * G]``, attached (call inside ``dr.resume_grad``)."""
        si = self._towards(S)
        return _eval_local(si, si.wi)

    def _towards(self, S: np.ndarray, e0: int = 0, e1: int | None = None):
        """The centroids' interactions with ``wi`` towards each spot ``S [G, 3]``, element-major ``[k * G]`` for
        the elements ``e0:e1`` (default: every one; gathered in Dr.Jit from one copy of the spots and the
        centroids)."""
        G = len(S)
        e1 = self.n if e1 is None else e1
        i = dr.arange(mi.UInt32, (e1 - e0) * G)
        g = dr.opaque(mi.UInt32, G)
        k = i // g
        e = k + dr.opaque(mi.UInt32, e0) if e0 else k
        si = dr.gather(type(self.si), self.si, e)
        w, _ = _unit32([a - b for a, b in zip(_gather3(_d3(S), i - k * g), _gather3(_d3(self.X0), e))])
        si.wi = si.to_local(w)
        return si

    def pair_values(self, cell_p: np.ndarray, e0: int, e1: int, spots: list) -> list:
        """The general path for BSDFs that are not Lambertian: ``f_x`` of every pair (cells x elements ``e0:e1``,
        cell-major) with ``wi`` towards the pair's cell centre, towards each entry of ``spots`` (a spot position
        ``[3]`` for all pairs, or ``[n_pairs, 3]``, one per pair): one ``mi.Float`` per entry (attached inside
        ``dr.resume_grad``)."""
        ne = e1 - e0
        e = e0 + np.tile(np.arange(ne), len(cell_p))
        si = dr.gather(type(self.si), self.si, _u(e))
        X = _d3(self.X0[e])
        wi, _ = _unit32([a - b for a, b in zip(_d3(np.repeat(cell_p, ne, axis=0)), X)])
        si.wi = si.to_local(wi)
        out = []
        for S in spots:
            wo, _ = _unit32([a - b for a, b in zip(_d3(np.atleast_2d(S)), X)])
            out.append(bsdf_value(si, wo))
        return out


def _eval_local(si, wo_local) -> "mi.Float":
    """``f cos`` at ``si`` towards the local direction ``wo_local``, mono."""
    return to_mono(si.bsdf().eval(mi.BSDFContext(), si, wo_local), si.wavelengths)


class WallCells:
    """The relay wall at every cell centre (hit from the detector, ``wi`` towards it) and its BSDF there.

    ``lambertian``: the wall's BSDF is Lambertian; then ``value [C]`` is ``f(wi, n_wi)`` (``n_wi`` the shading
    normal on ``wi``'s side), ``n_sh [C, 3]`` the shading normal and ``side [C]`` the side ``wi`` lies on, so a
    pair's ``f_p = value |cos(wo)|`` where ``wo`` lies on that side (module docstring).
    """

    def __init__(self, scene, setup, cell_p: np.ndarray, D: np.ndarray):
        dq = cell_p - D
        dq /= np.linalg.norm(dq, axis=1, keepdims=True)
        ray = mi.Ray3f(mi.Point3f(_v3(np.broadcast_to(D, (len(cell_p), 3)))), _v3(dq))
        self.si = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=True)
        dr.eval(self.si)  # (once: gathered per pair by the general path)
        self.lambertian = is_lambertian(setup.relay_wall.bsdf())
        z = np.asarray(self.si.wi.z)
        self.side = np.sign(z).astype(np.int8)
        self.n_sh = np.ascontiguousarray(np.asarray(self.si.sh_frame.n, dtype=np.float64).reshape(3, -1).T)
        self.value = np.asarray(self.value_ad(), dtype=np.float64) if self.lambertian else None

    def value_ad(self) -> "mi.Float":
        """``f(wi, n_wi)`` per cell (Lambertian walls; attached inside ``dr.resume_grad``)."""
        si = self.si
        return _eval_local(si, mi.Vector3f(0.0, 0.0, dr.select(si.wi.z < 0, -1.0, 1.0)))

    def pair_values(self, cell_p: np.ndarray, X0: np.ndarray, e0: int, e1: int) -> "mi.Float":
        """``f_p`` of every pair (cells x elements ``e0:e1``, cell-major) towards its element's centroid: the
        general path for walls that are not Lambertian."""
        ne = e1 - e0
        c = np.repeat(np.arange(len(cell_p)), ne)
        si = dr.gather(type(self.si), self.si, _u(c))
        wo, _ = _unit32([a - b for a, b in zip(_d3(np.tile(X0[e0:e1], (len(cell_p), 1))), _d3(cell_p[c]))])
        return bsdf_value(si, wo)
