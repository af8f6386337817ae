"""Rendering of NLOS laser spots: replicates, spot groups, the group histogram and the closed-form wall return.

:func:`render_spots` is what the ``transient_nlos_path`` integrator (and ``transient_path`` under a
``spad_array``, which delegates to it) runs for one group of laser spots: it splits the samples into
independent replicates (:mod:`._replicates`), runs the Dr.Jit kernel (:mod:`._nlos_kernel`) over the lanes
of :func:`group_layout` into a :class:`GroupHistogram`, adds the wall's first-bounce return in closed form,
and returns one ``TransientResult`` per spot. The estimator is documented in
:mod:`transient_mi.integrators.transient_nlos_path`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import drjit as dr
import mitsuba as mi
import numpy as np

from transient_mi._upload import upload
from transient_mi.integrators._lanes import (NLOS_GROUP_TARGET_LANES, LaneHistogram, LaneLayout, dropped_fraction,
                                             seed_rng, streams_for, sum_strided)
from transient_mi.integrators._nlos_kernel import KernelConstants, KernelScene, nlos_pass
from transient_mi.integrators._replicates import (DEFAULT_REPLICATES, ReplicateStats, effective_replicates,
                                                  replicate_seed)
from transient_mi.props import PluginParameterError
from transient_mi.time_axis import apply_kernel

if TYPE_CHECKING:
    from transient_mi.sensors._nlos_setup import NLOSSetup

#: Histogram floats held per kernel launch when an array capture renders a group of spots at once.
GROUP_HIST_FLOATS = 1 << 26
#: Most laser spots rendered together (sharing the detector-side sub-paths).
MAX_GROUP = 64


def group_layout(n_pixels: int, spp: int, n_bins_ext: int, n_spots: int) -> tuple[int, int]:
    """``(streams K, spots per group)`` for an NLOS capture; depends only on the configuration.

    ``K`` follows the lane policy of :func:`~._lanes.streams_for` with the target
    :data:`~._lanes.NLOS_GROUP_TARGET_LANES` (few lanes keep the per-lane histograms, which are zeroed and
    summed for every launch, small; each lane loops over many samples) and no memory cap on ``K``: the
    memory is budgeted by the group size instead, as many spots as fit ``GROUP_HIST_FLOATS`` histogram
    values (at least 1, at most :data:`MAX_GROUP`). Every group shares the detector-side sub-path of each
    sample (patch point, hidden vertex, further bounces) between its spots.
    """
    k = streams_for(n_pixels, spp, n_bins_ext, NLOS_GROUP_TARGET_LANES, None)
    per_spot = n_pixels * k * n_bins_ext
    g = max(1, min(MAX_GROUP, n_spots, GROUP_HIST_FLOATS // max(per_spot, 1)))
    return k, g


def conflict_free_rounds(keys: np.ndarray) -> np.ndarray:
    """The record each entry goes to so that no record holds a key twice: an entry's round is the number of
    entries of its key before it (``keys`` int ``[n]``; returns int64 ``[n]``, the largest round + 1 records)."""
    order = np.argsort(keys, kind="stable")
    ks = keys[order]
    first = np.r_[True, ks[1:] != ks[:-1]] if len(ks) else np.zeros(0, dtype=bool)
    start = np.maximum.accumulate(np.where(first, np.arange(len(ks)), 0)) if len(ks) else np.zeros(0, np.int64)
    rounds = np.empty(len(ks), dtype=np.int64)
    rounds[order] = np.arange(len(ks)) - start
    return rounds


class GroupHistogram(LaneHistogram):
    """Lane histograms with one sub-slot per spot of the group (slot = ``lane * G + spot``)."""

    def __init__(self, layout: LaneLayout, axis, pad: int, n_sub: int):
        n = layout.n_lanes * n_sub
        super().__init__(layout, axis, pad, n_slots=n, n_count_slots=n)
        self.n_sub = n_sub
        self._nsub = dr.opaque(mi.UInt32, n_sub)

    def record(self, lane, opl_m, value, active, sub=0):
        slot = mi.UInt32(lane) * self._nsub + mi.UInt32(sub)
        LaneHistogram.record(self, slot, opl_m, value, active)

    def collect_all(self, taps, scale: float = 1.0):
        """Yield per spot of the group ``(hist[n_pixels, n_bins] float32, steady[n_pixels], dropped, fraction)``.

        Values are averaged over the samples and multiplied by ``scale``. The
        ``K`` stream slots of a pixel are summed in a fixed order in one drjit
        kernel (as :meth:`LaneHistogram._per_pixel`); each spot's histogram is
        a view into that one buffer.
        """
        L = self.layout
        T = self.n_bins_ext
        G = self.n_sub
        f = scale / L.spp
        idx = dr.arange(mi.UInt32, L.n_pixels * G * T)
        pg = idx // T  # (pixel, spot of the group)
        pixel = pg // G
        base = (pixel * (L.streams * G) + (pg - pixel * G)) * self.stride + (idx - pg * T)
        out = sum_strided(self.data, base, G * self.stride, L.streams, L.n_pixels * G * T)
        out *= f
        dr.eval(out)
        lost = self._overflow().reshape(L.n_pixels, L.streams, G).sum(axis=1) * f
        dropped = self._counters()[:, 0].reshape(L.n_pixels, L.streams, G).sum(axis=(0, 1), dtype=np.uint64)
        self.data = None  # free the lane slots
        hist = np.asarray(out).reshape(L.n_pixels, G, T)  # zero-copy view
        del out
        rows = hist.sum(axis=2, dtype=np.float64)  # [P, G]
        for g in range(G):
            h = hist[:, g, :]
            steady = rows[:, g] + lost[:, g]
            if len(taps) > 1:
                h = apply_kernel(h, taps).astype(np.float32)
                in_hist = float(h.sum(dtype=np.float64))
            else:
                in_hist = float(rows[:, g].sum())
            total = float(steady.sum())
            frac = dropped_fraction(self, total, in_hist)
            yield h, steady, int(dropped[g]), frac


def render_spots(setup: "NLOSSetup", scene, film, options: dict, *, seed: int, spp: int, spots, progress=None,
                 replicate_offset: int = 0, replicates: int | None = None):
    """Render a group of laser spots of an array capture together (or the confocal capture, ``[0]``).

    The spots of a group share every sample's detector-side sub-path
    (patch point, hidden vertex, further bounces) and differ only in the
    final connection to their laser spot: each spot's estimate is unbiased,
    and a group of ``G`` spots costs little more than one. The result of a
    spot depends on the seed and on the group it was rendered with (the
    render pipeline always uses the same groups, see
    :meth:`~transient_mi.sensors.spad_array.SpadArray.spot_groups`).

    Parameters
    ----------
    setup : NLOSSetup
        From :meth:`~transient_mi.sensors._nlos_setup.NLOSSetup.build` for this ``scene``.
    scene : mitsuba.Scene
    film : transient_film
    options : dict
        ``max_depth`` (segments, -1 unlimited), ``rr_depth``,
        ``hidden_geometry_prob`` (alpha in [0, 1]), ``variance_replicates``
        (independent replicates, see :mod:`._replicates`), ``medium`` (an
        :class:`~._nlos_medium.NLOSMedium` to render through, or None: the
        surface kernel).
    seed, spp : int
    spots : sequence of int
        Laser spot indices (scan order); ``[0]`` for confocal captures.
    progress : callable, optional
        ``progress(done_paths, total_paths)``.
    replicate_offset : int
        Index of the first replicate (a later batch of a progressive render
        continues the replicate seeds where the earlier one stopped).
    replicates : int, optional
        Replicates of this call (default ``gcd(spp, variance_replicates)``);
        must divide ``spp``.

    Returns
    -------
    list of TransientResult
        One per spot, histograms ``[height, width, n_bins]`` in photons per
        pulse per bin, with the variance of every bin estimated from the
        independent replicates (:mod:`._replicates`).

    With ``estimator="quadrature"`` the three-bounce light and the wall return come from
    :func:`~._nlos_quadrature.render_spots_quadrature` (an ``error_bound``, no variance); with ``max_depth``
    above 4 (or -1) the Monte Carlo remainder (the same kernel with ``skip_three_bounce``: every other path)
    is added by :func:`combine_remainder`, whose results carry both the bound and the remainder's variance.
    """
    W, H = setup.width, setup.height
    spots = [int(j) for j in spots]
    confocal = setup.capture == "confocal"
    if confocal and spots != [0]:
        raise PluginParameterError(f"spad_array: spots={spots}; a confocal capture is one file (spot 0)")
    for j in spots:
        if not 0 <= j < setup.n_spots:
            raise PluginParameterError(f"spad_array: spot={j} out of range [0, {setup.n_spots})")
    if len(set(spots)) != len(spots) or not spots:
        raise PluginParameterError(f"spad_array: spots={spots} must be distinct and non-empty")
    if options.get("estimator") == "quadrature":  # deterministic three-bounce estimator (+ the MC remainder)
        from transient_mi.integrators._nlos_quadrature import (check_supported, needs_remainder,
                                                               render_spots_quadrature)

        plugin = options.get("plugin", "transient_nlos_path")
        if options.get("medium") is not None:
            raise PluginParameterError(f"{plugin}: estimator=quadrature cannot render through a medium (fog); use "
                                       "estimator=monte_carlo")
        check_supported(setup, options, plugin)
        total = W * H * spp
        remainder = needs_remainder(options)
        share = 1.0 if not remainder else 0.5  # of the progress bar (then the Monte Carlo remainder's)

        def tick(done, n):
            if progress is not None and n > 0:
                progress(int(total * share * done / n), total)

        results = render_spots_quadrature(setup, scene, film, options, spots, progress=tick)
        if not remainder:
            if progress is not None:
                progress(total, total)
            return results
        # light beyond three bounces: the Monte Carlo estimator without the three-bounce connection and the
        # wall return (KernelConstants.skip_three_bounce); the sum is unbiased up to the quadrature's error
        def rest_progress(done, n):  # the second half of the bar
            if progress is not None and n > 0:
                progress(int(total * (share + (1.0 - share) * done / n)), total)

        rest = _render_monte_carlo(setup, scene, film, dict(options, skip_three_bounce=True), seed=seed, spp=spp,
                                   spots=spots, progress=rest_progress, replicate_offset=replicate_offset,
                                   replicates=replicates)
        return [combine_remainder(q, r) for q, r in zip(results, rest)]
    return _render_monte_carlo(setup, scene, film, options, seed=seed, spp=spp, spots=spots, progress=progress,
                               replicate_offset=replicate_offset, replicates=replicates)


def combine_remainder(q, r):
    """The capture of ``estimator="quadrature"`` beyond three bounces: the quadrature's result ``q`` (three-bounce
    light and the wall return, with its ``error_bound``) plus the Monte Carlo remainder ``r`` (every other path,
    with its replicate ``variance``). Both errors are kept, each of its own part."""
    from transient_mi.films.transient_film import TransientResult

    info = dict(q.estimator_info or {}, remainder="monte_carlo", remainder_samples=r.samples,
                remainder_replicates=r.replicates, quadrature_pairs=q.samples)
    return TransientResult(
        histogram=(q.histogram.astype(np.float64) + r.histogram.astype(np.float64)).astype(np.float32),
        steady=(q.steady.astype(np.float64) + r.steady.astype(np.float64)).astype(np.float32),
        dropped_contributions=q.dropped_contributions + r.dropped_contributions,
        dropped_fraction=_combined_fraction(q, r),
        samples=r.samples,
        variance=r.variance,
        total_variance=r.total_variance,
        replicates=r.replicates,
        invalid_contributions=r.invalid_contributions,
        negative_fraction=r.negative_fraction,
        error_bound=q.error_bound,
        total_error_bound=q.total_error_bound,
        estimator_info=info,
    )


def _combined_fraction(q, r) -> float:
    """Share of the combined light outside the histogram (each part's fraction weighted by its light)."""
    tq, tr = float(q.steady.astype(np.float64).sum()), float(r.steady.astype(np.float64).sum())
    return (q.dropped_fraction * tq + r.dropped_fraction * tr) / (tq + tr) if tq + tr > 0 else 0.0


def _render_monte_carlo(setup: "NLOSSetup", scene, film, options: dict, *, seed: int, spp: int, spots, progress,
                        replicate_offset: int, replicates: int | None):
    """The Monte Carlo estimator of :func:`render_spots`: independent replicates of :func:`_render_replicate`."""
    from transient_mi.films.transient_film import TransientResult

    W, H = setup.width, setup.height
    R = replicates or effective_replicates(spp, options.get("variance_replicates", DEFAULT_REPLICATES))
    n = spp // R
    P = W * H
    total = P * spp
    stats: list = [None] * len(spots)
    steady = [np.zeros(P) for _ in spots]
    dropped = [0] * len(spots)
    frac = [0.0] * len(spots)
    invalid, negative = 0, 0.0
    for r in range(R):
        done = P * n * r

        def rep_progress(d, _t, _done=done):
            if progress is not None:
                progress(_done + d, total)

        outs, anomalies = _render_replicate(setup, scene, film, options,
                                            seed=replicate_seed(seed, replicate_offset + r, R), spp=n, spots=spots,
                                            progress=rep_progress)
        invalid += anomalies["invalid"]
        negative = min(negative, anomalies["negative_fraction"])
        for g, (h, st, dr_n, fr) in enumerate(outs):
            if stats[g] is None:
                stats[g] = ReplicateStats.first(h)
            else:
                stats[g].add(h)
            steady[g] += st
            dropped[g] += dr_n
            frac[g] += fr
        del outs
    T = film.time_axis().n_bins
    results = []
    for g in range(len(spots)):
        s = stats[g]
        var = s.variance()
        tvar = s.total_variance()
        results.append(TransientResult(
            histogram=s.mean.reshape(H, W, T),
            steady=(steady[g] / R).astype(np.float32).reshape(H, W),
            dropped_contributions=dropped[g],
            dropped_fraction=frac[g] / R,
            samples=total,
            variance=None if var is None else var.reshape(H, W, T),
            total_variance=None if tvar is None else tvar.reshape(H, W),
            replicates=R,
            invalid_contributions=invalid if g == 0 else 0,  # (per group: counted once)
            negative_fraction=negative,
        ))
    return results


def _render_replicate(setup: "NLOSSetup", scene, film, options: dict, *, seed: int, spp: int, spots, progress=None):
    """One replicate of :func:`render_spots`: ``spp`` samples with the streams of ``seed``.

    Returns one ``(hist[n_pixels, n_bins] float32, steady[n_pixels], dropped, fraction)`` per spot, and
    ``{"invalid": n, "negative_fraction": f}`` (see :class:`~._lanes.LaneHistogram`).
    """
    W, H = setup.width, setup.height
    confocal = setup.capture == "confocal"
    taps = film.kernel_taps()
    pad = len(taps) // 2
    axis = film.time_axis()
    G = len(spots)
    K, _ = group_layout(W * H, spp, axis.n_bins + 2 * pad, 1 if confocal else setup.n_spots)
    layout = LaneLayout(W * H, spp, K)
    hist = GroupHistogram(layout, axis, pad, G)
    rng = seed_rng(seed, layout.n_lanes)

    c = KernelConstants.build(setup, options, seed=seed, n_group=G)
    ks = KernelScene.build(scene, setup, spots)
    fog = options.get("medium")  # NLOSMedium (transient_volpath with a sensor medium) or None
    if fog is not None:
        from transient_mi.integrators._nlos_medium import MediumConstants, nlos_medium_pass
        mc = MediumConstants.build(fog)

    total = layout.n_pixels * spp
    for j0, j1 in layout.passes():
        if fog is None:
            rng = nlos_pass(scene, hist, rng, layout, j0, j1, c, ks)
        else:
            rng = nlos_medium_pass(scene, hist, rng, layout, j0, j1, c, ks, mc)
        hist.evaluate(rng)  # one evaluation of the loop (evaluating rng separately would run it twice)
        if progress is not None:
            progress(min(total, layout.n_pixels * min(spp, j1 * K)), total)

    # closed-form first-bounce return of the wall (weighted by spp: collect() divides by it); a divergent
    # beam's footprint has M entries per spot (arrays [n_spots, M], flattened here)
    wr = setup.wall_return if fog is None else fog.wall_return(setup)
    if c.skip_three_bounce:  # the remainder of estimator=quadrature: the quadrature adds the wall return
        wr = dict(wr, photons=np.zeros_like(wr["photons"]))
    all_spots = np.arange(setup.n_spots) if confocal else np.array(spots)
    sub = np.zeros(len(all_spots), dtype=np.uint32) if confocal else np.arange(G, dtype=np.uint32)
    pix = wr["pixel"][all_spots]
    sub = np.broadcast_to(sub.reshape((-1,) + (1,) * (pix.ndim - 1)), pix.shape).reshape(-1)
    pix = pix.reshape(-1)
    photons = wr["photons"][all_spots].reshape(-1)
    opl = wr["opl_m"][all_spots].reshape(-1)
    sel = np.flatnonzero((pix >= 0) & (photons > 0))
    # The records add without atomics (ReduceMode.NoConflicts), so no record may hold two entries of one slot: a
    # divergent beam's footprint samples of a spot (or, confocal, of neighbouring spots) often share a pixel and a
    # bin, and on a GPU such entries in one record raced (lost or reordered additions). Entries of one slot go to
    # successive records in their order (spot-major, then footprint sample): the additions' order stays fixed.
    rounds = conflict_free_rounds(pix[sel].astype(np.int64) * G + sub[sel])
    for r in range(int(rounds.max()) + 1 if len(sel) else 0):
        e = sel[rounds == r]
        ph = photons[e] / setup.photons_per_pulse  # N is applied below
        hist.record(upload(mi.UInt32, pix[e] * K), upload(mi.Float, opl[e]), upload(mi.Float, ph * spp),
                    mi.Bool(True), sub=upload(mi.UInt32, sub[e]))
        hist.evaluate()

    out = list(hist.collect_all(taps, scale=setup.photons_per_pulse))
    anomalies = {"invalid": hist.invalid_count(), "negative_fraction": hist.negative_fraction}
    return out, anomalies


