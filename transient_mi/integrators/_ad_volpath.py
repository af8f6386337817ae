"""Differentiable ``transient_volpath`` (camera views): reverse and forward mode through participating media.

The scheme of :mod:`transient_mi.integrators._ad` (path-replay backpropagation with one adjoint per time
bin: a first replay sums ``A = sum_j delta[p, b_j] c_j`` over a path's contributions, the second replays the
same random numbers and back-propagates; forward mode carries the derivative ``S`` of the path's
log-throughput), applied to the estimator of ``transient_volpath`` (same sampling, same random numbers, so
the replay follows the primal's paths). Sampling is detached (free-flight distances, null/real choices,
phase and BSDF directions, emitter samples); at each step the replay re-evaluates, with gradients attached
and at the detached sample, the factors the path's weight is proportional to, as Mitsuba's ``prbvolpath``:

* a free-flight segment of length ``t`` (to a collision or to the next surface): ``exp(-t mu)`` with
  ``mu`` the majorant (``sigma_t`` in a homogeneous medium): ``d log = -t d mu``;
* a real collision: ``sigma_s`` (``albedo * sigma_t``); a null collision (heterogeneous media):
  ``sigma_n = mu - sigma_t``; the sampling probabilities (``sigma_t / mu``, the free-flight pdf) are
  detached, which keeps the estimator unbiased;
* the sampled direction's phase-function value (e.g. ``hg``'s ``g``) or BSDF value;
* the emitted radiance at an emitter hit, and at next-event estimation the emitter's value, the phase or
  BSDF value of the light's direction and the shadow ray's transmittance, whose factors (closed form
  ``exp(-d sigma_t)`` in homogeneous media, ``exp(-t mu) sigma_n`` per ratio-tracking step, a ``null``
  boundary's transmission) are back-propagated by a second run of the shadow-ray loop with the same random
  numbers, with the adjoint of that contribution (Mitsuba's ``prbvolpath`` does the same).

Each segment factor multiplies the contributions of its own step and all later ones; a direction's value
only the later ones. Not differentiated (refused in one line by
:meth:`TransientVolPath.render_backward`): shape geometry, a medium's extent, NLOS captures, spectral and
polarized variants, a ``channels="mono"`` film in RGB variants. Time bins: a path length is detached (no
parameter here moves a vertex).
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from transient_mi.integrators import _ad
from transient_mi.integrators._ad import _values
from transient_mi.integrators._ad_geometry import geometry_keys
from transient_mi.integrators._media import index_spectrum as _index
from transient_mi.integrators._mis import detached_mis_weight as _mis
from transient_mi.integrators._optical_path import segment_index
from transient_mi.props import PluginParameterError


def check_volpath_ad(integrator, sensor, params) -> None:
    """Refuse, in one line, what the volumetric replay does not differentiate."""
    name = integrator.NAME
    if hasattr(sensor, "nlos_setup"):
        raise PluginParameterError(f"{name}: differentiable rendering of NLOS captures (spad_array) through media "
                                   "is not supported; use transient_nlos_path without media")
    keys = geometry_keys(params)
    if keys:
        raise PluginParameterError(f"{name}: {keys[0]} is differentiated; derivatives with respect to geometry "
                                   "are not supported in media (transient_path differentiates geometry)")
    if not (mi.is_monochromatic or mi.is_rgb) or mi.is_polarized:
        raise PluginParameterError(f"{name}: differentiable rendering supports *_mono and *_rgb variants, "
                                   f"not {mi.variant()}")
    film = sensor.film()
    if mi.is_rgb and hasattr(film, "channel_names") and film.channel_names() is None:
        raise PluginParameterError(f"{name}: differentiable rendering in {mi.variant()} needs the film's RGB "
                                   "channels, not channels='mono'")


def _ratio(att, ok):
    """``att / detach(att)`` (a Spectrum of value 1 carrying ``d log att``; 1 where not ``ok`` or 0)."""
    d = dr.detach(att)
    return dr.select(ok & (d > 0), att / dr.select(d > 0, d, 1), 1)


def _tr_ratio(mu, t, ok):
    """The ratio of an attached ``exp(-t mu)`` (``mu`` attached) to its value: ``d log = -t d mu`` (1 where
    ``t`` is not finite or not ``ok``)."""
    fin = ok & dr.isfinite(t)
    return dr.select(fin, dr.exp(-dr.select(fin, t, 0) * (mu - dr.detach(mu))), 1)


def _per_channel(spec, n: int) -> list:
    """A Spectrum's components for ``n`` recorded channels (mono: 1; rgb films: R, G, B)."""
    s = mi.unpolarized_spectrum(spec)
    return [s[c] for c in range(n)]


# ------------------------------------------------------------------ next-event transmittance


@dr.syntax
def _shadow_tr(integrator, scene, rng, ref, si, ds, medium, channel, from_surface, active, mode: str, adjoint,
               n: int):
    """Transmittance of the shadow ray to ``ds.p`` (the primal's ratio tracking, same random numbers).

    Returns ``(tr, score)``. ``mode``: ``primal`` (``score`` zeros); ``backward`` also back-propagates
    ``sum_c adjoint[c] d log tr_c`` at each step (``adjoint``: the contribution's adjoint, per channel);
    ``forward``: ``score`` is ``[d log tr_c]`` (the tangent, per channel)."""
    active = mi.Bool(active)  # (a copy: the loop narrows it)
    medium = dr.select(active, medium, dr.zeros(mi.MediumPtr))
    medium[from_surface & si.is_medium_transition()] = si.target_medium(ds.d)
    ray = ref.spawn_ray_to(ds.p)
    max_dist = mi.Float(ray.maxt)
    total = mi.Float(0)
    si_s = dr.zeros(mi.SurfaceInteraction3f)
    needs_intersection = mi.Bool(True)
    tr = mi.Spectrum(1)
    score = [mi.Float(0) for _ in range(n)]
    heterogeneous = integrator._heterogeneous
    grads = mode != "primal"

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

        end = dr.minimum(remaining, si_s.t)
        m_h = dr.zeros(mi.MediumInteraction3f)
        m_h.t = end
        m_h.p = ray(end)
        m_h.medium = medium
        with dr.resume_grad(when=grads):
            _, _, sig_t_a = medium.get_scattering_coefficients(m_h, homog)
            mult = _tr_ratio(sig_t_a, end, homog)
        tr[homog] *= dr.exp(-end * dr.detach(sig_t_a))

        collided = mi.Bool(False)
        if dr.hint(heterogeneous, mode="scalar"):
            m = medium.sample_interaction(ray, rng.next_float32(), channel, ratio)
            m.t[ratio & ((si_s.t < m.t) | (m.t > remaining))] = dr.inf
            t_in = dr.minimum(remaining, dr.minimum(m.t, si_s.t)) - m.mint
            trm = dr.exp(-t_in * m.combined_extinction)
            ffp = dr.select(m.is_valid(), trm * m.combined_extinction, trm)
            ffp_c = _index(ffp, channel)
            spectral = ratio & medium.has_spectral_extinction()
            tr[spectral] *= dr.select(ffp_c > 0, trm / ffp_c, 0)
            tr[ratio & ~spectral & m.is_valid()] *= dr.rcp(m.combined_extinction)
            collided = ratio & m.is_valid()
            tr[collided] *= m.sigma_n
            with dr.resume_grad(when=grads):
                mu_a = medium.get_majorant(m, ratio)
                _, sig_n_a, _ = medium.get_scattering_coefficients(m, collided)
                mult = mult * _tr_ratio(mu_a, t_in, ratio) * _ratio(sig_n_a, collided)
            ray.o[collided] = m.p
            si_s.t[collided] = si_s.t - m.t
            total[collided] += m.t

        crossed = (on_surface | (in_medium & ~collided)) & si_s.is_valid() & (si_s.t < remaining)
        bsdf = si_s.bsdf(ray)
        null_tr = bsdf.eval_null_transmission(si_s, crossed)
        tr[crossed] *= null_tr
        with dr.resume_grad(when=grads):
            null_a = bsdf.eval_null_transmission(si_s, crossed)
            r = _per_channel(mult * _ratio(null_a, crossed), n)
            if dr.hint(mode == "backward", mode="scalar"):
                dr.backward_from(sum((adjoint[c] * r[c] for c in range(n)), mi.Float(0)),
                                 flags=dr.ADFlag.Default | dr.ADFlag.AllowNoGrad)
            elif dr.hint(mode == "forward", mode="scalar"):
                g = dr.forward_to(*r, flags=dr.ADFlag.Default | dr.ADFlag.AllowNoGrad)
                g = list(g) if isinstance(g, (list, tuple)) else [g]
                score = [score[c] + dr.select(active, dr.detach(g[c]), 0) for c in range(n)]
        total[crossed] += si_s.t
        ray[crossed] = si_s.spawn_ray(mi.Vector3f(ray.d))
        needs_intersection |= crossed
        medium[crossed & si_s.is_medium_transition()] = si_s.target_medium(ray.d)
        active &= (collided | crossed) & dr.any(mi.unpolarized_spectrum(tr) != 0)
    return tr, score


# ------------------------------------------------------------------ the replay


def _step(adj, mode, lane, acc, score, opl, le, act_le, opl_em, lr, act_em, seg, dirr, nee_score, hist, scale):
    """One step's bookkeeping. ``seg``: the segment's ratios (this step's terms and all later ones);
    ``dirr``: the sampled direction's ratios (later terms only); per channel lists.

    ``weight``: ``acc += delta . c``; ``backward``: back-propagates this step and returns the adjoint of
    the rest (``acc`` is ``A`` still to come, this step included); ``forward``: records ``d c`` and updates
    ``score``."""
    n = len(acc)
    if mode == "weight":
        w_le = adj.weights(lane, opl, le, act_le)
        w_lr = adj.weights(lane, opl_em, lr, act_em)
        return [a + dr.detach(w_le[c] + w_lr[c]) for c, a in enumerate(acc)], score, None
    if mode == "backward":
        w_le = adj.weights(lane, opl, le, act_le)
        w_lr = adj.weights(lane, opl_em, lr, act_em)
        rest = [a - dr.detach(w_le[c] + w_lr[c]) for c, a in enumerate(acc)]
        obj = mi.Float(0)
        for c in range(n):
            obj += (acc[c] * dr.replace_grad(mi.Float(1), seg[c]) + w_le[c] + w_lr[c]
                    + rest[c] * dr.replace_grad(mi.Float(1), dirr[c]))
        dr.backward_from(scale * obj, flags=dr.ADFlag.Default | dr.ADFlag.AllowNoGrad)
        return rest, score, [scale * dr.detach(w) for w in w_lr]
    grads = dr.forward_to(*le, *lr, *seg, *dirr, flags=dr.ADFlag.Default | dr.ADFlag.AllowNoGrad)
    grads = list(grads) if isinstance(grads, (list, tuple)) else [grads]
    mid = [score[c] + dr.detach(grads[2 * n + c]) for c in range(n)]
    out_le = [dr.detach(grads[c]) + dr.detach(le[c]) * mid[c] for c in range(n)]
    out_lr = [dr.detach(grads[n + c]) + dr.detach(lr[c]) * (mid[c] + nee_score[c]) for c in range(n)]
    mono = n == 1 and not mi.is_rgb
    hist.record(lane, opl, out_le[0] if mono else out_le, act_le)
    hist.record(lane, opl_em, out_lr[0] if mono else out_lr, act_em)
    return acc, [mid[c] + dr.detach(grads[3 * n + c]) for c in range(n)], None


@dr.syntax
def _replay(integrator, scene, rng, lane, ray, throughput, origin, adj, mode: str, extra, scale: float):
    """One path of ``transient_volpath``'s ``_trace`` (same sampling, same random numbers), in one of three
    modes: ``weight`` returns ``A_c = sum_j delta[b_j, c] c_{j,c}`` (a list per channel); ``backward``
    (``extra`` that list) back-propagates; ``forward`` (``extra`` the derivative histogram) records
    ``d c_j``."""
    ctx = mi.BSDFContext()
    phase_ctx = mi.PhaseFunctionContext()
    wavelengths = ray.wavelengths
    channels, rotation = integrator._channel_setup(ray)
    ray = mi.Ray3f(dr.detach(ray))
    beta = mi.Spectrum(dr.detach(throughput))
    eta = mi.Float(1)
    depth = mi.UInt32(0)
    active = mi.Bool(True)
    opl = dr.norm(ray.o - origin)
    sm = integrator._sensor_medium
    medium = mi.MediumPtr(sm) if sm is not None else dr.zeros(mi.MediumPtr)
    si = dr.zeros(mi.SurfaceInteraction3f)
    needs_intersection = mi.Bool(True)
    last_event = dr.zeros(mi.Interaction3f)
    last_pdf = mi.Float(1)
    specular_chain = mi.Bool(True)
    if mi.is_rgb:
        channel = mi.UInt32(dr.minimum(3 * rng.next_float32(), 2))
    else:
        channel = mi.UInt32(0)
    n = 1 if channels is None else len(channels)
    acc = [mi.Float(0) for _ in range(n)]
    if dr.hint(mode == "backward", mode="scalar"):
        acc = [mi.Float(a) for a in extra]
    score = [mi.Float(0) for _ in range(n)]
    max_depth = integrator.max_depth
    rr_depth = integrator.rr_depth
    hide_emitters = integrator.hide_emitters
    heterogeneous = integrator._heterogeneous
    grads = mode != "weight"

    while active:
        bmax = dr.max(mi.unpolarized_spectrum(beta))
        active &= bmax != 0
        q = dr.minimum(bmax * dr.square(eta), 0.95)
        perform_rr = depth > rr_depth
        active &= (rng.next_float32() < q) | ~perform_rr
        beta[perform_rr] *= dr.rcp(q)

        active_medium = active & (medium != None)  # noqa: E711
        active_surface = active & ~active_medium

        # ---- free flight (detached sampling), then the attached segment and collision factors
        mei = medium.sample_interaction(ray, rng.next_float32(), channel, active_medium)
        ray.maxt[active_medium & medium.is_homogeneous() & mei.is_valid()] = mei.t
        intersect = needs_intersection & active
        si[intersect] = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=False, active=intersect)
        needs_intersection &= ~active
        mei.t[active_medium & (si.t < mei.t)] = dr.inf
        in_segment = mi.Bool(active_medium)
        t_seg = dr.minimum(mei.t, si.t) - mei.mint

        spectral = active_medium & medium.has_spectral_extinction()
        tr, ff_pdf = medium.transmittance_eval_pdf(mei, si, spectral)
        tr_pdf = _index(ff_pdf, channel)
        beta[spectral] *= dr.select(tr_pdf > 0, tr / tr_pdf, 0)

        escaped = active_medium & ~mei.is_valid()
        active_medium &= mei.is_valid()
        spectral &= active_medium
        opl[active_medium] += eta * mei.t

        sig_t_c = _index(mei.sigma_t, channel)
        comb_c = _index(mei.combined_extinction, channel)
        null_scatter = mi.Bool(False)
        if dr.hint(heterogeneous, mode="scalar"):
            null_scatter = active_medium & (rng.next_float32() >= sig_t_c / comb_c)
            sig_n_c = _index(mei.sigma_n, channel)
            beta[spectral & null_scatter] *= dr.select(sig_n_c > 0, mei.sigma_n * comb_c / sig_n_c, 0)
        real_scatter = active_medium & ~null_scatter
        depth[real_scatter] += 1
        last_event[real_scatter] = mei
        active &= depth < max_depth
        real_scatter &= active
        real_coll = mi.Bool(real_scatter)
        if dr.hint(heterogeneous, mode="scalar"):
            ray.o[null_scatter] = mei.p
            si.t[null_scatter] = si.t - mei.t
        beta[spectral & real_scatter] *= dr.select(sig_t_c > 0, mei.sigma_s * comb_c / sig_t_c, 0)
        beta[~spectral & real_scatter] *= mei.sigma_s / mei.sigma_t
        phase = mei.medium.phase_function()
        sample_emitters = mei.medium.use_emitter_sampling()
        specular_chain &= ~real_scatter
        specular_chain |= real_scatter & ~sample_emitters

        # ---- emitter hits
        active_surface |= escaped
        opl[active_surface] += eta * si.t
        emitter = si.emitter(scene)
        active_e = active_surface & (emitter != None) & ~((depth == 0) & hide_emitters)  # noqa: E711
        count_direct = (depth == 0) | specular_chain
        ds_hit = mi.DirectionSample3f(scene, si, last_event)
        em_pdf = scene.pdf_emitter_direction(last_event, ds_hit, active_e & ~count_direct)
        mis_hit = dr.select(count_direct, 1, _mis(last_pdf, em_pdf))

        # ---- next-event estimation (the shadow ray's factors: forward mode here, reverse mode below)
        active_surface &= si.is_valid()
        bsdf = si.bsdf(ray)
        nee_surface = active_surface & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth) & (depth + 1 < max_depth)
        nee_medium = real_scatter & sample_emitters
        nee = nee_medium | nee_surface
        ref = dr.zeros(mi.Interaction3f)
        ref[nee_medium] = mei
        ref[nee_surface] = si
        u_em = mi.Point2f(rng.next_float32(), rng.next_float32())
        ds, _ = scene.sample_emitter_direction(ref, u_em, False, nee)
        nee &= ds.pdf != 0
        nee_rng = mi.PCG32(rng)
        # (before any attached value of this step: forward mode cannot cross into the shadow loop's scope)
        tr_nee, nee_score = _shadow_tr(integrator, scene, rng, ref, si, ds, medium, channel, nee_surface, nee,
                                       "forward" if mode == "forward" else "primal", None, n)
        wo_nee = si.to_local(ds.d)
        n_nee = dr.select(nee_surface, segment_index(bsdf, si, wo_nee, eta, nee_surface), eta)
        opl_nee = opl + n_nee * ds.dist

        # ---- phase-function and BSDF sampling (detached)
        wo, ph_weight, ph_pdf_s = phase.sample(phase_ctx, mei, rng.next_float32(),
                                               mi.Point2f(rng.next_float32(), rng.next_float32()), real_scatter)
        real_scatter &= ph_pdf_s > 0
        bs, bsdf_weight = bsdf.sample(ctx, si, rng.next_float32(),
                                      mi.Point2f(rng.next_float32(), rng.next_float32()), active_surface)
        smooth = active_surface & (bs.pdf > 0) & ~mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)

        # ---- the attached factors of this step, and the adjoint / tangent bookkeeping
        with dr.resume_grad(when=grads):
            mu_a = medium.get_majorant(mei, in_segment)
            sig_s_a, sig_n_a, _ = medium.get_scattering_coefficients(mei, real_coll | null_scatter)
            seg = _tr_ratio(mu_a, t_seg, in_segment) * _ratio(sig_s_a, real_coll) * _ratio(sig_n_a, null_scatter)
            seg_v = _per_channel(seg, n)
            Le = beta * emitter.eval(si, active_e) * mis_hit
            Le_v = _values(Le, wavelengths, channels, rotation)
            _, em_val = scene.sample_emitter_direction(ref, u_em, False, nee)  # attached emitter value
            bsdf_val, bsdf_pdf = bsdf.eval_pdf(ctx, si, wo_nee, nee_surface)
            ph_val, ph_pdf = phase.eval_pdf(phase_ctx, mei, ds.d, nee_medium)
            f_val = dr.select(nee_surface, bsdf_val, ph_val)
            f_pdf = dr.select(ds.delta, 0, dr.select(nee_surface, dr.detach(bsdf_pdf), dr.detach(ph_pdf)))
            L_nee = dr.select(nee, beta * f_val * em_val * dr.detach(tr_nee) * _mis(ds.pdf, f_pdf), 0)
            L_nee_v = _values(L_nee, wavelengths, channels, rotation)
            ph_a, _ = phase.eval_pdf(phase_ctx, mei, wo, real_scatter)
            f_a = bsdf.eval(ctx, si, bs.wo, smooth)
            dirr = _ratio(mi.Spectrum(ph_a), real_scatter) * _ratio(f_a, smooth)
            dirr_v = _per_channel(dirr, n)
            acc, score, w_nee = _step(adj, mode, lane, acc, score, opl, Le_v, active_e, opl_nee, L_nee_v, nee,
                                      seg_v, dirr_v, nee_score, extra, scale)
        if dr.hint(mode == "backward", mode="scalar"):
            _shadow_tr(integrator, scene, nee_rng, ref, si, ds, medium, channel, nee_surface, nee, "backward",
                       w_nee, n)

        ray[real_scatter] = mei.spawn_ray(wo)
        needs_intersection |= real_scatter
        last_pdf[real_scatter] = ph_pdf_s
        beta[real_scatter] *= ph_weight

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
    return acc


# ------------------------------------------------------------------ entry points


def render_backward(integrator, scene, params, grad_in, sensor, seed, spp) -> None:
    """Reverse mode: propagate ``grad_in`` (the adjoint of the histogram tensor) to the scene parameters
    (:func:`transient_mi.integrators._ad.render_backward` with this module's replay, detached sampling)."""
    _ad.render_backward(integrator, scene, params, grad_in, sensor, seed, spp, replay=_replay, detached=True)


def render_forward(integrator, scene, params, sensor, seed, spp) -> mi.TensorXf:
    """Forward mode: the derivative of the histogram tensor along the parameters' tangents."""
    return _ad.render_forward(integrator, scene, params, sensor, seed, spp, replay=_replay, detached=True)
