"""The pairs (element, cell) of one level of the deterministic NLOS estimator
(:mod:`transient_mi.integrators._nlos_quadrature`), shared by the primal and its derivatives
(:mod:`transient_mi.integrators._nlos_quadrature_ad`).

* :class:`LevelElements`: a level's elements (hidden side) and their surfaces;
* :class:`SpotSide`: per element and laser spot, everything of the laser side (visibility, intensity, BSDF
  towards the spot, laser parts of the arrival knots);
* :class:`Chunk`: the detector side of the pairs of every cell with a range of elements
  (:func:`~._nlos_pair_kernels.pair_geometry`, visibility from the cells, the wall's BSDF), and their
  deposit for every spot of a group in one call (:func:`~._nlos_pair_kernels.spread_group`).

World frame, metres, float64 unless stated; the kernels' layout is in :mod:`~._nlos_pair_kernels`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from transient_mi.integrators._nlos_element_slope import laser_amplitudes
from transient_mi.integrators._nlos_elements import sample_points
from transient_mi.integrators._nlos_pair_kernels import pair_geometry, spot_knots, spread_group
from transient_mi.integrators._nlos_surfaces import ElementSurfaces, WallCells, spot_intensities, visibility_masks

if TYPE_CHECKING:
    import mitsuba as mi

#: Pairs (element, cell) per chunk (what one chunk's per-pair arrays hold).
PAIRS_PER_CHUNK = 1 << 20


def element_terms(tri: np.ndarray):
    """``(pts [n, 4, 3] visibility samples (centroid first), area [n], unit normal [n, 3])`` of elements."""
    pts = sample_points(tri)
    nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(nrm, axis=1)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    return pts, area, nrm


def chunk_starts(n_cells: int, n: int):
    """``(e0, e1)`` element ranges of the chunks (``PAIRS_PER_CHUNK`` pairs each at most)."""
    per = max(1, PAIRS_PER_CHUNK // max(n_cells, 1))
    return [(e0, min(n, e0 + per)) for e0 in range(0, n, per)]


def spot_masks(scene, setup, spots, pts: np.ndarray) -> np.ndarray:
    """Visibility masks of every element's four samples from the laser spots ``spots``: ``uint8 [n, G]``
    (:func:`~._nlos_surfaces.visibility_masks`, element-major)."""
    S = np.asarray(setup.spots, dtype=np.float64)[list(spots)]
    return visibility_masks(scene, S, setup.frame.normal, pts, 0, len(pts), element_major=True).reshape(len(pts),
                                                                                                       len(S))


class TracedVisibility:
    """Visibility masks already traced for the first ``n`` elements of a level (by the refinement test,
    :func:`~._nlos_refinement.refine_visibility`): from the laser spots ``spots`` (``spot``, ``uint8 [n, G]``, as
    :func:`spot_masks`) and, where that test used the level's own cells, from the cells ``cell_p`` (``cell``,
    ``uint8 [C, n]``, as :func:`~._nlos_surfaces.visibility_masks`; ``None`` otherwise). :class:`SpotSide` and
    :class:`Chunk` take them instead of tracing the same rays again (each ray's result does not depend on the
    launch it is traced in: same bytes)."""

    def __init__(self, spots, spot: np.ndarray, cell_p: np.ndarray | None = None, cell: np.ndarray | None = None):
        self.spots = list(spots)
        self.spot, self.cell_p, self.cell = spot, cell_p, cell
        self.n = len(spot)

    def kept(self, keep: np.ndarray) -> "TracedVisibility":
        """The masks of the elements ``keep`` (bool ``[n]``), in order."""
        return TracedVisibility(self.spots, self.spot[keep], self.cell_p,
                                None if self.cell is None else np.ascontiguousarray(self.cell[:, keep]))

    def then(self, more: "TracedVisibility") -> "TracedVisibility":
        """These elements' masks followed by ``more``'s (traced from the same spots and cells)."""
        cell = None if self.cell is None or more.cell is None else np.concatenate([self.cell, more.cell], axis=1)
        return TracedVisibility(self.spots, np.concatenate([self.spot, more.spot]), self.cell_p, cell)


class LevelElements:
    """A level's elements: vertices ``tri [n, 3, 3]``, source triangles ``src`` (rows of the
    :class:`~._nlos_elements.Faces`), visibility samples, areas, normals and the surfaces at the centroids
    (:class:`~._nlos_surfaces.ElementSurfaces`); ``traced``, optional: the :class:`TracedVisibility` of its first
    elements; ``refinement``, optional: the :class:`~._nlos_refinement.Refinement` that shares the pairs between
    split elements and their children."""

    def __init__(self, setup, faces, hidden_ptrs, tri: np.ndarray, src: np.ndarray,
                 traced: TracedVisibility | None = None, refinement=None):
        self.n = len(tri)
        self.tri, self.src = tri, src
        self.pts, self.area, self.nrm = element_terms(tri)
        self.X0 = self.pts[:, 0]
        self.surf = ElementSurfaces(setup.hidden_shapes, hidden_ptrs, faces, tri, src)
        self.traced = traced
        self.refinement = refinement

    def spot_vis(self, scene, setup, spots, e0: int = 0, e1: int | None = None) -> np.ndarray:
        """:func:`spot_masks` of the elements ``e0:e1`` (default: every one) from the spots ``spots``, ``uint8 [k,
        G]`` (the traced ones taken, the others traced)."""
        e1 = self.n if e1 is None else e1
        t = self.traced
        if t is None or t.spots != list(spots):
            return spot_masks(scene, setup, spots, self.pts[e0:e1])
        if t.n >= e1:
            return t.spot[e0:e1]
        known = t.spot[e0:max(e0, t.n)]
        rest = spot_masks(scene, setup, spots, self.pts[max(e0, t.n):e1])
        return rest if len(known) == 0 else np.concatenate([known, rest])

    def traced_cells(self, cell_p: np.ndarray, e0: int, e1: int) -> np.ndarray | None:
        """The traced masks of the elements ``e0:e1`` from the cells ``cell_p``, ``uint8 [C, k]`` for the first ``k``
        of them (``k`` may be 0), or ``None`` when no masks were traced from these cells."""
        t = self.traced
        if t is None or t.cell is None or not np.array_equal(t.cell_p, cell_p):
            return None
        return t.cell[:, e0:max(e0, min(e1, t.n))]


#: (element, spot) combinations of one :class:`SpotSide` in a level's integration (:func:`side_blocks`): its
#: arrays take about 110 bytes a combination (about 0.2 GB here; the laser amplitudes, vectorised in numpy when
#: this bound was set, took about as much again in temporaries and now take none). A confocal capture pairs every element with every pixel's spot: the 64 x 64 letter's reference
#: render at 1 cm peaked at 5.4 GB with the whole level's at once, 1.2 GB a block at a time
#: (``bench/results/nlos_quadrature_confocal64_before_blocks.json`` and ``_blocks.json``).
SIDE_COMBINATIONS = 1 << 21


def side_blocks(starts: list, n_spots: int) -> list:
    """The chunks ``starts`` (``(e0, e1)`` element ranges, in order) grouped into blocks of consecutive chunks, each
    with at most :data:`SIDE_COMBINATIONS` (element, spot) combinations for ``n_spots`` spots (one chunk at
    least): ``[(b0, b1, chunks)]``. A level builds one :class:`SpotSide` per block; an array capture's few spots
    fit a level of half a million elements in one block, a confocal capture's pixels a few hundred elements."""
    per = max(1, SIDE_COMBINATIONS // max(n_spots, 1))
    blocks = []
    for e0, e1 in starts:
        if blocks and e1 - blocks[-1][0] <= per:
            b0, _, chunks = blocks[-1]
            chunks.append((e0, e1))
            blocks[-1] = (b0, e1, chunks)
        else:
            blocks.append((e0, e1, [(e0, e1)]))
    return blocks


class SpotSide:
    """Per element ``e0:e1`` of a level (default: every one) and spot of the group ``spots`` (element-major ``[k,
    G]``, row 0 the element ``e0``): visibility ``vis [k, G]`` (uint8 masks of the samples seen from the spot,
    :func:`~._nlos_surfaces.visibility_masks`), the spot's intensity ``intensity`` (``f_S cos`` towards the
    centroid), ``r_sv [k, G, 3]`` and ``r_sx`` (m), ``sw`` = intensity / r_sx^2, the knots' laser parts ``B [k, G,
    3]`` (bins); for Lambertian elements ``fx_e`` and ``side_s`` (:meth:`~._nlos_surfaces.ElementSurfaces.toward`),
    zeros otherwise."""

    def __init__(self, scene, setup, g, spots, lv: LevelElements, e0: int = 0, e1: int | None = None):
        self.spots = list(spots)
        self.S = np.asarray(setup.spots, dtype=np.float64)[self.spots]  # [G, 3]
        self.e0, self.e1 = e0, lv.n if e1 is None else e1
        G, n = len(self.S), self.e1 - self.e0
        rows = slice(self.e0, self.e1)
        self.Lo = np.asarray(setup.laser_origin, dtype=np.float64)
        beam = np.asarray(setup.spot_targets, dtype=np.float64)[self.spots] - self.Lo
        self.beam = beam / np.linalg.norm(beam, axis=1, keepdims=True)
        self.laser_leg = np.linalg.norm(self.S - self.Lo, axis=1)  # [G]
        self.vis = lv.spot_vis(scene, setup, self.spots, self.e0, self.e1)
        self.intensity = np.asarray(self.intensity_ad(scene, lv.X0[rows]), dtype=np.float64).reshape(n, G)
        self.B, self.r_sv, self.r_sx = spot_knots(lv.tri[rows], lv.X0[rows], self.S, g.fl * self.laser_leg, g.bin_m,
                                                  g.t0_m / g.bin_m - g.pad)
        self.sw = np.ascontiguousarray(self.intensity / self.r_sx ** 2)
        # (empty without the element's slope: the kernels then give every pair the midpoint weight of before)
        self.amp_s = (laser_amplitudes(lv.tri[rows], lv.X0[rows], lv.nrm[rows], self.S,
                                       np.asarray(setup.frame.normal, dtype=np.float64))
                      if g.element_slope else np.empty((0, 0, 3)))
        if lv.surf.lambertian:
            self.fx_e, self.side_s = lv.surf.toward(self.S, self.e0, self.e1)
        else:
            self.fx_e, self.side_s = np.zeros((n, G)), np.zeros((n, G), dtype=np.int8)

    def intensity_ad(self, scene, X0: np.ndarray) -> "mi.Float":
        """The spots' intensities towards every centroid ``X0``, element-major ``[n * G]`` (the laser ray to each
        spot, ``wi`` towards the laser; attached inside ``dr.resume_grad``)."""
        return spot_intensities(scene, self.Lo, self.beam, self.S, X0)


class Chunk:
    """The detector side of the pairs of every cell with the elements ``e0:e1`` (cell-major: pair ``i`` is cell
    ``i // ne``, element ``e0 + i % ne``): :func:`~._nlos_pair_kernels.pair_geometry`'s arrays, the wall's BSDF
    ``f_p`` (per cell times ``cos_p`` for a Lambertian wall, per pair otherwise) and the visibility of the element's
    samples from the cell ``vis_p [n]`` (masks), tested for the pairs that can carry light for a spot of ``side``
    (``lit`` of :func:`~._nlos_pair_kernels.pair_geometry`; 0 for the others, which the kernels then skip as they
    skip any pair without light). ``out``, optional: :func:`~._nlos_pair_kernels.pair_results` the geometry is
    written to (views of it become the chunk's arrays: a chunk using them must be gone before the next one is
    made)."""

    def __init__(self, scene, g, lv: LevelElements, wall: WallCells, e0: int, e1: int, side: SpotSide,
                 confocal: bool, out: tuple | None = None):
        C = len(g.cell_p)
        self.e0, self.e1, self.ne = e0, e1, e1 - e0
        # (the kernels index the level's arrays and the side's alike: from the side's first element, ``k0`` the
        # chunk's first there)
        if not side.e0 <= e0 <= e1 <= side.e1:
            raise ValueError(f"chunk elements {e0}:{e1} outside the spot side's {side.e0}:{side.e1}")
        self.k0 = e0 - side.e0
        rows = slice(side.e0, side.e1)
        self.n = C * self.ne
        self.per_pixel = g.m * g.m * self.ne
        # (each pair once: with a split element or with its children)
        owned = None if lv.refinement is None else lv.refinement.owned(C, e0, self.ne)
        (self.geo, self.cos_p, self.A, self.w1, self.w2, self.tilt, self.side_x,
         lit, self.amp) = pair_geometry(g.cell_p, g.cell_w0, *g.cell_terms, lv.X0[rows], lv.tri[rows], lv.nrm[rows],
                              lv.area[rows], lv.surf.n_sh[rows], wall.n_sh, wall.side, self.k0, self.k0 + self.ne,
                              g.cell_ax, g.cell_ay, g.fl, g.bin_m, g.N,
                              g.cell_half_diag > 0, g.normal, self.per_pixel, side.vis, side.side_s, wall.lambertian,
                              lv.surf.lambertian, confocal, out, g.element_slope, owned)
        if wall.lambertian:
            self.f_p = (wall.value[:, None] * self.cos_p.reshape(C, self.ne)).reshape(-1)
        else:
            self.f_p = np.asarray(wall.pair_values(g.cell_p, lv.X0, e0, e1), dtype=np.float64)
        known = lv.traced_cells(g.cell_p, e0, e1)  # [C, k]: the first k elements' masks, traced already
        k = 0 if known is None else known.shape[1]
        if k == self.ne:
            self.vis_p = known.reshape(-1) * lit
        elif k == 0 and lit.all():
            self.vis_p = visibility_masks(scene, g.cell_p, g.normal, lv.pts, e0, e1)
        else:
            self.vis_p = np.zeros(self.n, dtype=np.uint8)
            todo = lit
            if k:
                self.vis_p.reshape(C, self.ne)[:, :k] = known
                self.vis_p *= lit
                todo = lit & (np.arange(self.n) % self.ne >= k)
            idx = np.flatnonzero(todo)
            self.vis_p[idx] = visibility_masks(scene, g.cell_p, g.normal, lv.pts, e0, e1, idx)

    def spot_of_pair(self) -> np.ndarray:
        """Confocal captures: each pair's spot (its pixel's: spot ``k`` lies on pixel ``k``'s patch)."""
        return np.arange(self.n) // self.per_pixel

    def fx_pairs(self, g, lv: LevelElements, side: SpotSide, confocal: bool) -> np.ndarray:
        """``f_x`` per pair for elements that are not Lambertian, ``[R, n]`` (a row per spot, one row with each
        pair's own spot for confocal captures); a placeholder for Lambertian ones (the kernel uses ``fx_e``)."""
        if lv.surf.lambertian:
            return np.zeros((1, 1))
        spots = [side.S[self.spot_of_pair()]] if confocal else list(side.S)
        return np.stack([np.asarray(v, dtype=np.float64) for v in lv.surf.pair_values(g.cell_p, self.e0, self.e1,
                                                                                       spots)])

    def spread(self, out: dict, lv: LevelElements, side: SpotSide, confocal: bool, fx_pair: np.ndarray) -> None:
        """Deposit the chunk's pairs for every spot of the group into ``out`` (``hist``, ``bound``, ``steady``,
        ``vis_err``, ``outside``: :func:`~._nlos_pair_kernels.spread_group`)."""
        spread_group(out["hist"], out["bound"], out["steady"], out["vis_err"], out["outside"], self.per_pixel,
                     self.k0, self.ne, self.geo, self.f_p, self.vis_p, self.A, self.w1, self.w2, self.tilt,
                     self.side_x, fx_pair, side.vis, side.B, side.sw, side.fx_e, side.side_s, lv.surf.lambertian,
                     confocal, self.amp, side.amp_s)
