"""Integrator ``transient_volpath``: volumetric path tracing that records every contribution's time of flight."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from transient_mi.integrators._lanes import channel_values
from transient_mi.integrators._media import index_spectrum
from transient_mi.integrators._mis import mis_weight
from transient_mi.integrators._optical_path import segment_index
from transient_mi.integrators._path_options import (as_int, check_render_call, estimator_suffix, read_nlos_options,
                                                     read_path_params)
from transient_mi.integrators._sensor_checks import is_nlos_sensor
from transient_mi.integrators.transient_nlos_path import render_nlos
from transient_mi.integrators.transient_path import TransientPath
from transient_mi.props import get_bool

PLUGIN = ("integrator", "transient_volpath", "TransientVolPath")


def _has_heterogeneous_medium(scene, sensor_medium) -> bool:
    """Whether any medium of ``scene`` (inside or outside a shape, or the sensor's) is not homogeneous."""
    media = [sensor_medium] + [m for sh in scene.shapes() for m in (sh.interior_medium(), sh.exterior_medium())]
    return any(m is not None and not m.is_homogeneous() for m in media)


class TransientVolPath(TransientPath):
    r"""Transient volumetric path tracer (``transient_volpath``).

    The estimator of Mitsuba's ``volpath`` (unidirectional volumetric path
    tracing with delta tracking, next-event estimation and multiple importance
    sampling), where every contribution is recorded in the ``transient_film``
    at its own optical path length. Summed over time the result equals
    Mitsuba's ``volpath`` image.

    Supported: homogeneous and heterogeneous (grid) media, as the interior or
    exterior medium of shapes and as the sensor's medium (``<medium>`` nested
    in the sensor: the medium the camera sits in, e.g. global fog); free-flight
    sampling with ``Medium.sample_interaction`` (for heterogeneous media,
    delta tracking against the majorant: null and real scattering);
    phase-function sampling and evaluation; next-event estimation from
    surfaces and from medium vertices with the transmittance of the shadow ray
    (closed form through homogeneous media, ratio tracking through
    heterogeneous ones, crossing ``null``-BSDF medium boundaries); MIS (power
    heuristic); Russian roulette. RGB variants sample one colour channel per
    path for the free-flight distances (spectrally varying extinction), as
    ``volpath`` does. Media in Mitsuba 3.9 do not emit light.

    Time in media: a path's optical path length is the sum of the lengths of
    its segments, from the sensor's time origin (as ``transient_path``: where
    the light reaches the sensor, the centre of projection of a perspective
    camera; the camera ray, which Mitsuba starts at ``ray.o`` on the near-clip
    plane, is followed back to it) through every real
    scattering vertex (null-scattering events do not bend the path: their
    segments add up to the distance along the ray) to the emitter: the hit
    point for an emitter hit, the sampled emitter point for next-event
    estimation. Each segment counts ``n d`` with ``n`` the relative index of
    the dielectric it is in (tracked through refractions, see
    :mod:`transient_mi.integrators._optical_path`); Mitsuba media carry no
    index of their own. Shadow rays only weight a contribution (transmittance);
    their length is the distance to the sampled emitter point.

    NLOS captures: under a ``spad_array`` it renders the capture with the NLOS
    estimator of ``transient_nlos_path`` (laser-spot connections, hidden-geometry
    MIS at the wall point, randomised QMC, spot groups; same parameters).
    Without a sensor medium that is ``transient_nlos_path`` itself (same seed,
    same bytes); with a ``homogeneous`` sensor medium (``<ref id="fog"/>``
    nested in the ``spad_array``: the fog fills the scene) it renders through
    the fog: free flights on every traced segment, phase sampling, and
    next-event estimation from every vertex to the laser spot and to the laser
    *beam* (whose single backscatter into the pixels is the main fog return),
    every segment attenuated (estimator: :mod:`transient_mi.integrators._nlos_medium`;
    ``scenes/fog_nlos.xml``). Refused in one line for NLOS: heterogeneous
    media, media inside shapes, ``include_first_last=false``.

    .. list-table::
       :header-rows: 1

       * - Parameter
         - Type
         - Description
       * - ``max_depth``
         - integer
         - Longest path, in Mitsuba's meaning (``volpath``): 1 = only
           directly visible emitters, 2 = direct illumination (single
           scattering in media), 3 = one more bounce ...; medium scattering
           events count as bounces, null-scattering events and ``null``-BSDF
           boundaries do not; -1 = unlimited (default). NLOS captures:
           segments from the detector to the laser, medium vertices
           included (``D - fog - beam - L`` is 3).
       * - ``rr_depth``
         - integer
         - Depth after which Russian roulette starts (``depth > rr_depth``,
           as ``volpath``), >= 1 (default 5).
       * - ``hide_emitters``
         - boolean
         - Emitters seen directly from the camera contribute nothing
           (default false); they still block the ray, as in ``volpath``.
       * - ``variance_replicates``
         - integer
         - Independent replicates each render is split into, in [1, 1024]
           (default 1: no variance); see ``transient_path``.
       * - ``rqmc``
         - boolean
         - NLOS only: randomised quasi-Monte Carlo for the patch point and
           the first bounce (default true), as ``transient_nlos_path``.
       * - ``hidden_geometry_prob``
         - float
         - NLOS only: probability of hidden-geometry sampling at the wall
           point, in [0, 1] (default 0.8), as ``transient_nlos_path``.

    Determinism: same seed, same bytes (per-lane histograms, see
    :mod:`transient_mi.integrators._lanes`).
    """

    NAME = "transient_volpath"

    def __init__(self, props: mi.Properties):
        mi.CppADIntegrator.__init__(self, props)  # not TransientPath's: it would accept the NLOS options
        max_depth, self.rr_depth, self.variance_replicates = read_path_params(props, self.NAME)
        self.max_depth_param = max_depth
        self.max_depth = max_depth if max_depth != -1 else 0xFFFFFFFF
        self.hide_emitters = get_bool(props, self.NAME, "hide_emitters", False)
        #: NLOS only (``rqmc``, ``hidden_geometry_prob``), as ``transient_nlos_path``
        self.nlos_options = read_nlos_options(props, self.NAME)
        self._sensor_medium = None
        #: whether the scene has a heterogeneous medium: without one, the kernels leave out null
        #: scattering and ratio tracking (a static choice, as Mitsuba's prbvolpath makes it)
        self._heterogeneous = True

    def render_transient(self, scene, sensor, **kwargs):
        """As :meth:`TransientPath.render_transient`; the sensor's medium (``sensor.get_medium()``) is the
        medium the camera rays start in. A ``spad_array`` sensor renders the NLOS capture through its medium
        (:mod:`transient_mi.integrators._nlos_medium`; without one, ``transient_nlos_path``'s bytes)."""
        if is_nlos_sensor(sensor):
            _, spp = check_render_call(self.NAME, sensor, kwargs.get("seed", 0), kwargs.get("spp", 0),
                                       kwargs.get("replicates"))
            kwargs["spp"] = spp
            kwargs.setdefault("seed", 0)
            return render_nlos(self, scene, sensor, media=True, **kwargs)
        self._sensor_medium = sensor.get_medium()
        self._heterogeneous = _has_heterogeneous_medium(scene, self._sensor_medium)
        try:
            return super().render_transient(scene, sensor, **kwargs)
        finally:
            self._sensor_medium = None

    def render_backward(self, scene, params, grad_in, sensor=0, seed=0, spp=0):
        """Reverse-mode derivative through media (camera views): see
        :mod:`transient_mi.integrators._ad_volpath` for what is differentiated and what is refused."""
        from transient_mi.integrators._ad_volpath import render_backward

        sensor = self._ad_sensor(scene, sensor, params)
        try:
            render_backward(self, scene, params, grad_in, sensor, as_int(seed), as_int(spp))
        finally:
            self._sensor_medium = None

    def render_forward(self, scene, params, sensor=0, seed=0, spp=0):
        """Forward-mode derivative of the histograms through media (``dr.forward``)."""
        from transient_mi.integrators._ad_volpath import render_forward

        sensor = self._ad_sensor(scene, sensor, params)
        try:
            return render_forward(self, scene, params, sensor, as_int(seed), as_int(spp))
        finally:
            self._sensor_medium = None

    def _ad_sensor(self, scene, sensor, params):
        from transient_mi.integrators._ad_volpath import check_volpath_ad

        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        check_volpath_ad(self, sensor, params)
        self._sensor_medium = sensor.get_medium()
        self._heterogeneous = _has_heterogeneous_medium(scene, self._sensor_medium)
        return sensor

    # ------------------------------------------------------------ tracing

    @dr.syntax
    def _trace(self, scene, rng, hist, lane, ray, throughput, origin):
        """Trace one volumetric path per lane and record every contribution at its path length.

        ``origin`` (per lane): where the light reaches the sensor (see
        :mod:`transient_mi.integrators._time_origin`); the first segment is timed from there, through
        ``ray.o`` (where Mitsuba starts camera rays and the medium free flights) along the ray.
        """
        ctx = mi.BSDFContext()
        phase_ctx = mi.PhaseFunctionContext()
        wavelengths = ray.wavelengths
        ray = mi.Ray3f(ray)
        beta = mi.Spectrum(throughput)
        eta = mi.Float(1)
        depth = mi.UInt32(0)
        active = mi.Bool(True)
        opl = dr.norm(ray.o - origin)  # optical path (m) from the time origin to the current vertex
        channels, rotation = self._channel_setup(ray)
        medium = mi.MediumPtr(self._sensor_medium) if self._sensor_medium is not None else dr.zeros(mi.MediumPtr)
        si = dr.zeros(mi.SurfaceInteraction3f)
        needs_intersection = mi.Bool(True)
        last_event = dr.zeros(mi.Interaction3f)
        last_pdf = mi.Float(1)
        specular_chain = mi.Bool(True)
        if mi.is_rgb:
            channel = mi.UInt32(dr.minimum(3 * rng.next_float32(), 2))
        else:
            channel = mi.UInt32(0)
        max_depth = self.max_depth
        rr_depth = self.rr_depth
        hide_emitters = self.hide_emitters
        heterogeneous = self._heterogeneous

        while active:
            # ---- Russian roulette (as volpath)
            bmax = dr.max(mi.unpolarized_spectrum(beta))
            active &= bmax != 0
            q = dr.minimum(bmax * dr.square(eta), 0.95)
            perform_rr = depth > rr_depth
            active &= (rng.next_float32() < q) | ~perform_rr
            beta[perform_rr] *= dr.rcp(q)

            active_medium = active & (medium != None)  # noqa: E711
            active_surface = active & ~active_medium

            # ---- free-flight sampling (tentative collision; one intersection per step for all lanes)
            mei = medium.sample_interaction(ray, rng.next_float32(), channel, active_medium)
            ray.maxt[active_medium & medium.is_homogeneous() & mei.is_valid()] = mei.t
            intersect = needs_intersection & active
            si[intersect] = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=False, active=intersect)
            needs_intersection &= ~active
            mei.t[active_medium & (si.t < mei.t)] = dr.inf

            # throughput / free-flight pdf: 1 at an escape, 1/sigma_t at a collision, unless the
            # extinction varies with the channel (RGB): then the ratio in the sampled channel (as volpath)
            spectral = active_medium & medium.has_spectral_extinction()
            tr, ff_pdf = medium.transmittance_eval_pdf(mei, si, spectral)
            tr_pdf = index_spectrum(ff_pdf, channel)
            beta[spectral] *= dr.select(tr_pdf > 0, tr / tr_pdf, 0)

            escaped = active_medium & ~mei.is_valid()
            active_medium &= mei.is_valid()
            spectral &= active_medium
            opl[active_medium] += eta * mei.t  # a segment in a dielectric of relative index eta takes eta d / c

            # null or real scattering: real with probability sigma_t / majorant (in the sampled channel);
            # homogeneous media have no null collisions (majorant = sigma_t)
            sig_t_c = index_spectrum(mei.sigma_t, channel)
            comb_c = index_spectrum(mei.combined_extinction, channel)
            null_scatter = mi.Bool(False)
            if dr.hint(heterogeneous, mode="scalar"):
                null_scatter = active_medium & (rng.next_float32() >= sig_t_c / comb_c)
                sig_n_c = index_spectrum(mei.sigma_n, channel)
                beta[spectral & null_scatter] *= dr.select(sig_n_c > 0, mei.sigma_n * comb_c / sig_n_c, 0)
            real_scatter = active_medium & ~null_scatter
            depth[real_scatter] += 1
            last_event[real_scatter] = mei
            active &= depth < max_depth
            real_scatter &= active
            if dr.hint(heterogeneous, mode="scalar"):
                ray.o[null_scatter] = mei.p
                si.t[null_scatter] = si.t - mei.t
            beta[spectral & real_scatter] *= dr.select(sig_t_c > 0, mei.sigma_s * comb_c / sig_t_c, 0)
            beta[~spectral & real_scatter] *= mei.sigma_s / mei.sigma_t
            phase = mei.medium.phase_function()
            sample_emitters = mei.medium.use_emitter_sampling()
            specular_chain &= ~real_scatter
            specular_chain |= real_scatter & ~sample_emitters

            # ---- emitter hits (no medium, or the ray left the medium)
            active_surface |= escaped
            opl[active_surface] += eta * si.t
            emitter = si.emitter(scene)
            active_e = active_surface & (emitter != None) & ~((depth == 0) & hide_emitters)  # noqa: E711
            count_direct = (depth == 0) | specular_chain
            ds_hit = mi.DirectionSample3f(scene, si, last_event)
            em_pdf = scene.pdf_emitter_direction(last_event, ds_hit, active_e & ~count_direct)
            Le = beta * emitter.eval(si, active_e) * dr.select(count_direct, 1, mis_weight(last_pdf, em_pdf))
            hist.record(lane, opl, channel_values(Le, wavelengths, channels, rotation), active_e)

            # ---- next-event estimation from the medium vertex or the surface
            active_surface &= si.is_valid()
            bsdf = si.bsdf(ray)
            nee_surface = active_surface & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth) & (depth + 1 < max_depth)
            nee_medium = real_scatter & sample_emitters
            em_val, ds = self._sample_emitter(scene, rng, mei, si, medium, channel, nee_medium, nee_surface)
            bsdf_val, bsdf_pdf = bsdf.eval_pdf(ctx, si, si.to_local(ds.d), nee_surface)
            ph_val, ph_pdf = phase.eval_pdf(phase_ctx, mei, ds.d, nee_medium)
            f_val = dr.select(nee_surface, bsdf_val, ph_val)
            f_pdf = dr.select(ds.delta, 0, dr.select(nee_surface, bsdf_pdf, ph_pdf))
            L_nee = beta * f_val * em_val * mis_weight(ds.pdf, f_pdf)
            n_nee = dr.select(nee_surface, segment_index(bsdf, si, si.to_local(ds.d), eta, nee_surface), eta)
            hist.record(lane, opl + n_nee * ds.dist, channel_values(L_nee, wavelengths, channels, rotation),
                        nee_surface | nee_medium)

            # ---- phase-function sampling
            wo, ph_weight, ph_pdf = phase.sample(phase_ctx, mei, rng.next_float32(),
                                                 mi.Point2f(rng.next_float32(), rng.next_float32()),
                                                 real_scatter)
            real_scatter &= ph_pdf > 0
            ray[real_scatter] = mei.spawn_ray(wo)
            needs_intersection |= real_scatter
            last_pdf[real_scatter] = ph_pdf
            beta[real_scatter] *= ph_weight

            # ---- BSDF sampling
            bs, bsdf_weight = bsdf.sample(ctx, si, rng.next_float32(),
                                          mi.Point2f(rng.next_float32(), rng.next_float32()), active_surface)
            active_surface &= bs.pdf > 0
            beta[active_surface] *= bsdf_weight
            eta[active_surface] *= bs.eta
            ray[active_surface] = si.spawn_ray(si.to_world(bs.wo))
            needs_intersection |= active_surface
            non_null = active_surface & ~mi.has_flag(bs.sampled_type, mi.BSDFFlags.Null)
            depth[non_null] += 1
            last_event[non_null] = si
            last_pdf[non_null] = bs.pdf
            specular_chain |= non_null & mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
            specular_chain &= ~(active_surface & mi.has_flag(bs.sampled_type, mi.BSDFFlags.Smooth))
            transition = active_surface & si.is_medium_transition()
            medium[transition] = si.target_medium(ray.d)
            active &= active_surface | active_medium

    @dr.syntax
    def _sample_emitter(self, scene, rng, mei, si, medium, channel, from_medium, from_surface):
        """Next-event estimation from a medium vertex (``from_medium``) or a surface (``from_surface``).

        Returns ``(emitter value * transmittance of the shadow ray, DirectionSample3f)``; the
        transmittance is the closed form through homogeneous media and ratio tracking through
        heterogeneous ones, crossing ``null``-BSDF boundaries (other surfaces block).
        """
        active = from_medium | from_surface
        ref = dr.zeros(mi.Interaction3f)
        ref[from_medium] = mei
        ref[from_surface] = si
        ds, em_val = scene.sample_emitter_direction(ref, mi.Point2f(rng.next_float32(), rng.next_float32()),
                                                    False, active)
        invalid = ds.pdf == 0
        em_val[invalid] = 0
        active &= ~invalid
        medium = dr.select(active, medium, dr.zeros(mi.MediumPtr))
        medium[from_surface & si.is_medium_transition()] = si.target_medium(ds.d)
        ray = ref.spawn_ray_to(ds.p)
        max_dist = mi.Float(ray.maxt)
        total = mi.Float(0)
        si_s = dr.zeros(mi.SurfaceInteraction3f)
        needs_intersection = mi.Bool(True)
        tr = mi.Spectrum(1)
        heterogeneous = self._heterogeneous

        while active:
            remaining = max_dist - total
            ray.maxt = remaining
            active &= remaining > 0
            needs_intersection &= active
            si_s[needs_intersection] = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=False,
                                                           active=needs_intersection)
            needs_intersection &= False
            in_medium = active & (medium != None)  # noqa: E711
            on_surface = active & ~in_medium
            homog = in_medium & medium.is_homogeneous()
            ratio = in_medium & ~homog

            # homogeneous: closed-form transmittance to the next surface or the end of the segment
            end = dr.minimum(remaining, si_s.t)
            m_h = dr.zeros(mi.MediumInteraction3f)
            m_h.t = end
            m_h.p = ray(end)
            m_h.medium = medium
            _, _, sig_t = medium.get_scattering_coefficients(m_h, homog)
            tr[homog] *= dr.exp(-end * sig_t)

            # heterogeneous: ratio tracking with the majorant of the sampled channel
            collided = mi.Bool(False)
            if dr.hint(heterogeneous, mode="scalar"):
                m = medium.sample_interaction(ray, rng.next_float32(), channel, ratio)
                m.t[ratio & ((si_s.t < m.t) | (m.t > remaining))] = dr.inf
                t_in = dr.minimum(remaining, dr.minimum(m.t, si_s.t)) - m.mint
                trm = dr.exp(-t_in * m.combined_extinction)
                ffp = dr.select(m.is_valid(), trm * m.combined_extinction, trm)
                ffp_c = index_spectrum(ffp, channel)
                spectral = ratio & medium.has_spectral_extinction()  # else trm / ffp_c is 1 or 1/majorant
                tr[spectral] *= dr.select(ffp_c > 0, trm / ffp_c, 0)
                tr[ratio & ~spectral & m.is_valid()] *= dr.rcp(m.combined_extinction)
                collided = ratio & m.is_valid()
                tr[collided] *= m.sigma_n
                ray.o[collided] = m.p
                si_s.t[collided] = si_s.t - m.t
                total[collided] += m.t

            # reached the next surface (or the end of the segment)
            crossed = (on_surface | (in_medium & ~collided)) & si_s.is_valid() & (si_s.t < remaining)
            bsdf = si_s.bsdf(ray)
            tr[crossed] *= bsdf.eval_null_transmission(si_s, crossed)
            total[crossed] += si_s.t
            ray[crossed] = si_s.spawn_ray(mi.Vector3f(ray.d))
            needs_intersection |= crossed
            medium[crossed & si_s.is_medium_transition()] = si_s.target_medium(ray.d)
            active &= (collided | crossed) & dr.any(mi.unpolarized_spectrum(tr) != 0)

        return em_val * tr, ds

    def to_string(self):
        o = self.nlos_options
        return (f"TransientVolPath[max_depth={self.max_depth_param}, rr_depth={self.rr_depth}, "
                f"hide_emitters={str(self.hide_emitters).lower()}, "
                f"variance_replicates={self.variance_replicates or 'default'}, "
                f"hidden_geometry_prob={o['hidden_geometry_prob']:g}, rqmc={str(o['rqmc']).lower()}"
                f"{estimator_suffix(o)}]")
