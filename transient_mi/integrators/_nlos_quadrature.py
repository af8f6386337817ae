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
  element's centroid (its own surface interaction there, even where an occluder hides it from the cell; a
  Lambertian BSDF evaluated once per (element, spot) and per wall cell, :mod:`~._nlos_surfaces`) and the
  cell's centre, times both areas; across the cell the weight is taken linear (its
  geometric factors, sensor weight, the wall's cosine and ``cos(theta_X) / r^2``, differenced over the cell's
  edge midpoints), and that tilt moves light between the pair's bins exactly (it leaves the pair's total
  unchanged): the light arriving late in a cell is not weighted as the light arriving early. Across the element
  the weight is taken linear in arrival time (``element_slope``, default true): its slope is the regression of the
  weight at the element's three vertices (both ``1 / r^2`` legs, the wall's cosines at the spot and the cell and
  the element's; beam profile, BSDF albedos and the sensor weight held) on their arrival knots, exact for a weight
  and a path length linear over the triangle, clamped so that the weight stays >= 0
  (:func:`~._nlos_element_slope.slope_of`); it too moves light within the pair only.
* **Arrival times: exact for the linearised path length.** Across a pair the optical path length is
  linear to second order; the pair's arrival-time distribution is the triangular distribution of the
  element's three vertex values convolved with the cell's two uniform components, integrated exactly over
  every bin (:mod:`transient_mi.integrators._nlos_time_spread`), not deposited at the centre. The leading
  second-order term (the path length is convex) is removed from the mean: the knots are shifted by 3/4 of
  the centroid's deviation from the vertex mean (exact for a quadratic over a triangle) and by 1/3 of the
  cell's corner-mean deviation from its centre (exact for a quadratic over a square). Along each edge of the cell
  the curvature ``a`` (from the edge midpoints) also shapes the spread to first order in ``a / s`` (``s`` the
  width): the uniform component is centred ``a / 8`` late, not ``a / 24``, with a density falling as
  ``1 - (a / |s|) v`` across it (the same mean; the slope joins the cell's tilt), faded out as ``|a|`` nears
  ``|s|`` (:func:`~._nlos_cell_curvature.cell_curvature`).
* **Visibility.** ``V(p, X)`` and ``V(X, S)`` are tested by ray casts at the centroid and at three points
  near the element's corners (each leg from the cell centre and from the spot; a sample is visible when no
  surface lies before ``1 - 1e-4`` of its distance: :func:`~._nlos_surfaces.visibility_masks`; from a cell
  only for pairs that can carry light, ``lit`` of :func:`~._nlos_pair_kernels.pair_geometry`). Elements with a
  pair (cell, spot) that can carry light and sees their samples partly (tested from the coarse level's cell centres:
  :func:`~._nlos_refinement.mixed_lit`) are split in four, up to ``refine_levels`` times. A split element stays
  in the level: each of its pairs (cell, spot) is integrated by it where the test's cell and the spot see all its
  samples or none, and by its four children where they see them partly
  (:class:`~._nlos_refinement.Refinement`), so the pairs that did not ask for the split cost one pair, not four. A
  pair still mixed then contributes the visible share of its samples (centroid 1/2, corners 1/6 each).
  Visibility is assumed constant over an element whose samples agree (an occluder smaller than an element
  can be missed: keep ``element_size_m`` below the smallest feature).

Error (stored like the Monte Carlo variance, ``kind: "error_bound"``), per bin, the sum of

1. **mixed visibility** (a bound): the whole unoccluded light of every pair whose samples disagree, times
   ``max(share, 1 - share)``, spread like its light;
2. **discretisation** (an a-posteriori estimate, :mod:`~._nlos_error_estimate`): the difference between the result
   and a coarse level with each element's parent (twice the size) and half the cells per side, ``I_h - I_2h``,
   as its root mean square over ``ESTIMATE_REACH_BINS`` bins either side (the difference crosses zero where the
   error need not; a local mean of squares keeps each pixel's sum of squares), divided by ``ESTIMATE_DIVISOR``:
   both levels converge at least at second order (midpoint rule for the weight, second-order path length; the
   element's slope lowers the error's constant, not its order: on the letter's self-convergence capture the
   actual error fell at order 1.9-2.4 with it as without it, a scratch study of 2026-12-07), so
   ``I_2h - I_h`` is about ``2^2 - 1 = 3`` times the fine level's error (Richardson).
   Pixel totals keep the whole difference. An estimate, not a guarantee: tested by self-convergence on the letter
   and the tilted plane (against a much finer level it covers pixel totals, each pixel's and each lit time
   window's squares).
3. **the cells' part with one cell per patch side** (an a-posteriori estimate): the coarse level cannot halve one
   cell, so its difference holds the elements' part only; the coarse elements are integrated once more with
   :data:`CELL_ESTIMATE_CELLS` cells per side, and ``local_rms(I_1 - I_2) * CELL_ESTIMATE_FACTOR`` (the same
   root mean square over ``ESTIMATE_REACH_BINS`` bins; halving the cells removes 3/4 of the one cell's error at
   second order) is added (:func:`cell_estimate_level`).

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

import mitsuba as mi
import numpy as np

from transient_core.units import C_M_PER_PS
from transient_mi.integrators._nlos_elements import (fine_provenance, mesh_triangles, provenance, split4, subdivide,
                                                     subdivide_provenance)
from transient_mi.integrators._nlos_error_estimate import discretisation_error, local_rms
from transient_mi.integrators._nlos_pair_kernels import cell_terms, pair_results
from transient_mi.integrators._nlos_pairs import Chunk, LevelElements, SpotSide, chunk_starts, side_blocks
from transient_mi.integrators._nlos_refinement import Refinement, cell_spots, refine_visibility, refinement_cells_of
from transient_mi.integrators._nlos_surfaces import WallCells
from transient_mi.integrators._nlos_rounding import finish_rows
from transient_mi.integrators._work_arrays import work_zeros
from transient_mi.props import PluginParameterError
from transient_mi.time_axis import apply_kernel

#: With one cell per patch side, the cells' part of the error is estimated on the coarse elements from one cell
#: against this many per side (the coarse level cannot halve one cell).
CELL_ESTIMATE_CELLS = 2
#: A level's error over its difference with the level of cells half as large, for a second-order method:
#: ``2^2 / (2^2 - 1)`` (``I_c - I_c/2 = (1 - 1/4) (I_c - I)``).
CELL_ESTIMATE_FACTOR = 4.0 / 3.0
#: The bins of the levels that only feed the error estimate (coarse, cells): float32 halves their memory (the
#: paper scene's 32 x 32 capture at 1 ps bins: 377 MB less). Their rounding, about 1e-7 of a bin per deposit, moved
#: the error estimate of the paper scene's 8 x 8 capture at 4 ps by at most 1.1e-5 of its largest bin (the capture
#: itself by nothing). Their totals (``steady``) stay float64.
ESTIMATE_DTYPE = np.float32
#: The error's parts (``error_parts``: they only plan a refinement) are returned in float32: a fifth of the float64
#: parts' memory, which also made the error a new array (the paper scene's 32 x 32 capture at 1 ps bins: 1.1 GB).
PARTS_DTYPE = np.float32
#: Default longest element edge, m.
DEFAULT_ELEMENT_SIZE_M = 0.01
#: Default cells per patch side.
DEFAULT_PATCH_CELLS = 4
#: Default visibility refinement levels.
DEFAULT_REFINE_LEVELS = 1


def error_estimate(options: dict) -> bool:
    """Whether a render integrates the levels of the error estimate (the default). ``options["error_estimate"] =
    False`` (set by the fit, :mod:`transient_mi.fit.capture_model`, not a scene parameter) integrates the fine level
    only, its elements split directly to ``element_size_m`` (not the coarse level's split in four): the result's
    error then holds the mixed visibility's bound only, without the discretisation estimate."""
    return bool(options.get("error_estimate", True))


def error_parts(options: dict) -> bool:
    """Whether a render returns its error's parts beside their sum (``options["error_parts"] = True``, set by
    ``render --noise-target``'s refinement, :func:`transient_mi.noise_target_quadrature.render_group_quadrature`, not a scene
    parameter): ``TransientResult.error_parts`` then maps ``visibility`` (the mixed-visibility bound),
    ``elements`` (the elements' discretisation estimate, with its cells' where the coarse level halves them) and,
    with one cell per patch side, ``cells`` to :data:`PARTS_DTYPE` arrays shaped as ``error_bound``, which is their
    sum (up to float32 rounding and the rounding residue it clears)."""
    return bool(options.get("error_parts", False))


def pair_refinement(options: dict) -> bool:
    """Whether the visibility refinement gives each pair (cell, spot) of a split element to the element or to its
    children as that pair's own visibility asks (the default, :class:`~._nlos_refinement.Refinement`), or every pair
    to the children (``options["pair_refinement"] = False``, set by the fit, :mod:`transient_mi.fit.capture_model`,
    not a scene parameter). Shared pairs cost less (on the paper scene's 32 x 32 capture the fine level's bin edges
    fell from 3.7e9 to 2.8e9, a scratch count) and leave the pairs that see an element wholly or not at all with the
    element itself. The fit keeps the children in every pair: its elements are coarse (6 cm by default), its records
    and tests were measured with the children's finer time spread in every pair of a split element, and a fit with
    shared pairs is not yet measured."""
    return bool(options.get("pair_refinement", True))


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


# ------------------------------------------------------------------ geometry and elements


class _Geometry:
    """The capture's fixed geometry in numpy float64 (world frame, metres)."""

    def __init__(self, setup, film, cells: int, element_slope: bool = True):
        self._setup, self._film = setup, film
        self.element_slope = bool(element_slope)  # (pairs weight their element linearly in time: _nlos_pair_kernels)
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
        self.cell_terms = cell_terms(self.cell_p, D, self.cell_ax, self.cell_ay, self.fl, self.ap_n, self.normal)

    def with_cells(self, cells: int) -> "_Geometry":
        """The same capture with ``cells`` cells per patch side."""
        return _Geometry(self._setup, self._film, cells, self.element_slope)


# ------------------------------------------------------------------ the render


def patch_cells(setup, options: dict) -> int:
    """Cells per patch side of the fine level (one with ``pixel_sampling="center"``)."""
    return 1 if setup.pixel_sampling == "center" else int(options.get("patch_cells", DEFAULT_PATCH_CELLS))


def cell_estimate_level(g: _Geometry) -> _Geometry | None:
    """The cells of the level that estimates the cells' part of the error where the fine level has one cell per
    patch side (:data:`CELL_ESTIMATE_CELLS` per side, integrated with the coarse elements), or ``None``: with
    several cells the coarse level halves them and its difference holds both parts; a point patch
    (``pixel_sampling="center"``) has no cell error."""
    return g.with_cells(CELL_ESTIMATE_CELLS) if g.m == 1 and g.cell_half_diag > 0 else None


def level_elements(scene, setup, g: _Geometry, options: dict, spot_ids, hidden_ptrs, with_provenance=False):
    """The elements of both levels: ``(coarse, fine, refine_levels_used[, fine provenance])``,
    :class:`~._nlos_pairs.LevelElements` (coarse: edges of at most twice ``element_size_m``; fine: each coarse
    one split in four, then refined where visibility is mixed; the provenance: :func:`~._nlos_elements.provenance`).

    A render keeps each split element beside its children and gives every pair to one of them
    (:class:`~._nlos_refinement.Refinement`); without :func:`pair_refinement` (the fit's forward model) the split
    elements leave and their children take every pair."""
    h = float(options.get("element_size_m", DEFAULT_ELEMENT_SIZE_M))
    faces = mesh_triangles(setup.hidden_shapes)
    if error_estimate(options):
        tri_c, src_c = subdivide(faces.tri, np.arange(len(faces.tri)), 2.0 * h)
        tri_f, src_f = split4(tri_c), np.repeat(src_c, 4)
        prov = fine_provenance(faces.tri, 2.0 * h) if with_provenance else None
    else:  # (no coarse level: the fine elements directly)
        tri_c = src_c = None
        tri_f, src_f = subdivide(faces.tri, np.arange(len(faces.tri)), h)
        prov = subdivide_provenance(faces.tri, provenance(len(faces.tri)), h) if with_provenance else None
    # split as the coarse level's cells see it (a quarter of the rays); still-mixed fine pairs are bounded. The
    # test's masks serve the fine level (from its own cells too with one cell per side: the same rays)
    m_test = max(1, g.m // 2)
    confocal = setup.capture == "confocal"
    tri_f, src_f, levels, prov, traced, split = refine_visibility(
        scene, setup, g if m_test == g.m else g.with_cells(m_test), spot_ids, tri_f, src_f,
        int(options.get("refine_levels", DEFAULT_REFINE_LEVELS)), prov, keep_cells=m_test == g.m, faces=faces,
        hidden_ptrs=hidden_ptrs, confocal=confocal, owned_only=pair_refinement(options))
    refinement = None
    if split is not None and pair_refinement(options):
        refinement = Refinement(*split, refinement_cells_of(g, m_test), cell_spots(g, confocal))
    elif split is not None:  # (the fit's forward model: the split elements leave, their children take every pair)
        keep = split[1] < 0
        tri_f, src_f = tri_f[keep], src_f[keep]
        prov = None if prov is None else prov[keep]
        traced = traced.kept(keep[:traced.n])
    out = (None if tri_c is None else LevelElements(setup, faces, hidden_ptrs, tri_c, src_c),
           LevelElements(setup, faces, hidden_ptrs, tri_f, src_f, traced, refinement), levels)
    return out + ((prov,) if with_provenance else ())


def render_spots_quadrature(setup, scene, film, options: dict, spots: list[int], progress=None):
    """Render the three-bounce light of a group of spots by quadrature (see the module docstring).

    Two levels are integrated: the *fine* one (elements of at most ``element_size_m``, ``patch_cells``
    cells per patch side, visibility refinement) is the result; the *coarse* one (each fine element's
    parent, of twice the size, and half the cells per side, at least one) serves the error estimate. With one
    cell per side a third, the coarse elements with :data:`CELL_ESTIMATE_CELLS` cells per side
    (:func:`cell_estimate_level`), estimates the cells' part, which the coarse level (one cell too) cannot see.

    ``progress(done, total)``, optional: called after every chunk of pairs, ``done / total`` the share of the
    pairs integrated (both levels; ``total`` fixed for the call).

    Returns one :class:`~transient_mi.films.transient_film.TransientResult` per spot with ``error_bound``
    and ``total_error_bound`` set and no variance.
    """
    from transient_mi.films.transient_film import TransientResult

    m = patch_cells(setup, options)
    g = _Geometry(setup, film, m, options.get("element_slope", True))
    confocal = setup.capture == "confocal"
    P = g.W * g.H
    max_depth = options.get("max_depth", 4)
    spot_ids = list(range(setup.n_spots)) if confocal else list(spots)
    G_out = 1 if confocal else len(spots)
    fine = coarse = cells = None
    info = {"elements": 0, "coarse_elements": 0, "refine_levels": 0, "pairs": 0, "patch_cells": m}
    if setup.hidden_shapes and (max_depth >= 4 or max_depth == -1):
        hidden_ptrs = mi.ShapePtr(setup.hidden_shapes)
        lv_c, lv_f, levels = level_elements(scene, setup, g, options, spot_ids, hidden_ptrs)
        m_c = max(1, g.m // 2)
        g_c = g if m_c == g.m else g.with_cells(m_c)  # (one cell per side: the same cells, their wall once)
        g_cc = cell_estimate_level(g) if lv_c is not None else None
        n_f = len(g.cell_p) * lv_f.n  # pairs of each level
        n_c = 0 if lv_c is None else len(g_c.cell_p) * lv_c.n
        n_cc = 0 if g_cc is None else len(g_cc.cell_p) * lv_c.n
        tick_f = tick_c = tick_cc = None
        if progress is not None:
            def tick_f(done):
                progress(done, n_f + n_c + n_cc)

            def tick_c(done):
                progress(n_f + done, n_f + n_c + n_cc)

            def tick_cc(done):
                progress(n_f + n_c + done, n_f + n_c + n_cc)
        wall = WallCells(scene, setup, g.cell_p, g.D)
        fine = _level(scene, setup, g, lv_f, spot_ids, confocal, G_out, tick_f, wall=wall, name="fine")
        # (the estimate's levels keep no per-bin light of mixed visibility, and their bins in ESTIMATE_DTYPE)
        if lv_c is not None:
            coarse = _level(scene, setup, g_c, lv_c, spot_ids, confocal, G_out, tick_c, with_bound=False,
                            wall=wall if g_c is g else None, dtype=ESTIMATE_DTYPE, name="coarse")
        if g_cc is not None:
            cells = _level(scene, setup, g_cc, lv_c, spot_ids, confocal, G_out, tick_cc, with_bound=False,
                           dtype=ESTIMATE_DTYPE, name="cells")
        info.update(elements=lv_f.n, coarse_elements=0 if lv_c is None else lv_c.n, refine_levels=levels,
                    pairs=fine["pairs"] + (0 if coarse is None else coarse["pairs"])
                    + (0 if cells is None else cells["pairs"]))
    if fine is None:  # no three-bounce light (no hidden shapes, or max_depth below 4): an empty level
        zeros = np.zeros((G_out, P, g.n_ext))
        fine = {"hist": zeros, "bound": zeros.copy(), "steady": np.zeros((G_out, P)), "vis_err": np.zeros((G_out, P)),
                "outside": np.zeros((G_out, P)), "pairs": 0}
    hist = fine["hist"]
    steady = fine["steady"]
    outside = fine["outside"]
    # error: the light of mixed visibility, plus the discretisation estimated from the coarse level
    bound = fine["bound"]
    parts = {"visibility": bound.astype(PARTS_DTYPE)} if error_parts(options) else None

    def part(name):  # (where an estimate is written beside its sum, when the parts are asked for)
        if parts is None:
            return None
        parts[name] = np.empty(bound.shape, dtype=PARTS_DTYPE)
        return parts[name]

    tot_bound = fine["vis_err"] + (np.abs(fine["steady"] - coarse["steady"]) if coarse is not None else 0.0)
    if cells is not None:
        tot_bound = tot_bound + np.abs(coarse["steady"] - cells["steady"]) * CELL_ESTIMATE_FACTOR
    p_elements = part("elements") if coarse is not None else None
    p_cells = part("cells") if cells is not None else None
    wr = setup.wall_return
    results = []
    for gi in range(G_out):
        # spot by spot, each while its rows are in the cache: the error estimates (added to the bound in place: no
        # float64 array of the capture's size per part), the wall's return, the rounding residue and the float32
        # copies (each row as for the whole group at once: the same bytes)
        if coarse is not None:
            discretisation_error(hist[gi], coarse["hist"][gi], add_to=bound[gi],
                                 part=None if p_elements is None else p_elements[gi])
        if cells is not None:
            # one cell per side: the coarse level's difference is the elements' part; the cells' part is the coarse
            # elements' one cell against CELL_ESTIMATE_CELLS (same local root mean square), scaled to the one cell's
            # own error
            local_rms(coarse["hist"][gi], cells["hist"][gi], CELL_ESTIMATE_FACTOR, add_to=bound[gi],
                      part=None if p_cells is None else p_cells[gi])
        # closed-form first-bounce return of the wall (as the Monte Carlo estimator; no error)
        for j in (spot_ids if confocal else [spots[gi]]):
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
        # (each spot's own float32 arrays, not views of one for the group: arrays of a spot's size are reused by the
        # C heap once freed, a group's are mapped afresh, and faulting their pages in cost more than the pass)
        hk, ek = ((np.array(apply_kernel(a[gi], g.taps), dtype=np.float64) for a in (hist, bound)) if g.pad
                  else (hist[gi], bound[gi]))  # (the level's own rows are cleared in place: they are not read again)
        h32, e32 = finish_rows(hk, ek)
        # (the parts as they are, views where the film has no kernel: they only plan a refinement)
        ep = None if parts is None else {
            name: (apply_kernel(a[gi], g.taps).astype(PARTS_DTYPE) if g.pad else a[gi]).reshape(g.H, g.W, g.n_bins)
            for name, a in parts.items()}
        in_hist = float(hk.sum())
        tot = float(steady[gi].sum())
        frac = max(0.0, 1.0 - in_hist / tot) if tot > 0 else 0.0
        results.append(TransientResult(
            histogram=h32.reshape(g.H, g.W, g.n_bins),
            steady=steady[gi].astype(np.float32).reshape(g.H, g.W),
            dropped_contributions=int((outside[gi] > 1e-12 * max(tot, 1e-300)).sum()),
            dropped_fraction=frac,
            samples=info["pairs"],
            variance=None,
            total_variance=None,
            replicates=1,
            error_bound=e32.reshape(g.H, g.W, g.n_bins),
            total_error_bound=tot_bound[gi].astype(np.float32).reshape(g.H, g.W),
            estimator_info=dict(info),
            error_parts=ep,
        ))
    return results


def _level(scene, setup, g: _Geometry, lv: LevelElements, spot_ids, confocal, G_out, tick=None,
           with_bound: bool = True, wall: WallCells | None = None, dtype=np.float64, name: str = "level") -> dict:
    """Integrate one level (elements ``lv``, the cells of ``g``) for every spot of the group (``tick(pairs done)``
    after every chunk, optional; ``wall``: the :class:`~._nlos_surfaces.WallCells` of ``g``'s cells, when another
    level has them already; ``name``: its bins' and bound's names among the :mod:`~._work_arrays`).

    Returns ``hist`` (of ``dtype``), ``bound`` (light of mixed visibility, per bin; no bins without ``with_bound``)
    ``[G, P, n_ext]``, ``steady``, ``vis_err``, ``outside`` ``[G, P]`` and ``pairs`` (pairs times the spots each
    was deposited for).
    """
    P = g.W * g.H
    out = {"hist": work_zeros(f"{name}.hist", (G_out, P, g.n_ext), dtype),
           "bound": work_zeros(f"{name}.bound", (G_out, P, g.n_ext if with_bound else 0)),
           "steady": np.zeros((G_out, P)), "vis_err": np.zeros((G_out, P)), "outside": np.zeros((G_out, P)),
           "pairs": 0}
    wall = WallCells(scene, setup, g.cell_p, g.D) if wall is None else wall
    starts = chunk_starts(len(g.cell_p), lv.n)
    # (one set of pair arrays for every chunk: each chunk is gone before the next is made)
    buffers = pair_results(len(g.cell_p) * max((e1 - e0 for e0, e1 in starts), default=0))
    # (the laser side of a block of elements at a time: a confocal capture's are every element with every pixel)
    for b0, b1, chunks in side_blocks(starts, len(spot_ids)):
        side = SpotSide(scene, setup, g, spot_ids, lv, b0, b1)
        for e0, e1 in chunks:
            ch = Chunk(scene, g, lv, wall, e0, e1, side, confocal, buffers)
            ch.spread(out, lv, side, confocal, ch.fx_pairs(g, lv, side, confocal))
            out["pairs"] += ch.n * (1 if confocal else len(spot_ids))
            del ch
            if tick is not None:
                tick(len(g.cell_p) * e1)
        del side
    return out
