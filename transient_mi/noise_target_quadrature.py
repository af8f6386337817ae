"""``render --noise-target`` for the deterministic quadrature (``estimator="quadrature"``): no samples to add, so
each round renders a group of spots afresh with finer settings, planned from the parts of the last round's error
(:func:`plan_quadrature_level`), until the stated rendering-error ratio meets the target. The Monte Carlo side
(pilot, ``1/spp`` plan, replicates and checkpoints) is :mod:`transient_mi.noise_target`, whose
:class:`~transient_mi.noise_target.TargetRun` and ``PLAN_MARGIN`` this module shares."""

from __future__ import annotations

import math
import time

from .noise_target import PLAN_MARGIN, TargetRun

#: Refinements a quadrature render may take to meet its target.
QUADRATURE_MAX_ROUNDS = 4
#: Smallest factor one refinement may shrink the element size by (the cost grows about as its inverse square
#: for the elements and as its square again for the cells).
QUADRATURE_MIN_FACTOR = 0.35
#: Most visibility refinement levels a noise target gives a render (each halves the mixed-visibility bound; the
#: elements it splits are the mixed ones only, so a level costs far less than halving every element).
QUADRATURE_MAX_REFINE_LEVELS = 4
#: One step of :func:`plan_quadrature_level` on the elements: their size shrinks by this factor.
QUADRATURE_ELEMENT_STEP = 0.9
#: The order at which the plan takes the elements' part of the error (a bound, not squared) to fall with their size
#: (:func:`~transient_mi.integrators._nlos_elements.element_scale_m`): the estimate is second order at least; on
#: the demo's 8 x 8 capture at 1 s per spot it fell as the size to the 2.6-3.0 (13.6-24.3 mm against 40 mm,
#: ``bench/results/quadrature_parts_a8_e1000ms.json``), so 2.5 plans a little finer than the measured fall.
ELEMENTS_ORDER = 2.5
#: The order at which the plan takes the cells' part (one cell per side; a share, the square root of its ratio) to
#: fall with the elements' size: it is estimated on the coarse elements (:func:`~transient_mi.integrators.
#: _nlos_quadrature.cell_estimate_level`), and on the demo's 8 x 8 capture at 1 s per spot its ratio fell from
#: 0.0087 to 0.0010 as the elements went from 40 to 13.6 mm at one cell, as the size to the 1.97th power
#: (``bench/results/quadrature_parts_a8_e1000ms.json``): its share as the size to the first.
CELLS_ELEMENTS_ORDER = 1.0


#: Half the largest power of the element size that a whole ratio was seen to grow as when a series' next capture
#: started coarser (:func:`coarser_start`): on the demo at 1 s per spot and the target 0.1 the 32 x 32 array started
#: 1.11 times coarser than the 16 x 16 one's settings (26.0 mm against 23.4 mm, 2026-12-07) gave 0.103 against
#: 0.036, the size to the 9.9th power, and needed a second round (56 s each); the 16 x 16 array's own settings give
#: the 32 x 32 one 0.048, so a part of that growth is the larger array's, not the elements'. Before, 1.12 times
#: gave 0.124 against 0.053 (the size to the 7.5th; 3.75 until 2026-12-07). The elements' part, a bound, falls as the
#: size to 2.6-3.0 within one capture (``bench/results/quadrature_parts_a8_e1000ms.json``).
COARSEN_ORDER = 5.0
#: The most :func:`coarser_start` enlarges the elements by.
MAX_COARSEN = 1.5


def coarser_start(settings: dict, ratio: float, target: float) -> dict:
    """Quadrature settings for the next capture of a series (same scene, exposure and detector: the demo's next
    array) from ``settings`` (``element_size_m``, ``patch_cells``, ``refine_levels``) that met ``target`` with the
    worst ratio ``ratio``: the elements enlarged by ``f = (PLAN_MARGIN target / ratio)^(1 / (2 COARSEN_ORDER))``
    (at most :data:`MAX_COARSEN`; never made smaller), the rest kept.

    A refinement overshoots (the plan steps the elements' size by :data:`QUADRATURE_ELEMENT_STEP` and aims at
    ``PLAN_MARGIN target``), and a series that starts every capture where the last one ended keeps that overshoot:
    on the demo at 1 s per spot the 4 x 4 array's second round gave 0.086 against 0.1, and the 8 x 8 to 32 x 32
    arrays, started there, 0.040-0.042, the 32 x 32 one in 109 s.

    The whole ratio is taken to grow as the size to ``2 COARSEN_ORDER``, the fastest seen between two captures of
    the demo; not the parts of the error by their own orders (:func:`quadrature_part_ratios`, as
    :func:`plan_quadrature_level` refines): grown so from the 16 x 16 array's parts (visibility 0.014, elements
    0.018, cells 0.002: ``f = 1.12``), the 32 x 32 array's start gave 0.124, its elements' part 0.054. The parts do
    not carry over from one array to the next; the next capture's own ratio is measured and refined as any other.
    Empty ``settings`` (a Monte Carlo capture), a ratio that is not positive or one at or above ``PLAN_MARGIN
    target`` return ``settings`` as they are."""
    out = dict(settings)
    if "element_size_m" not in out or not ratio > 0 or ratio >= PLAN_MARGIN * target:
        return out
    f = min(MAX_COARSEN, max(1.0, (PLAN_MARGIN * target / ratio) ** (0.5 / COARSEN_ORDER)))
    out["element_size_m"] = float(out["element_size_m"]) * f
    return out


def quadrature_ratio(run: TargetRun, j: int, result) -> float:
    """The rendering-error ratio of a quadrature result (its error estimate carried like ``detect`` does)."""
    return run.headline(j, result.histogram, result.error_bound, result.total_error_bound, error_bound=True)


#: Threads that state a group's spots' ratios at once (numpy releases the GIL in the detector model's FFTs and array
#: passes; each spot's ratio is computed alone, so the same values whatever the threads).
RATIO_THREADS = 2


def _ratios(run: TargetRun, group: list, results: list) -> list:
    """:func:`quadrature_ratio` of every spot of ``group`` (with its result), in group order, on up to
    :data:`RATIO_THREADS` threads (the paper scene's 32 x 32 capture at 1 ps bins: 1.9 s for its four spots on one)."""
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=min(len(group), RATIO_THREADS)) as pool:
        return list(pool.map(lambda jr: quadrature_ratio(run, *jr), zip(group, results)))


def quadrature_part_ratios(run: TargetRun, j: int, result) -> dict | None:
    """The ratio each part of a quadrature result's error would give alone (``visibility``, ``elements``,
    ``cells``: :func:`transient_mi.integrators._nlos_quadrature.error_parts`), or None without its parts."""
    parts = getattr(result, "error_parts", None)
    if not parts:
        return None
    return {name: run.headline(j, result.histogram, a, error_bound=True) for name, a in parts.items()}


def _even_cells(m: int) -> int:
    """``m`` cells per patch side as the refinement plans them: one, or the even count at or above ``m`` (at most
    64).

    The error estimate's coarse level takes half the cells, ``m // 2``: an odd count is not halved, and its stated
    error is far above its actual one (three cells against one: on the README letter, 16 x 16 at 9 mm and 10 ms, a
    stated ratio of 0.54 for an actual 0.0061; four cells: 0.0138 for 0.0021)."""
    m = int(m)
    return m if m <= 1 else min(64, m + (m % 2))


def _next_quadrature_level(tri, footprint_m: float, h: float, m: int, f: float) -> tuple[float, int]:
    """Shrink the elements' size by ``f`` as their error sees it
    (:func:`~transient_mi.integrators._nlos_elements.element_scale_m`, the area-weighted root mean square of their
    longest edge): ``element_size_m`` is lowered from ``h f`` until that size is ``f`` times what it was (where
    the meshes' triangles are smaller than ``2 h``, a lower ``h`` splits nothing, so ``h f`` alone may change no
    element; where large triangles set the size, ``h f`` is about enough). The cells shrink by ``f`` too where they
    are larger than the elements (that size; cells smaller than the elements are left: on the paper scene's 1 cm^2
    patches two cells per side and four gave the same error, 0.082 and 0.081). With several cells per patch side
    the coarse level halves both, so the elements' estimate holds the cells' part too; this is the step
    :func:`plan_quadrature_level` takes for it (and the whole refinement of a render without the error's parts).

    The size model replaced the elements' count (``1 / f^2`` times as many): on the demo's capture at 1 s per spot
    the mannequin's many small triangles made a 2.4-fold count a 4-fold one, 13.6 mm instead of about 20 mm, and its
    error ratio came out 6 times under the target it was planned for."""
    from transient_mi.integrators._nlos_elements import element_scale_m

    if len(tri) == 0:
        return h * f, _even_cells(math.ceil(m / f))
    need = f * element_scale_m(tri, h)
    h_new = h * f
    for _ in range(200):
        if element_scale_m(tri, h_new) <= need * (1.0 + 1e-9):
            break
        h_new *= 0.95
    edge = element_scale_m(tri, h_new)
    m_new = _even_cells(math.ceil(m / f)) if footprint_m / m > edge else m
    return h_new, m_new


def plan_quadrature_level(tri, footprint_m: float, h: float, m: int, refine_levels: int, ratio: float,
                          parts: dict | None, target: float) -> tuple[float, int, int]:
    """The next ``(element_size_m, patch_cells, refine_levels)`` of :func:`render_group_quadrature`, refining the
    part of the error that sets it.

    The error is the sum of three parts (:func:`transient_mi.integrators._nlos_quadrature.error_parts`), and the
    ratio is quadratic in it, so the sum must shrink by ``kappa = sqrt(PLAN_MARGIN target / ratio)``. Each part's
    share is taken as the square root of the ratio it gives alone, and the largest share is refined, one step at a
    time, until the shares' sum is ``kappa`` times what it was:

    * ``visibility`` (the light of elements whose visibility samples disagree): one more visibility refinement
      level halves the mixed area (at most :data:`QUADRATURE_MAX_REFINE_LEVELS`; beyond, the elements shrink);
    * ``elements`` (second order): their size (:func:`~transient_mi.integrators._nlos_elements.element_scale_m`)
      shrinks by :data:`QUADRATURE_ELEMENT_STEP`, its part by the step to :data:`ELEMENTS_ORDER`, the visibility
      part by the step (the mixed area is a band one element wide) and the cells' part by the step to
      :data:`CELLS_ELEMENTS_ORDER` (it is estimated on the coarse elements), down to
      :data:`QUADRATURE_MIN_FACTOR` in one round (:func:`_next_quadrature_level`, which refines the cells as well
      where they are larger than the elements and several per side: their part is then in this one);
    * ``cells`` (one cell per patch side, second order): the next even count per side (:func:`_even_cells`: an odd
      count states far more error than it has), ``(m / m')^2`` of the part.

    On the paper scene's 8 x 8 demo capture at 1 s per spot (4 cm, one cell, one level: ratio 0.38 against 0.1) the
    parts gave 0.14 (visibility), 0.20 (elements) and 0.008 (cells): the cells, which the previous rule refined
    with the elements (two per side, four times the pairs), were not the error. Without ``parts`` (a render that
    did not return them) the elements shrink by ``(PLAN_MARGIN target / ratio)^(1/4)`` with the cells as before.
    """
    f_all = max(QUADRATURE_MIN_FACTOR, min(0.9, (PLAN_MARGIN * target / ratio) ** 0.25)) if ratio > 0 else 0.9
    b = {k: math.sqrt(max(float(v), 0.0)) for k, v in (parts or {}).items()}
    if not b or sum(b.values()) <= 0.0:
        h_new, m_new = _next_quadrature_level(tri, footprint_m, h, m, f_all)
        return h_new, m_new, refine_levels
    goal = math.sqrt(PLAN_MARGIN * target / ratio) * sum(b.values()) if ratio > 0 else 0.0
    f = 1.0
    m_cells = m
    for _ in range(64):
        if sum(b.values()) <= goal:
            break
        name = max(b, key=b.get)
        if name == "visibility" and refine_levels < QUADRATURE_MAX_REFINE_LEVELS:
            refine_levels += 1
            b["visibility"] *= 0.5
        elif name == "cells" and m_cells < 64:
            m_next = _even_cells(m_cells + 1)
            b["cells"] *= (m_cells / m_next) ** 2
            m_cells = m_next
        elif f * QUADRATURE_ELEMENT_STEP >= QUADRATURE_MIN_FACTOR:
            f *= QUADRATURE_ELEMENT_STEP
            b["elements"] = b.get("elements", 0.0) * QUADRATURE_ELEMENT_STEP ** ELEMENTS_ORDER
            if "visibility" in b:
                b["visibility"] *= QUADRATURE_ELEMENT_STEP
            if "cells" in b:
                b["cells"] *= QUADRATURE_ELEMENT_STEP ** CELLS_ELEMENTS_ORDER
        else:
            break  # (this round's refinement is as large as one round may take; the next round measures again)
    if f < 1.0:
        h, m_elem = _next_quadrature_level(tri, footprint_m, h, m, f)
        if m > 1:  # (several cells per side: the elements' part holds theirs, refined with it)
            m_cells = max(m_cells, m_elem)
    return h, m_cells, refine_levels


def render_group_quadrature(job, run: TargetRun, group: list[int], log=None):
    """Render one group of spots with the quadrature, refined until its error meets the target.

    The quadrature has no samples to add: every round renders the group afresh with finer settings, planned
    from the parts of the last round's error by :func:`plan_quadrature_level` (smaller elements, more visibility
    refinement levels or more cells per patch side, whichever sets the error), at most
    :data:`QUADRATURE_MAX_ROUNDS` times. The capture is the last round's render (deterministic: no
    stopping-rule bias). Returns ``(results, info per spot)``; the integrator's settings are restored afterwards.
    """
    from transient_mi.integrators._nlos_elements import mesh_triangles

    opts = job.integrator.nlos_options
    h0, m0, rl0 = float(opts["element_size_m"]), int(opts["patch_cells"]), int(opts["refine_levels"])
    h, m, rl = h0, m0, rl0
    say = log or (lambda line: None)
    name = f"spots {group[0]}-{group[-1]}" if len(group) > 1 else f"spot {group[0]}"
    setup = job.sensor.nlos_setup(job.scene)
    tri = mesh_triangles([s for s in setup.hidden_shapes if s.is_mesh()]).tri
    try:
        for rnd in range(QUADRATURE_MAX_ROUNDS + 1):
            opts.update(element_size_m=h, patch_cells=m, refine_levels=rl, error_parts=True)
            t0 = time.perf_counter()
            if len(group) == 1:
                res = [job.integrator.render_transient(job.scene, job.sensor, seed=0, spp=1, spot=group[0])]
            else:
                res = job.integrator.render_transient(job.scene, job.sensor, seed=0, spp=1, spots=group)
            ratios = _ratios(run, group, res)
            worst = max(ratios)
            g_worst = ratios.index(worst)
            last = worst <= run.spec.target or rnd == QUADRATURE_MAX_ROUNDS
            # (the parts plan the next round: the worst spot's, and only where there is one)
            parts = None if last else quadrature_part_ratios(run, group[g_worst], res[g_worst])
            for r in res:
                r.error_parts = None  # (the capture keeps their sum only)
            said = "" if not parts else " (" + ", ".join(f"{k} {v:.3g}" for k, v in parts.items()) + ")"
            say(f"{name}: quadrature, element_size_m {h:.4g}, patch_cells {m}, refine_levels {rl}: error ratio "
                f"{worst:.3g}{said} (target {run.spec.target:g}), {time.perf_counter() - t0:.0f} s")
            if last:
                break
            h, m, rl = plan_quadrature_level(tri, float(setup.footprint_m), h, m, rl, worst, parts, run.spec.target)
    finally:
        opts.update(element_size_m=h0, patch_cells=m0, refine_levels=rl0)
        opts.pop("error_parts", None)
    info = [{"element_size_m": h, "patch_cells": m, "refine_levels": rl, "rounds": rnd + 1, "ratio": ratios[g],
             "met": ratios[g] <= run.spec.target} for g in range(len(group))]
    if worst > run.spec.target:
        say(f"{name}: target {run.spec.target:g} NOT met after {rnd + 1} rounds (error ratio {worst:.3g})")
    return res, info
