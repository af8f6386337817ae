"""Integrator ``transient_path``: path tracing that records every contribution's time of flight."""

from __future__ import annotations


import drjit as dr
import mitsuba as mi
import numpy as np

from transient_mi.integrators._lanes import (STOKES_CHANNELS, ChannelHistogram, LaneHistogram, LaneLayout,
                                             channel_values, choose_streams, seed_rng, stokes_rotation)
from transient_mi.integrators._mis import mis_weight
from transient_mi.integrators._path_options import (as_int, check_render_call, estimator_suffix, read_nlos_options,
                                                     read_path_params, render_tensor, replicates_for)
from transient_mi.integrators._optical_path import segment_index
from transient_mi.integrators._pixel_filter import PixelFilter
from transient_mi.integrators._replicates import (ReplicateStats, effective_replicates,
                                                  replicate_seed)
from transient_mi.integrators._time_origin import TimeOrigin
from transient_mi.integrators._sensor_checks import is_nlos_sensor
from transient_mi.integrators.transient_nlos_path import render_nlos
from transient_mi.props import PluginParameterError

PLUGIN = ("integrator", "transient_path", "TransientPath")


class TransientPath(mi.CppADIntegrator):
    r"""Transient path tracer (``transient_path``).

    Unidirectional path tracing with next-event estimation and multiple
    importance sampling (power heuristic), the estimator of Mitsuba's
    ``path`` integrator, where every contribution is recorded in the
    ``transient_film`` at its own optical path length: from the sensor
    through every path vertex to the point on the emitter (for next-event
    estimation, the sampled emitter point; for emitter hits, the hit point).
    Summed over time the result equals Mitsuba's ``path`` image.

    Optical path length: every segment adds ``n d``, with ``n`` the relative
    refractive index of the medium it crosses, tracked through every
    refraction (``eta``, the product of the sampled ``bs.eta``; a next-event
    connection through a rough dielectric takes the index of the far side);
    see :mod:`transient_mi.integrators._optical_path`. The sensor's side
    counts as index 1.

    Time zero is when light leaves the emitter. The first segment is
    measured from where the light reaches the sensor, per sampled ray
    (:mod:`transient_mi.integrators._time_origin`; Mitsuba starts camera rays
    on the near-clip plane, so ``ray.o`` is traced back to the sensor plane):

    * ``perspective``: the centre of projection;
    * ``orthographic``: the ray's point on the image plane through the
      sensor's position (every pixel is timed from its own point, so an
      off-axis pixel is not late);
    * ``thinlens``: the ray's point on the lens, as mitransient does. The
      equal-time (Fermat) property of an ideal lens (every path from an
      in-focus point through the lens to its image takes the same time) is
      not modelled: paths from one in-focus point at distance ``d`` differ by
      the lens-point distance, up to ``r^2 / (2 d)`` for an aperture radius
      ``r`` (1 cm at 1 m: 50 um, 0.17 ps);
    * ``radiancemeter``, ``irradiancemeter`` and any other sensor: the ray's
      origin (the meter's point).

    Infinitely distant emitters (environment, directional) have no time of
    flight: their contributions are dropped and counted.

    Sampler and reconstruction filter
    (:mod:`transient_mi.integrators._sensor_checks`): the integrator draws
    its own PCG32 streams, one per SIMD lane, and reads the ``<sampler>``'s
    ``sample_count`` only; the ``independent`` sampler is accepted, every
    other (``stratified``, ``multijitter``, ``ldsampler``, ``orthogonal``, ...)
    refused (for variance reduction in NLOS captures see ``rqmc``). Camera
    sensors honour the film's ``<rfilter>`` by filter importance sampling
    (:mod:`transient_mi.integrators._pixel_filter`): each sample's offset from
    its pixel centre is drawn from the filter, separately in x and y, so a
    pixel converges to the filter-weighted average Mitsuba's films give;
    ``box``, ``tent``, ``gaussian`` (Mitsuba's default when the film gives
    none) and any non-negative filter are honoured, filters with negative
    lobes (``mitchell``, ``catmullrom``, ``lanczos``) refused. ``spad_array``:
    a pixel is a wall patch integrated uniformly; an explicit ``rfilter``
    other than ``box`` is refused, the film's default ignored.

    With a ``spad_array`` sensor it delegates to the NLOS estimator of
    ``transient_nlos_path`` (laser-spot and hidden-geometry sampling, see
    :mod:`transient_mi.integrators.transient_nlos_path`) with these
    parameters: same seed, same bytes as ``transient_nlos_path``, the NLOS
    integrator new scenes should name.

    .. list-table::
       :header-rows: 1

       * - Parameter
         - Type
         - Description
       * - ``max_depth``
         - integer
         - Longest path, in Mitsuba's meaning: 1 = only directly visible
           emitters, 2 = direct illumination, 3 = one indirect bounce ...;
           -1 = unlimited (default).
       * - ``rr_depth``
         - integer
         - Depth at which Russian roulette starts, >= 1 (default 5).
       * - ``variance_replicates``
         - integer
         - Independent replicates each render is split into, in [1, 1024]
           (default 1: no variance; ``transient-mi render`` uses 8 for NLOS
           captures): the capture stores their mean and the variance of every bin (see
           :mod:`transient_mi.integrators._replicates`);
           ``gcd(spp, variance_replicates)`` are used; 1 records no variance.
       * - ``rqmc``
         - boolean
         - NLOS only: randomised quasi-Monte Carlo (a shifted Kronecker
           sequence) for the patch point and the first bounce (default
           true); false draws them from PCG32 (plain Monte Carlo), for
           comparisons.
       * - ``hidden_geometry_prob``
         - float
         - NLOS only: probability of hidden-geometry sampling (vs BSDF
           sampling) at the relay-wall patch point, in [0, 1] (default 0.8).
       * - ``estimator``, ``element_size_m``, ``patch_cells``, ``refine_levels``, ``element_slope``
         - string, float, integer, integer, boolean
         - NLOS only: ``estimator="quadrature"`` renders three-bounce light
           deterministically, with the quadrature's settings (beyond
           ``max_depth=4`` plus the Monte Carlo remainder); as
           ``transient_nlos_path`` (same names, defaults and ranges).

    Determinism: each SIMD lane accumulates its own histogram slot (see
    :mod:`transient_mi.integrators._lanes`), so the same seed gives the same
    bytes.

    Variants: renders need a JIT variant (``llvm_*``, ``cuda_*``).
    ``scalar_*`` variants load scenes and construct the plug-ins (to debug
    XML and parameters). To inspect the integrator's intermediate values,
    use an ``llvm_*`` variant with ``dr.set_flag(dr.JitFlag.SymbolicLoops,
    False)`` (evaluated loops whose variables can be printed).
    """

    NAME = "transient_path"

    def __init__(self, props: mi.Properties):
        super().__init__(props)
        max_depth, self.rr_depth, replicates = read_path_params(props, self.NAME)
        self.max_depth_param = max_depth
        self.max_depth = max_depth if max_depth != -1 else 0xFFFFFFFF
        #: None: the default for the sensor (see :meth:`replicates_for`)
        self.variance_replicates = replicates
        #: NLOS only (``rqmc``, ``hidden_geometry_prob``), see :func:`~._path_options.read_nlos_options`
        self.nlos_options = read_nlos_options(props, self.NAME)

    def replicates_for(self, nlos: bool) -> int:
        """Replicates a render is split into (cameras and NLOS alike, see :func:`~._path_options.replicates_for`)."""
        return replicates_for(self.variance_replicates)

    # ---------------------------------------------------------------- API

    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True, progress=None):
        """Render and return the histograms as ``mi.TensorXf [height, width, n_bins]``.

        The film keeps the full :class:`~transient_mi.films.transient_film.TransientResult`.
        """
        return render_tensor(self, scene, sensor, seed, spp, progress)

    def render_backward(self, scene, params, grad_in, sensor=0, seed=0, spp=0):
        """Reverse-mode derivative (what ``dr.backward`` after ``mi.render(scene, params)`` calls): propagate
        ``grad_in`` (``[height, width, n_bins(, channels)]``) to the scene parameters. Camera sensors;
        see :mod:`transient_mi.integrators._ad` for what is differentiated; NLOS sensors
        (``spad_array``): :mod:`transient_mi.integrators._nlos_ad` (``estimator="quadrature"``:
        :mod:`transient_mi.integrators._nlos_quadrature_ad`)."""
        from transient_mi.integrators._ad import render_backward

        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        if is_nlos_sensor(sensor) and self.nlos_options.get("estimator") == "quadrature":
            from transient_mi.integrators._nlos_quadrature_ad import quadrature_backward

            return quadrature_backward(self, scene, params, grad_in, sensor)
        if is_nlos_sensor(sensor):
            from transient_mi.integrators._nlos_ad import nlos_backward

            return nlos_backward(self, scene, params, grad_in, sensor, as_int(seed), as_int(spp))
        render_backward(self, scene, params, grad_in, sensor, as_int(seed), as_int(spp))

    def render_forward(self, scene, params, sensor=0, seed=0, spp=0):
        """Forward-mode derivative of the histograms along the parameters' tangents (``dr.forward``)."""
        from transient_mi.integrators._ad import render_forward

        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        if is_nlos_sensor(sensor) and self.nlos_options.get("estimator") == "quadrature":
            from transient_mi.integrators._nlos_quadrature_ad import quadrature_forward

            return quadrature_forward(self, scene, params, sensor)
        if is_nlos_sensor(sensor):
            from transient_mi.integrators._nlos_ad import nlos_forward

            return nlos_forward(self, scene, params, sensor, as_int(seed), as_int(spp))
        return render_forward(self, scene, params, sensor, as_int(seed), as_int(spp))

    def render_transient(self, scene, sensor, *, seed: int = 0, spp: int = 0, spot: int | None = None,
                         spots=None, progress=None, replicate_offset: int = 0, replicates: int | None = None):
        """Render one transient image (or one laser spot of an NLOS capture).

        Parameters
        ----------
        scene, sensor
            Mitsuba scene and its sensor (whose film is a transient film).
        seed : int
            Seed of the random streams (0 <= seed < 2**32).
        spp : int
            Samples per pixel; 0 takes the sensor's sampler value.
        spot : int, optional
            Laser spot to render (NLOS sensors only).
        spots : sequence of int, optional
            A group of laser spots to render together (NLOS array captures,
            see ``spad_array.spot_groups``); a list of results is returned.
        progress : callable, optional
            ``progress(done_paths, total_paths)`` after every kernel launch.
        replicate_offset : int
            Index of the first replicate: a later batch of a progressive
            render (``render --noise-target``) continues the replicate seeds
            (see :mod:`transient_mi.integrators._replicates`).
        replicates : int, optional
            Replicates of this call (overrides ``variance_replicates``; must
            divide ``spp``).

        Returns
        -------
        TransientResult
        """
        film, spp = check_render_call(self.NAME, sensor, seed, spp, replicates)
        if is_nlos_sensor(sensor):  # the estimator of transient_nlos_path, with this integrator's parameters
            return render_nlos(self, scene, sensor, seed=seed, spp=spp, spot=spot, spots=spots, progress=progress,
                               replicate_offset=replicate_offset, replicates=replicates)
        else:
            if spot not in (None, 0) or spots not in (None, [0]):
                raise PluginParameterError(f"{self.NAME}: spot={spot} given, but the sensor is a camera")
            result = self._render_camera(scene, sensor, seed, spp, progress, replicate_offset, replicates)
        film.set_result(result)
        return result

    # ------------------------------------------------------------- camera

    def _render_camera(self, scene, sensor, seed, spp, progress, replicate_offset=0, replicates=None):
        from transient_mi.films.transient_film import TransientResult

        film = sensor.film()
        W, H = film.width, film.height
        axis = film.time_axis()
        R = replicates or effective_replicates(spp, self.replicates_for(False))
        n = spp // R
        total = W * H * spp
        stats, steady, dropped, frac = None, 0.0, 0, 0.0
        invalid, negative = 0, 0.0
        for r in range(R):
            done0 = W * H * n * r

            def rep_progress(d, _t, _done=done0):
                if progress is not None:
                    progress(_done + d, total)

            (h, st, dr_n, fr), anomalies = self._render_camera_replicate(
                scene, sensor, replicate_seed(seed, replicate_offset + r, R), n, rep_progress)
            invalid += anomalies["invalid"]
            negative = min(negative, anomalies["negative_fraction"])
            if stats is None:
                stats = ReplicateStats.first(h)
            else:
                stats.add(h)
            steady = steady + st.astype(np.float64)
            dropped += dr_n
            frac += fr
            del h
        var, tvar = stats.variance(), stats.total_variance()
        ch = stats.mean.shape[2:]  # (n_channels,) for multi-channel films, else ()
        return TransientResult(
            histogram=stats.mean.reshape((H, W, axis.n_bins) + ch),
            steady=(steady / R).astype(np.float32).reshape((H, W) + ch),
            dropped_contributions=dropped,
            dropped_fraction=frac / R,
            samples=total,
            variance=None if var is None else var.reshape((H, W, axis.n_bins) + ch),
            total_variance=None if tvar is None else tvar.reshape((H, W) + ch),
            replicates=R,
            invalid_contributions=invalid,
            negative_fraction=negative,
        )

    def _render_camera_replicate(self, scene, sensor, seed, spp, progress):
        """One replicate: ``(hist[n_pixels, n_bins], steady[n_pixels], dropped, fraction)`` and the anomalies
        ``{"invalid": n, "negative_fraction": f}`` (see :class:`~transient_mi.integrators._lanes.LaneHistogram`)."""
        film = sensor.film()
        W, H = film.width, film.height
        taps = film.kernel_taps()
        pad = len(taps) // 2
        axis = film.time_axis()
        channels = film.channel_names() if hasattr(film, "channel_names") else None
        n_ch = len(channels) if channels else 1
        K = choose_streams(W * H, spp, (axis.n_bins + 2 * pad) * n_ch)
        layout = LaneLayout(W * H, spp, K)
        hist = LaneHistogram(layout, axis, pad) if channels is None else ChannelHistogram(layout, axis, pad, n_ch)
        # what _trace records per contribution (read there: keeps its signature for subclasses)
        self._channels, self._sensor = channels, sensor
        rng = seed_rng(seed, layout.n_lanes)
        origin = TimeOrigin(sensor)
        pixel_filter = PixelFilter(film.rfilter(), film.sample_border())
        total = layout.n_pixels * spp
        for j0, j1 in layout.passes():
            rng = self._camera_pass(scene, sensor, hist, rng, layout, j0, j1, W, H, origin, pixel_filter)
            hist.evaluate(rng)
            done = min(total, layout.n_pixels * min(spp, j1 * K))
            if progress is not None:
                progress(done, total)
        out = hist.collect(taps)
        return out, {"invalid": hist.invalid_count(), "negative_fraction": hist.negative_fraction}

    @dr.syntax
    def _camera_pass(self, scene, sensor, hist, rng, layout, j0, j1, W, H, origin, pixel_filter, trace=None):
        """Trace the samples ``[j0, j1)`` of every lane. ``origin``: a
        :class:`~transient_mi.integrators._time_origin.TimeOrigin`; ``pixel_filter``: a
        :class:`~transient_mi.integrators._pixel_filter.PixelFilter` (image-plane positions);
        ``trace``: what follows each camera ray (default :meth:`_trace`; the AD passes of
        :mod:`transient_mi.integrators._ad` pass their own)."""
        trace = self._trace if trace is None else trace
        K = layout.streams
        lane = dr.arange(mi.UInt32, layout.n_lanes)
        pixel = lane // K
        k = lane - pixel * K
        px = mi.Float(pixel % W)
        py = mi.Float(pixel // W)
        j = mi.UInt32(dr.opaque(mi.UInt32, j0))
        j_end = dr.opaque(mi.UInt32, j1)
        spp = dr.opaque(mi.UInt32, layout.spp)
        inv_size = mi.Vector2f(1.0 / W, 1.0 / H)
        bx, by = pixel_filter.bounds(px, W), pixel_filter.bounds(py, H)
        needs_aperture = sensor.needs_aperture_sample()
        while (j < j_end) & (k + j * K < spp):
            x = pixel_filter.sample(px, rng.next_float32(), bx)
            y = pixel_filter.sample(py, rng.next_float32(), by)
            pos = mi.Vector2f(x, y) * inv_size
            aperture = mi.Point2f(rng.next_float32(), rng.next_float32()) if needs_aperture else mi.Point2f(0.5)
            wav = rng.next_float32() if mi.is_spectral else mi.Float(0)
            ray, ray_weight = sensor.sample_ray_differential(mi.Float(0), wav, pos, aperture)
            ray = mi.Ray3f(ray)
            trace(scene, rng, hist, lane, ray, ray_weight, origin(ray))
            j += 1
        return rng

    def _channel_setup(self, ray):
        """``(channels, rotation)`` for :func:`~transient_mi.integrators._lanes.channel_values`: the film's
        channels of this render and, for Stokes vectors, the rotation into the sensor's frame."""
        channels = getattr(self, "_channels", None)
        if channels != STOKES_CHANNELS:
            return channels, None
        return channels, stokes_rotation(self._sensor, ray.d)

    @dr.syntax
    def _trace(self, scene, rng, hist, lane, ray, throughput, origin):
        """Trace one path per lane and record every contribution at its path length.

        ``origin``: where the first segment's length is measured from (per lane, see
        :mod:`transient_mi.integrators._time_origin`).
        """
        ctx = mi.BSDFContext()
        wavelengths = ray.wavelengths
        ray = mi.Ray3f(ray)
        depth = mi.UInt32(0)
        beta = mi.Spectrum(throughput)
        eta = mi.Float(1)
        active = mi.Bool(True)
        prev_si = dr.zeros(mi.SurfaceInteraction3f)
        prev_bsdf_pdf = mi.Float(1)
        prev_bsdf_delta = mi.Bool(True)
        si = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=True)
        opl = dr.select(si.is_valid(), dr.norm(si.p - origin), dr.inf)
        channels, rotation = self._channel_setup(ray)
        max_depth = self.max_depth
        rr_depth = self.rr_depth

        while active:
            # ---- emitter hit (weighted against the previous vertex's NEE)
            ds = mi.DirectionSample3f(scene, si=si, ref=prev_si)
            em_pdf = scene.pdf_emitter_direction(prev_si, ds, ~prev_bsdf_delta)
            Le = beta * mis_weight(prev_bsdf_pdf, em_pdf) * ds.emitter.eval(si, prev_bsdf_pdf > 0)
            hist.record(lane, opl, channel_values(Le, wavelengths, channels, rotation),
                        active & (ds.emitter != None))  # noqa: E711

            active_next = active & si.is_valid() & (depth + 1 < max_depth)
            bsdf = si.bsdf(ray)

            # ---- next-event estimation
            active_em = active_next & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
            ds, em_weight = scene.sample_emitter_direction(
                si, mi.Point2f(rng.next_float32(), rng.next_float32()), True, active_em)
            active_em &= ds.pdf != 0
            wo = si.to_local(ds.d)
            bsdf_val, bsdf_pdf = bsdf.eval_pdf(ctx, si, wo, active_em)
            mis_em = dr.select(ds.delta, 1, mis_weight(ds.pdf, bsdf_pdf))
            Lr = beta * mis_em * bsdf_val * em_weight
            # the segment to the emitter runs at c / n: n = eta on this side, changed by a rough dielectric's
            # transmission (see segment_index)
            n_em = segment_index(bsdf, si, wo, eta, active_em)
            hist.record(lane, opl + n_em * ds.dist, channel_values(Lr, wavelengths, channels, rotation), active_em)

            # ---- BSDF sampling
            bs, bsdf_weight = bsdf.sample(ctx, si, rng.next_float32(),
                                          mi.Point2f(rng.next_float32(), rng.next_float32()), active_next)
            ray = si.spawn_ray(si.to_world(bs.wo))
            eta *= bs.eta
            beta *= bsdf_weight
            prev_si = dr.detach(si, True)
            prev_bsdf_pdf = bs.pdf
            prev_bsdf_delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)

            # ---- Russian roulette (as Mitsuba's path)
            depth[si.is_valid()] += 1
            beta_max = dr.max(mi.unpolarized_spectrum(beta))
            rr_prob = dr.minimum(beta_max * dr.square(eta), 0.95)
            rr_active = depth >= rr_depth
            rr_continue = rng.next_float32() < rr_prob
            beta[rr_active] *= dr.rcp(rr_prob)
            active = active_next & (~rr_active | rr_continue) & (beta_max != 0)

            si_next = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=False, active=active)
            # optical path: the new segment lies in the medium of relative index eta (1 outside dielectrics)
            opl = dr.select(si_next.is_valid(), opl + eta * dr.norm(si_next.p - si.p), dr.inf)
            si = si_next

    def to_string(self):
        o = self.nlos_options
        return (f"TransientPath[max_depth={self.max_depth_param}, rr_depth={self.rr_depth}, "
                f"variance_replicates={self.variance_replicates or 'default'}, hidden_geometry_prob={o['hidden_geometry_prob']:g}, "
                f"rqmc={str(o['rqmc']).lower()}"
                f"{estimator_suffix(o)}]")
