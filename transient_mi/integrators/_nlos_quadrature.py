r"""The deterministic three-bounce NLOS estimator (``estimator="quadrature"``).

Three-bounce light, laser spot ``S`` -> hidden point ``X`` -> wall point ``p`` of pixel ``k``'s patch ->
detector ``D``, is the 4-D integral (photons per pulse, arrival time ``\ell / c``)

.. math::

    \Phi_k(t) = N \int_{A_k} \int_{H} \frac{W_0(p)}{A_{pix}} \,[f_p \cos\theta_{pX}]\,
        \frac{\cos\theta_X}{|X - p|^2}\,[f_X \cos\theta_{XS}]\,\frac{[f_S \cos\theta_{SX}]}{|S - X|^2}\,
        V(p, X)\, V(X, S)\; \delta(t - \ell(p, X)/c)\; dA_X\, dA_p,

the same integrand the Monte Carlo estimator samples (:mod:`transient_mi.integrators.transient_nlos_path`:
``W_0`` the sensor weight, every bracket one Mitsuba ``bsdf.eval``, so BSDFs and textures are the scene's own).
Here it is integrated by quadrature instead of sampling:

* **Elements.** Every triangle of every hidden shape (mesh shapes; Mitsuba's ``rectangle`` is one) is
  split uniformly until no edge is longer than ``element_size_m``; every pixel patch into
  ``patch_cells x patch_cells`` square cells (one point, the centre, with ``pixel_sampling="center"``).
* **Weight of a pair (element, cell): the midpoint rule, with the cell's first moment.** The integrand at the
  element's centroid and the cell's centre, times both areas; across the cell the weight is taken linear (its
  geometric factors, sensor weight, the wall's cosine and ``cos(theta_X) / r^2``, differenced over the cell's
  edge midpoints), and that tilt moves light between the pair's bins exactly (it leaves the pair's total
  unchanged): the light arriving late in a cell is not weighted as the light arriving early.
* **Arrival times: exact for the linearised path length.** Across a pair the optical path length is
  linear to second order; the pair's arrival-time distribution is the triangular distribution of the
  element's three vertex values convolved with the cell's two uniform components, integrated exactly over
  every bin (:mod:`transient_mi.integrators._nlos_time_spread`), not deposited at the centre. The leading
  second-order term (the path length is convex) is removed from the mean: the knots are shifted by 3/4 of
  the centroid's deviation from the vertex mean (exact for a quadratic over a triangle) and by 1/3 of the
  cell's corner-mean deviation from its centre (exact for a quadratic over a square).
* **Visibility.** ``V(p, X)`` and ``V(X, S)`` are tested by ray casts at the centroid and at three points
  near the element's corners (each leg from the cell centre and from the spot). Elements whose samples
  disagree for some pixel or spot (tested from the coarse level's cell centres) are split in four, up to
  ``refine_levels`` times; a pair still mixed
  then contributes the visible share of its samples (centroid 1/2, corners 1/6 each).
  Visibility is assumed constant over an element whose samples agree (an occluder smaller than an element
  can be missed: keep ``element_size_m`` below the smallest feature).

Error (stored like the Monte Carlo variance, ``kind: "error_bound"``), per bin, the sum of

1. **mixed visibility** (a bound): the whole unoccluded light of every pair whose samples disagree, times
   ``max(share, 1 - share)``, spread like its light;
2. **discretisation** (an a-posteriori estimate): ``|I_h - I_2h| / ESTIMATE_DIVISOR``, from the difference
   between the result and a coarse level with each element's parent (twice the size) and half the cells per
   side, each bin taking the largest difference within ``ESTIMATE_REACH_BINS`` bins (the difference crosses
   zero where the errors do not). Both levels converge at least at second order (midpoint rule for the
   weight, second-order path length), so ``I_2h - I_h`` is about ``2^2 - 1 = 3`` times the fine level's error
   (Richardson); on the letter the per-bin error falls faster (~10x per halving), so it is conservative there.
   Pixel totals keep the whole difference. An estimate, not a guarantee: tested by self-convergence (against a
   much finer level it covers pixel totals, each pixel's and each time window's squares).

What it does not do (refused in one line; use ``estimator="monte_carlo"``): windows and media on the device
legs or in hidden space, a divergent laser beam, a non-planar relay wall, shapes that are not meshes
(spheres, cylinders). The wall's first-bounce return is added in closed form as in the Monte Carlo estimator.
With ``max_depth`` above 4 (or -1) the light beyond three bounces is added by the Monte Carlo estimator
restricted to the remaining paths (``KernelConstants.skip_three_bounce``: without the three-bounce connection
and the wall return); its variance, from the replicates, is stored beside the quadrature's error
(:mod:`transient_mi.capture_error`). Differentiable (:mod:`~._nlos_quadrature_ad`, :mod:`~._nlos_quadrature_geom`).
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np
from scipy.ndimage import maximum_filter1d

from transient_core.units import C_M_PER_PS
from transient_mi.integrators._lanes import to_mono
from transient_mi.integrators._nlos_elements import fine_provenance, mesh_triangles, sample_points, split4, subdivide
from transient_mi.integrators._nlos_time_spread import pair_geometry, spread_spot, visibility_rays
from transient_mi.props import PluginParameterError
from transient_mi.time_axis import apply_kernel

#: Relative tolerance on a hit distance for a point to count as visible (as the Monte Carlo estimator).
VISIBILITY_REL_TOL = 1e-4
#: The discretisation estimate of a bin is the largest two-level difference within this many bins of it.
ESTIMATE_REACH_BINS = 2
#: The two-level difference over the fine level's error for a second-order method (Richardson: ``2^2 - 1``).
ESTIMATE_DIVISOR = 3.0
#: Pairs (element, cell) evaluated per Dr.Jit launch.
PAIRS_PER_CHUNK = 1 << 20
#: Default longest element edge, m.
DEFAULT_ELEMENT_SIZE_M = 0.01
#: Default cells per patch side.
DEFAULT_PATCH_CELLS = 4
#: Default visibility refinement levels.
DEFAULT_REFINE_LEVELS = 3


def needs_remainder(options: dict) -> bool:
    """True when ``max_depth`` (-1: unlimited) asks for light beyond three bounces: the capture is then the
    quadrature's three-bounce light plus the Monte Carlo remainder (every other path, see
    :func:`~._nlos_render.render_spots` and ``KernelConstants.skip_three_bounce``)."""
    d = int(options.get("max_depth", 4))
    return d == -1 or d > 4


def check_supported(setup, options: dict, plugin: str) -> None:
    """Refuse, in one line naming the reason, a capture the quadrature does not render."""
    why = None
    if setup.windows:
        why = "the scene has windows (delta-transmissive shapes)"
    elif setup.laser.divergence_mrad > 0:
        why = f"the laser beam diverges (divergence_mrad={setup.laser.divergence_mrad:g})"
    elif not setup.planar_wall:
        why = "the relay wall is not planar"
    else:
        for s in setup.hidden_shapes:
            if not s.is_mesh():
                why = f"the hidden shape {s.id() or type(s).__name__!r} is not a mesh (spheres, cylinders, ...)"
                break
    if why is not None:
        raise PluginParameterError(f"{plugin}: estimator=quadrature cannot render this capture: {why}; use "
                                   "estimator=monte_carlo")


# ------------------------------------------------------------------ Mitsuba queries


def _f(a) -> "mi.Float":
    return mi.Float(np.ascontiguousarray(a, dtype=np.float32))


def _v3(a) -> "mi.Vector3f":
    a = np.asarray(a)
    return mi.Vector3f(_f(a[:, 0]), _f(a[:, 1]), _f(a[:, 2]))


def _visible(scene, origins: np.ndarray, targets: np.ndarray, target_shape, offset_normal: np.ndarray):
    """Whether the first surface along ``origin -> target`` is ``target_shape`` at the target's distance.

    ``origins`` lie on the relay wall and are offset along its ``offset_normal`` (no self-hit); returns a
    numpy bool array and the surface interactions (for BSDF evaluations at the targets).
    """
    o = origins + 1e-6 * offset_normal
    d = targets - o
    dist = np.linalg.norm(d, axis=1)
    return _cast(scene, o.astype(np.float32), (d / dist[:, None]).astype(np.float32), dist.astype(np.float32),
                 target_shape)


def _cast(scene, o: np.ndarray, d: np.ndarray, dist: np.ndarray, target_shape):
    """As :func:`_visible` for prepared float32 rays (:func:`~._nlos_time_spread.visibility_rays`)."""
    ray = mi.Ray3f(mi.Point3f(mi.Float(o[:, 0].copy()), mi.Float(o[:, 1].copy()), mi.Float(o[:, 2].copy())),
                   mi.Vector3f(mi.Float(d[:, 0].copy()), mi.Float(d[:, 1].copy()), mi.Float(d[:, 2].copy())))
    si = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=False)
    dist_f = mi.Float(dist)
    ok = si.is_valid() & (si.shape == target_shape) & (dr.abs(si.t - dist_f) <= VISIBILITY_REL_TOL * dist_f)
    return si, ok


def bsdf_value(si, wo: np.ndarray) -> "mi.Float":
    """``f cos`` of the BSDF at ``si`` (``wi`` as traced) towards the world directions ``wo`` ``[n, 3]``, mono
    (Mitsuba's ``bsdf.eval``: attached to the BSDF's parameters inside ``dr.resume_grad``)."""
    return to_mono(si.bsdf().eval(mi.BSDFContext(), si, si.to_local(_v3(wo))), si.wavelengths)


def spot_intensity(scene, laser_origin: np.ndarray, beam_dir: np.ndarray, spot: np.ndarray,
                   targets: np.ndarray) -> "mi.Float":
    """``f_S cos(theta_SX)`` of the wall at the laser spot (hit along ``beam_dir`` from ``laser_origin``, ``wi``
    towards the laser) towards each of ``targets`` ``[n, 3]`` seen from ``spot`` (radiant intensity per photon)."""
    n = len(targets)
    ray = mi.Ray3f(mi.Point3f(_v3(np.broadcast_to(laser_origin, (n, 3)))), _v3(np.broadcast_to(beam_dir, (n, 3))))
    sig = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=True)
    to_x = targets - spot
    return bsdf_value(sig, to_x / np.linalg.norm(to_x, axis=1, keepdims=True))


class _Geometry:
    """The capture's fixed geometry in numpy float64 (world frame, metres)."""

    def __init__(self, setup, film, cells: int):
        self._setup, self._film = setup, film
        fr = setup.frame
        W, H = setup.width, setup.height
        self.W, self.H = W, H
        center = setup.pixel_sampling == "center"
        self.m = 1 if center else int(cells)
        m = self.m
        pc = fr.grid(W, H, setup.pitch_m).reshape(-1, 3)  # [P, 3] patch centres in the wall plane
        off = (np.arange(m) + 0.5) / m - 0.5
        ou, ov = np.meshgrid(off, off, indexing="xy")  # [m, m]
        fp = setup.footprint_m
        delta = (ou.reshape(-1, 1) * fr.ex + ov.reshape(-1, 1) * fr.ey) * (0.0 if center else fp)  # [m^2, 3]
        self.cell_p = (pc[:, None, :] + delta[None]).reshape(-1, 3)  # [P m^2, 3]
        self.cell_pixel = np.repeat(np.arange(W * H), m * m)
        self.cell_ax = fr.ex * (0.0 if center else fp / m)
        self.cell_ay = fr.ey * (0.0 if center else fp / m)
        self.cell_half_diag = 0.0 if center else fp / m / math.sqrt(2.0)
        self.normal = np.asarray(fr.normal, dtype=np.float64)
        D = np.asarray(setup.detector, dtype=np.float64)
        self.D = D
        self.ap_n = np.asarray(setup.aperture_normal, dtype=np.float64)
        to_q = self.cell_p - D
        dist_q = np.linalg.norm(to_q, axis=1)
        dq = to_q / dist_q[:, None]
        # W0 / A_pix times the cell's share of the patch: A_ap cos(theta_ap) cos(theta_q) / |q - D|^2 * A_pix / m^2
        self.cell_w0 = (setup.aperture_area_m2 * np.maximum(dq @ setup.aperture_normal, 0.0)
                        * np.abs(dq @ self.normal) / dist_q ** 2 * setup.footprint_m ** 2 / (m * m))
        self.fl = 1.0 if setup.include_first_last else 0.0
        self.cell_opl_d = self.fl * dist_q  # the detector leg
        self.dq = dq
        axis = film.time_axis()
        self.taps = film.kernel_taps()
        self.pad = len(self.taps) // 2
        self.n_bins = axis.n_bins
        self.n_ext = axis.n_bins + 2 * self.pad
        self.bin_m = axis.bin_width_ps * C_M_PER_PS
        self.t0_m = axis.t0_ps * C_M_PER_PS
        self.N = float(setup.photons_per_pulse)

    def with_cells(self, cells: int) -> "_Geometry":
        """The same capture with ``cells`` cells per patch side."""
        return _Geometry(self._setup, self._film, cells)


class _SpotSide:
    """Per laser spot and element: the spot's surface interaction, visibility of the element's samples,
    the spot's intensity towards the centroid, distances."""

    def __init__(self, scene, setup, spots: list[int], tri, shape_index, hidden_ptrs):
        n = len(tri)
        pts = sample_points(tri)  # [n, 4, 3]
        Lo = np.asarray(setup.laser_origin, dtype=np.float64)
        normal = np.asarray(setup.frame.normal, dtype=np.float64)
        self.S = np.asarray(setup.spots, dtype=np.float64)[spots]  # [G, 3]
        self.laser_leg = np.linalg.norm(self.S - Lo, axis=1)  # [G]
        tg = np.asarray(setup.spot_targets, dtype=np.float64)[spots]
        d = tg - Lo
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        shape_ptr = dr.gather(mi.ShapePtr, hidden_ptrs, mi.UInt32(np.repeat(shape_index, 4).astype(np.uint32)))
        self.Lo, self.beam = Lo, d
        self.vis = np.zeros((len(spots), n, 4), dtype=bool)
        self.intensity = np.zeros((len(spots), n))  # f_S cos(theta_SX) towards the centroid
        for g in range(len(spots)):
            S = self.S[g]
            _, ok = _visible(scene, np.broadcast_to(S, (n * 4, 3)), pts.reshape(-1, 3), shape_ptr, normal)
            self.vis[g] = np.asarray(ok).reshape(n, 4)
            # the laser ray to this spot, once per element (wi towards the laser)
            self.intensity[g] = np.asarray(spot_intensity(scene, Lo, d[g], S, pts[:, 0]), dtype=np.float64)
        self.r_sv = np.linalg.norm(tri[None, :, :, :] - self.S[:, None, None, :], axis=3)  # [G, n, 3]
        self.r_sx = np.linalg.norm(pts[None, :, 0, :] - self.S[:, None, :], axis=2)  # [G, n]


def _mixed_elements(scene, g: _Geometry, spot_side: _SpotSide, tri, shape_index, hidden_ptrs) -> np.ndarray:
    """Elements whose visibility samples disagree for some cell or spot (bool ``[n]``)."""
    n = len(tri)
    mixed = (spot_side.vis.any(axis=2) & ~spot_side.vis.all(axis=2)).any(axis=0)
    pts = sample_points(tri)
    C = len(g.cell_p)
    per = max(1, PAIRS_PER_CHUNK // (4 * C))
    for e0 in range(0, n, per):
        e1 = min(n, e0 + per)
        ne = e1 - e0
        org = np.repeat(g.cell_p, ne * 4, axis=0)
        tgt = np.tile(pts[e0:e1].reshape(-1, 3), (C, 1))
        sp = dr.gather(mi.ShapePtr, hidden_ptrs,
                       mi.UInt32(np.tile(np.repeat(shape_index[e0:e1], 4), C).astype(np.uint32)))
        _, ok = _visible(scene, org, tgt, sp, g.normal)
        v = np.asarray(ok).reshape(C, ne, 4)
        mixed[e0:e1] |= (v.any(axis=2) & ~v.all(axis=2)).any(axis=0)
    return mixed


def refine_visibility(scene, setup, g: _Geometry, spots, tri, shape_index, refine_levels: int, hidden_ptrs, prov=None):
    """Split mixed-visibility elements (and ``prov``) in four, ``refine_levels`` times at most."""
    levels = 0
    for _ in range(refine_levels):
        side = _SpotSide(scene, setup, spots, tri, shape_index, hidden_ptrs)
        mixed = _mixed_elements(scene, g, side, tri, shape_index, hidden_ptrs)
        if not mixed.any():
            break
        keep = ~mixed
        tri = np.concatenate([tri[keep], split4(tri[mixed])])
        shape_index = np.concatenate([shape_index[keep], np.repeat(shape_index[mixed], 4)])
        prov = None if prov is None else np.concatenate([prov[keep], split4(prov[mixed])])
        levels += 1
    return tri, shape_index, levels, prov


# ------------------------------------------------------------------ the render


def patch_cells(setup, options: dict) -> int:
    """Cells per patch side of the fine level (one with ``pixel_sampling="center"``)."""
    return 1 if setup.pixel_sampling == "center" else int(options.get("patch_cells", DEFAULT_PATCH_CELLS))


def level_elements(scene, setup, g: _Geometry, options: dict, spot_ids, hidden_ptrs, with_provenance=False):
    """The elements of both levels: ``(tri_c, idx_c, tri_f, idx_f, refine_levels_used[, fine provenance])`` (coarse:
    edges of at most twice ``element_size_m``; fine: each coarse one split in four, then refined where mixed)."""
    h = float(options.get("element_size_m", DEFAULT_ELEMENT_SIZE_M))
    tri0, idx0 = mesh_triangles(setup.hidden_shapes)
    tri_c, idx_c = subdivide(tri0, idx0, 2.0 * h)
    tri_f, idx_f = split4(tri_c), np.repeat(idx_c, 4)
    prov = fine_provenance(tri0, 2.0 * h) if with_provenance else None
    # split as the coarse level's cells see it (a quarter of the rays); still-mixed fine pairs are bounded
    tri_f, idx_f, levels, prov = refine_visibility(scene, setup, g.with_cells(max(1, g.m // 2)), spot_ids, tri_f,
                                                   idx_f, int(options.get("refine_levels", DEFAULT_REFINE_LEVELS)),
                                                   hidden_ptrs, prov)
    return (tri_c, idx_c, tri_f, idx_f, levels) + ((prov,) if with_provenance else ())


def render_spots_quadrature(setup, scene, film, options: dict, spots: list[int]):
    """Render the three-bounce light of a group of spots by quadrature (see the module docstring).

    Two levels are integrated: the *fine* one (elements of at most ``element_size_m``, ``patch_cells``
    cells per patch side, visibility refinement) is the result; the *coarse* one (each fine element's
    parent, of twice the size, and half the cells per side, at least one) serves the error estimate.

    Returns one :class:`~transient_mi.films.transient_film.TransientResult` per spot with ``error_bound``
    and ``total_error_bound`` set and no variance.
    """
    from transient_mi.films.transient_film import TransientResult

    m = patch_cells(setup, options)
    g = _Geometry(setup, film, m)
    confocal = setup.capture == "confocal"
    P = g.W * g.H
    max_depth = options.get("max_depth", 4)
    spot_ids = list(range(setup.n_spots)) if confocal else list(spots)
    G_out = 1 if confocal else len(spots)
    zeros = np.zeros((G_out, P, g.n_ext))
    fine = {"hist": zeros, "bound": zeros.copy(), "steady": np.zeros((G_out, P)), "vis_err": np.zeros((G_out, P)),
            "outside": np.zeros((G_out, P)), "pairs": 0}
    coarse = None
    info = {"elements": 0, "coarse_elements": 0, "refine_levels": 0, "pairs": 0, "patch_cells": m}
    if setup.hidden_shapes and (max_depth >= 4 or max_depth == -1):
        hidden_ptrs = mi.ShapePtr(setup.hidden_shapes)
        tri_c, idx_c, tri_f, idx_f, levels = level_elements(scene, setup, g, options, spot_ids, hidden_ptrs)
        g_c = g.with_cells(max(1, g.m // 2))
        fine = _level(scene, setup, g, tri_f, idx_f, hidden_ptrs, spot_ids, confocal, G_out)
        coarse = _level(scene, setup, g_c, tri_c, idx_c, hidden_ptrs, spot_ids, confocal, G_out)
        info.update(elements=len(tri_f), coarse_elements=len(tri_c), refine_levels=levels,
                    pairs=fine["pairs"] + coarse["pairs"])
    hist = fine["hist"]
    steady = fine["steady"]
    outside = fine["outside"]
    # error: the light of mixed visibility, plus the discretisation estimated by the coarse level
    # (the difference of two levels crosses zero where their errors do not: each bin takes the largest
    # difference within ESTIMATE_REACH_BINS bins of it)
    bound = fine["bound"]
    if coarse is not None:
        bound = bound + maximum_filter1d(np.abs(fine["hist"] - coarse["hist"]), 2 * ESTIMATE_REACH_BINS + 1,
                                         axis=-1, mode="constant") / ESTIMATE_DIVISOR
    tot_bound = fine["vis_err"] + (np.abs(fine["steady"] - coarse["steady"]) if coarse is not None else 0.0)
    # closed-form first-bounce return of the wall (as the Monte Carlo estimator; no error)
    wr = setup.wall_return
    for gi in range(G_out):
        js = spot_ids if confocal else [spots[gi]]
        for j in js:
            pix = int(wr["pixel"][j])
            ph = float(wr["photons"][j])
            if pix < 0 or ph <= 0:
                continue
            b = int(math.floor((float(wr["opl_m"][j]) - g.t0_m) / g.bin_m)) + g.pad
            steady[gi, pix] += ph
            if 0 <= b < g.n_ext:
                hist[gi, pix, b] += ph
            else:
                outside[gi, pix] += ph
    results = []
    for gi in range(G_out):
        hk = apply_kernel(hist[gi], g.taps) if g.pad else hist[gi]
        ek = apply_kernel(bound[gi], g.taps) if g.pad else bound[gi]
        in_hist = float(hk.sum())
        tot = float(steady[gi].sum())
        frac = max(0.0, 1.0 - in_hist / tot) if tot > 0 else 0.0
        results.append(TransientResult(
            histogram=hk.astype(np.float32).reshape(g.H, g.W, g.n_bins),
            steady=steady[gi].astype(np.float32).reshape(g.H, g.W),
            dropped_contributions=int((outside[gi] > 1e-12 * max(tot, 1e-300)).sum()),
            dropped_fraction=frac,
            samples=info["pairs"],
            variance=None,
            total_variance=None,
            replicates=1,
            error_bound=ek.astype(np.float32).reshape(g.H, g.W, g.n_bins),
            total_error_bound=tot_bound[gi].astype(np.float32).reshape(g.H, g.W),
            estimator_info=dict(info),
        ))
    return results


def element_terms(tri: np.ndarray):
    """``(pts [n, 4, 3] visibility samples (centroid first), area [n], unit normal [n, 3])`` of elements."""
    pts = sample_points(tri)
    nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(nrm, axis=1)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    return pts, area, nrm


def chunk_starts(g: _Geometry, n: int):
    """``(e0, e1)`` element ranges of the chunks (``PAIRS_PER_CHUNK`` pairs each at most)."""
    per = max(1, PAIRS_PER_CHUNK // len(g.cell_p))
    return [(e0, min(n, e0 + per)) for e0 in range(0, n, per)]


class Chunk:
    """The detector side of the pairs (every cell x the elements ``e0:e1``), sorted by cell (hence by pixel):
    visibility of the element's samples from the cell, pair geometry (:func:`~._nlos_time_spread.pair_geometry`),
    the surface interactions at the element (``si_x``, ``wi`` towards the cell) and at the wall (``si_p``,
    ``wi`` towards the detector) and the wall BSDF ``f_p`` towards the element."""

    def __init__(self, scene, g: _Geometry, tri, idx, hidden_ptrs, pts, area, nrm, e0: int, e1: int):
        C = len(g.cell_p)
        ne = e1 - e0
        X0 = pts[:, 0]
        self.ce = ce = np.repeat(np.arange(C), ne)  # pair -> cell
        self.ee = ee = np.tile(np.arange(e0, e1), C)  # pair -> element
        sp = dr.gather(mi.ShapePtr, hidden_ptrs, mi.UInt32(idx[ee].astype(np.uint32)))
        self.si_x, ok_c = _cast(scene, *visibility_rays(ce, ee, g.cell_p, pts, g.normal, 0, 1), sp)
        dr.eval(self.si_x, ok_c)  # wi towards p: the BSDF at X for every spot
        sp3 = dr.gather(mi.ShapePtr, hidden_ptrs, mi.UInt32(np.repeat(idx[ee], 3).astype(np.uint32)))
        _, ok3 = _cast(scene, *visibility_rays(ce, ee, g.cell_p, pts, g.normal, 1, 3), sp3)
        self.vis_p = np.ascontiguousarray(np.concatenate([np.asarray(ok_c).reshape(-1, 1),
                                                          np.asarray(ok3).reshape(-1, 3)], axis=1))
        del sp3, ok3, ok_c
        (self.d_px, self.r_px, self.geo, self.r_pv, self.opl_d, self.w1, self.w2, self.cell_shift,
         self.tilt) = pair_geometry(ce, ee, g.cell_p, g.cell_w0, X0, tri, nrm, area, g.D, g.cell_ax, g.cell_ay, g.fl,
                                    g.bin_m, g.N, g.cell_half_diag > 0, g.ap_n, g.normal)
        ray_p = mi.Ray3f(mi.Point3f(_v3(np.broadcast_to(g.D, (len(ce), 3)))), _v3(g.dq[ce]))
        self.si_p = scene.ray_intersect(ray_p, ray_flags=mi.RayFlags.All, coherent=True)
        self.f_p = np.asarray(bsdf_value(self.si_p, self.d_px), dtype=np.float64)
        pix = g.cell_pixel[ce]
        self.pixel_start = np.searchsorted(pix, np.arange(g.W * g.H + 1)).astype(np.int64)
        self.pe = ee.astype(np.int64)

    def jobs(self, confocal: bool, n_spots: int):
        """``(spot index, output index, pair slice)``: confocal, each pixel's pairs with its own spot (spot
        ``k`` lies on pixel ``k``'s patch); otherwise every pair with every spot of the group."""
        ps = self.pixel_start
        if confocal:
            return [(k, 0, slice(ps[k], ps[k + 1])) for k in range(len(ps) - 1)]
        return [(gi, gi, slice(0, len(self.ee))) for gi in range(n_spots)]

    def job_pixel_start(self, confocal: bool, si_idx: int, sl: slice) -> np.ndarray:
        """The ``pixel_start`` of a job: a confocal job's pairs all belong to pixel ``si_idx``."""
        if not confocal:
            return self.pixel_start
        ps = np.full(len(self.pixel_start), sl.start, dtype=np.int64)
        ps[si_idx + 1:] = sl.stop
        return ps

    def to_spot(self, X0: np.ndarray, S: np.ndarray, sl: slice) -> np.ndarray:
        """Unit directions from the elements of the pairs ``sl`` to the spot ``S``."""
        to_s = S - X0[self.ee[sl]]
        return to_s / np.linalg.norm(to_s, axis=1, keepdims=True)

    def si_x_of(self, confocal: bool, sl: slice):
        """The element-side interactions of the pairs ``sl`` (all of them outside confocal captures)."""
        if confocal:
            return dr.gather(type(self.si_x), self.si_x, mi.UInt32(np.arange(sl.start, sl.stop, dtype=np.uint32)))
        return self.si_x

    def spread_args(self):
        """The per-pair arguments of :func:`~._nlos_time_spread.spread_spot` after ``base``."""
        return (self.vis_p, self.r_pv, self.r_px, self.opl_d, self.cell_shift, self.w1, self.w2, self.tilt)


def _level(scene, setup, g: _Geometry, tri, idx, hidden_ptrs, spot_ids, confocal, G_out) -> dict:
    """Integrate one level (elements ``tri``, the cells of ``g``) for every spot of the group.

    Returns ``hist``, ``bound`` (light of mixed visibility, per bin) ``[G, P, n_ext]``, ``steady``,
    ``vis_err``, ``outside`` ``[G, P]`` and ``pairs``.
    """
    P = g.W * g.H
    out = {"hist": np.zeros((G_out, P, g.n_ext)), "bound": np.zeros((G_out, P, g.n_ext)),
           "steady": np.zeros((G_out, P)), "vis_err": np.zeros((G_out, P)), "outside": np.zeros((G_out, P)),
           "pairs": 0}
    side = _SpotSide(scene, setup, spot_ids, tri, idx, hidden_ptrs)
    pts, area, nrm = element_terms(tri)
    X0 = pts[:, 0]
    t_origin = g.t0_m / g.bin_m - g.pad
    spot_weight = side.intensity / side.r_sx ** 2  # [G, n]
    for e0, e1 in chunk_starts(g, len(tri)):
        ch = Chunk(scene, g, tri, idx, hidden_ptrs, pts, area, nrm, e0, e1)
        base = ch.geo * ch.f_p  # photons per pulse before the element's BSDF and the spot leg
        for si_idx, gout, sl in ch.jobs(confocal, len(spot_ids)):
            if sl.stop <= sl.start:
                continue
            sub = ch.si_x_of(confocal, sl)
            f_sub = np.asarray(bsdf_value(sub, ch.to_spot(X0, side.S[si_idx], sl)), dtype=np.float64)
            if confocal:
                f_x = np.zeros(len(ch.ee))
                f_x[sl] = f_sub
            else:
                f_x = f_sub
            spread_spot(out["hist"][gout], out["bound"][gout], out["steady"][gout], out["vis_err"][gout],
                        out["outside"][gout], ch.job_pixel_start(confocal, si_idx, sl), ch.pe, base,
                        *ch.spread_args(), f_x, np.ascontiguousarray(side.vis[si_idx]), spot_weight[si_idx],
                        np.ascontiguousarray(side.r_sv[si_idx]), side.r_sx[si_idx],
                        g.fl * float(side.laser_leg[si_idx]), g.bin_m, t_origin)
            out["pairs"] += sl.stop - sl.start
        del ch
    return out
