"""Differentiable transient rendering of camera views: Mitsuba's AD interfaces for ``transient_path``.

``mi.render(scene, params, ...)`` followed by ``dr.backward`` (reverse mode) or ``dr.forward`` (forward
mode) calls :meth:`TransientPath.render_backward` / :meth:`TransientPath.render_forward`, implemented
here in the style of Mitsuba's path-replay backpropagation (PRB, Vicini et al. 2021; Mitsuba's
``prb.py``): sampling is detached; along a replayed path the BSDF values of the sampled directions, the
emitted radiance and the next-event terms are evaluated again with gradients attached, and each vertex
propagates its share of the adjoint immediately, so memory does not grow with path length.

Transient twist
---------------
A path's contributions land in different time bins, each with its own adjoint ``delta[pixel, bin]``
(the incoming gradient of the histogram). PRB's "radiance still to come" becomes the adjoint-weighted
sum ``A = sum_j delta[p, b_j] . c_j`` over the path's remaining contributions ``c_j`` (bin ``b_j``): a
first replay of each sample computes ``A``; the second replays the same random numbers and, at each
vertex ``i``, back-propagates ``delta[b_Le] . Le + delta[b_NEE] . L_NEE + A_after_i . f_i / detach(f_i)``
(the last term carries the derivative of the throughput into every later contribution). Forward mode
accumulates the derivative of the path's log-throughput ``S`` (a tangent, per lane) and records
``d c_j = (d c_j at fixed throughput) + c_j S`` into a derivative histogram.

What is differentiated
----------------------
Parameters that enter BSDF values (reflectance, roughness's value at fixed sampled directions),
emitted radiance and the film's temporal kernel (the adjoint is correlated with the kernel taps), and
**shape geometry** (a shape's ``to_world`` and a mesh's ``vertex_positions``, tested; a sphere's
``center`` takes the same code, untested):
:mod:`transient_mi.integrators._ad_geometry` replays the path with every vertex attached to its shape
(the camera vertex along its fixed ray, later vertices ``FollowShape`` in area measure) and
differentiates the arrival time through the film's Gaussian kernel (``kernel_sigma_ps > 0``, refused
otherwise): the interior derivative. Not differentiated: sampling densities and MIS weights (detached,
which keeps the gradient unbiased: the proposal does not need differentiating) and visibility (a moving
shape's silhouette, a shadow edge sweeping over a surface: biased, measured in
``docs/differentiable.md``). NLOS captures (``spad_array`` sensors) are differentiated by
:mod:`transient_mi.integrators._nlos_ad`.

Variants: ``*_mono``, ``*_rgb`` and ``*_spectral`` (geometry: mono and rgb); in spectral variants a path
carries several wavelengths with different BSDF values, so ``A`` and ``S`` are kept per (channel,
wavelength) (:data:`N_WL`, :func:`_values`); polarized variants are refused.

Determinism: forward mode records tangents in per-lane histograms (same seed, same bytes); reverse mode
accumulates each parameter's gradient with Dr.Jit's atomic adds across threads (same seed: equal to float
rounding; the last bits of a gradient can change from run to run with more than one thread, as for an
emitter's ``intensity`` here before geometry was added).
"""

from __future__ import annotations

import contextlib

import drjit as dr
import mitsuba as mi
import numpy as np

from transient_mi._upload import upload, upload_tensor
from transient_mi.integrators._lanes import (ChannelHistogram, LaneHistogram, LaneLayout, as_list,
                                             channel_values, choose_streams, seed_rng)
from transient_mi.integrators._ad_geometry import TimeAdjoint, TimeTangent, check_geometry, replay_geometry
from transient_mi.integrators._mis import detached_mis_weight as _mis
from transient_mi.integrators._optical_path import segment_index
from transient_mi.integrators._pixel_filter import PixelFilter
from transient_mi.integrators._time_origin import TimeOrigin
from transient_mi.props import PluginParameterError


def _check(integrator, sensor):
    if hasattr(sensor, "nlos_setup"):
        raise PluginParameterError(
            f"{integrator.NAME}: this is the camera AD path; NLOS captures (spad_array) are differentiated by "
            "transient_mi.integrators._nlos_ad (see docs/differentiable.md)")
    film = sensor.film()
    if not hasattr(film, "is_transient"):
        raise PluginParameterError(f"{integrator.NAME}: the sensor's film is {type(film).__name__}; use a "
                                   "transient_film")
    if mi.is_polarized:
        raise PluginParameterError(f"{integrator.NAME}: differentiable rendering supports *_mono, *_rgb and "
                                   f"*_spectral variants, not {mi.variant()}")
    if film.channel_names() is None and (mi.is_rgb or mi.is_spectral):  # (the replay's ratios are per colour)
        raise PluginParameterError(f"{integrator.NAME}: differentiable rendering in {mi.variant()} needs the film's "
                                   "colour channels, not channels='mono'")
    if film.channel_names() is not None and not (mi.is_rgb or mi.is_spectral):
        raise PluginParameterError(f"{integrator.NAME}: differentiable rendering of channels "
                                   f"{film.channel_names()} is not supported")
    return film


def _adjoint_ext(grad_in, film, n_ch: int) -> np.ndarray:
    """The incoming gradient ``[H, W, T(, C)]`` as ``[P, T_ext, C]`` float32: correlated with the temporal
    kernel's taps (the adjoint of the film's convolution; the taps are symmetric) over the padded bins."""
    H, W, T = film.height, film.width, film.time_axis().n_bins
    g = np.asarray(grad_in, dtype=np.float64).reshape(H * W, T, n_ch)
    taps = film.kernel_taps()
    pad = len(taps) // 2
    if pad:
        from scipy.ndimage import convolve1d

        g = convolve1d(np.pad(g, ((0, 0), (pad, pad), (0, 0))), taps, axis=1, mode="constant", cval=0.0)
    return np.ascontiguousarray(g, dtype=np.float32)


class _Adjoint:
    """Gathers ``delta[pixel, bin(opl)] . values`` (0 outside the padded range)."""

    def __init__(self, delta: np.ndarray, binner: LaneHistogram, K: int):
        self.P, self.T_ext, self.C = delta.shape
        self.delta = upload(mi.Float, delta)
        self.binner = binner
        self.K = K
        #: spectral variants: the values are per (channel, wavelength), ``N_WL`` wavelengths per channel
        self.per_channel = N_WL

    def weights(self, lane, opl, values, active) -> list:
        """``[delta[pixel, bin(opl), c] * values[c] for c]`` (0 outside the padded range); spectral: ``values``
        per (channel, wavelength), channel ``c = i // N_WL``."""
        valid, _, b_ext, invalid = self.binner.bin_index(opl)
        ok = mi.Bool(active) & valid & ~invalid
        pixel = mi.UInt32(lane) // self.K
        base = (pixel * self.T_ext + mi.UInt32(dr.maximum(b_ext, 0))) * self.C
        n = self.per_channel
        return [dr.gather(mi.Float, self.delta, base + c // n, ok) * dr.select(ok, v, 0)
                for c, v in enumerate(values)]


#: Wavelengths per path of a spectral variant (1 otherwise): the replay's adjoint sums and log-throughput
#: derivatives are kept per (channel, wavelength), since a BSDF value's ratio differs per wavelength
N_WL = dr.size_v(mi.Spectrum) if mi.is_spectral else 1


def _values(value, wavelengths, channels, rotation) -> list:
    """A contribution's recorded values: per channel (mono, rgb), or per (channel, wavelength) in spectral
    variants (the recorded value of each wavelength alone; the channels are linear in the spectrum)."""
    if not mi.is_spectral:
        return as_list(channel_values(value, wavelengths, channels, rotation))
    s = mi.unpolarized_spectrum(value)
    parts = []
    for i in range(N_WL):
        one = mi.Spectrum(*[s[j] if j == i else mi.Float(0) for j in range(N_WL)])
        parts.append(as_list(channel_values(one, wavelengths, channels, rotation)))
    return [parts[i][c] for c in range(len(parts[0])) for i in range(N_WL)]


def _channel_ratio(f_att, f_det, ok, n_values: int = 0) -> list:
    """Per channel ``f_att / f_det`` (1 where the BSDF sample is invalid or a delta lobe); spectral: per
    wavelength, repeated for each channel (``n_values`` = channels x wavelengths)."""
    a, d = mi.unpolarized_spectrum(f_att), mi.unpolarized_spectrum(f_det)
    n = 3 if mi.is_rgb else N_WL if mi.is_spectral else 1
    r = [dr.select(ok & (d[c] > 0), a[c] / dr.select(d[c] > 0, d[c], 1), 1) for c in range(n)]
    if mi.is_spectral:
        r = [r[i % N_WL] for i in range(n_values)]
    return r


def _setup(integrator, scene, sensor, spp):
    film = _check(integrator, sensor)
    W, H = film.width, film.height
    axis = film.time_axis()
    taps = film.kernel_taps()
    pad = len(taps) // 2
    channels = film.channel_names()
    n_ch = len(channels) if channels else 1
    spp = spp or int(sensor.sampler().sample_count())
    K = choose_streams(W * H, spp, (axis.n_bins + 2 * pad) * n_ch)
    layout = LaneLayout(W * H, spp, K)
    integrator._channels, integrator._sensor = channels, sensor
    return film, layout, axis, taps, pad, channels, n_ch


def render_backward(integrator, scene, params, grad_in, sensor, seed, spp, replay=None, detached=False) -> None:
    """Reverse mode: propagate ``grad_in`` (the adjoint of the histogram tensor) to the scene parameters.

    ``replay`` is the path replay (default :func:`_replay`; ``transient_volpath`` passes its own, which runs
    under ``dr.suspend_grad`` (``detached``) and resumes gradients for the factors it re-evaluates)."""
    film, layout, axis, taps, pad, channels, n_ch = _setup(integrator, scene, sensor, spp)
    delta = _adjoint_ext(grad_in, film, n_ch)
    binner = LaneHistogram(LaneLayout(1, 1, 1), axis, pad)
    adj = _Adjoint(delta, binner, layout.streams)
    rng = seed_rng(seed, layout.n_lanes)
    origin, pixel_filter = TimeOrigin(sensor), PixelFilter(film.rfilter(), film.sample_border())
    scale = 1.0 / layout.spp
    if replay is None:
        if check_geometry(integrator, film, params):
            return _geometry_backward(integrator, scene, sensor, film, layout, grad_in, n_ch, adj, rng, origin,
                                      pixel_filter, scale)
        replay = _replay

    def trace(scene_, rng_, _hist, lane, ray, weight, org):
        state = (mi.UInt64(rng_.state), mi.UInt64(rng_.inc))
        with _detached(detached):
            A = replay(integrator, scene_, rng_, lane, ray, weight, org, adj, "weight", None, scale)  # [A_c]
        replay_rng = mi.PCG32()
        replay_rng.state, replay_rng.inc = state
        with _detached(detached):
            replay(integrator, scene_, replay_rng, lane, ray, weight, org, adj, "backward", A, scale)

    for j0, j1 in layout.passes():
        rng = integrator._camera_pass(scene, sensor, None, rng, layout, j0, j1, film.width, film.height, origin,
                                      pixel_filter, trace=trace)
        dr.eval(rng.state)


def render_forward(integrator, scene, params, sensor, seed, spp, replay=None, detached=False) -> mi.TensorXf:
    """Forward mode: the derivative of the histogram tensor along the parameters' tangents (``replay``,
    ``detached``: as in :func:`render_backward`)."""
    film, layout, axis, taps, pad, channels, n_ch = _setup(integrator, scene, sensor, spp)
    hist = LaneHistogram(layout, axis, pad) if channels is None else ChannelHistogram(layout, axis, pad, n_ch)
    rng = seed_rng(seed, layout.n_lanes)
    origin, pixel_filter = TimeOrigin(sensor), PixelFilter(film.rfilter(), film.sample_border())
    if replay is None:
        if check_geometry(integrator, film, params):
            return _geometry_forward(integrator, scene, sensor, film, layout, axis, taps, channels, n_ch, hist, rng,
                                     origin, pixel_filter)
        replay = _replay

    def trace(scene_, rng_, hist_, lane, ray, weight, org):
        with _detached(detached):
            replay(integrator, scene_, rng_, lane, ray, weight, org, None, "forward", hist_, 1.0)

    for j0, j1 in layout.passes():
        rng = integrator._camera_pass(scene, sensor, hist, rng, layout, j0, j1, film.width, film.height, origin,
                                      pixel_filter, trace=trace)
        hist.evaluate(rng)
    h, _, _, _ = hist.collect(taps)
    H, W = film.height, film.width
    return upload_tensor(h.reshape((H, W, axis.n_bins) + h.shape[2:]))


def _detached(on: bool):
    """``dr.suspend_grad()`` when ``on`` (a replay that detaches its sampling itself), else no change."""
    return dr.suspend_grad() if on else contextlib.nullcontext()


def _geometry_backward(integrator, scene, sensor, film, layout, grad_in, n_ch, adj, rng, origin, pixel_filter,
                       scale) -> None:
    """Reverse mode with shape geometry (:mod:`._ad_geometry`): the replay with attached vertices and the
    arrival-time term."""
    tadj = TimeAdjoint(grad_in, film, n_ch, layout.streams)

    def trace(scene_, rng_, _hist, lane, ray, weight, org):
        state = (mi.UInt64(rng_.state), mi.UInt64(rng_.inc))
        with dr.suspend_grad():
            A = replay_geometry(integrator, scene_, rng_, lane, ray, weight, org, adj, tadj, "weight", None, scale)
        replay_rng = mi.PCG32()
        replay_rng.state, replay_rng.inc = state
        replay_geometry(integrator, scene_, replay_rng, lane, ray, weight, org, adj, tadj, "backward", A, scale)

    for j0, j1 in layout.passes():
        rng = integrator._camera_pass(scene, sensor, None, rng, layout, j0, j1, film.width, film.height, origin,
                                      pixel_filter, trace=trace)
        dr.eval(rng.state)


def _geometry_forward(integrator, scene, sensor, film, layout, axis, taps, channels, n_ch, hist, rng, origin,
                      pixel_filter) -> mi.TensorXf:
    """Forward mode with shape geometry: evaluated loops and calls (Dr.Jit cannot forward-propagate a shape
    parameter into symbolic scopes, drjit issue 295); the arrival-time tangent is added after the taps."""
    tt = TimeTangent(film, layout.n_lanes, n_ch)

    def trace(scene_, rng_, hist_, lane, ray, weight, org):
        replay_geometry(integrator, scene_, rng_, lane, ray, weight, org, None, None, "forward", hist_, 1.0,
                        time_tangent=tt)

    with dr.scoped_set_flag(dr.JitFlag.SymbolicLoops, False), dr.scoped_set_flag(dr.JitFlag.SymbolicCalls, False):
        for j0, j1 in layout.passes():
            rng = integrator._camera_pass(scene, sensor, hist, rng, layout, j0, j1, film.width, film.height, origin,
                                          pixel_filter, trace=trace)
            hist.evaluate(rng, tt.data)
    h, _, _, _ = hist.collect(taps)
    h = np.asarray(h, dtype=np.float64).reshape(layout.n_pixels, axis.n_bins, n_ch) + tt.collect(layout)
    H, W = film.height, film.width
    shape = (H, W, axis.n_bins) if channels is None else (H, W, axis.n_bins, n_ch)
    return upload_tensor(h.reshape(shape))


def _accumulate(adj, lane, acc, opl, le, act_le, opl_em, lr, act_em):
    """Weight pass: ``A_c += delta . c`` for this vertex's emitter hit and next-event terms."""
    w_le = adj.weights(lane, opl, le, act_le)
    w_lr = adj.weights(lane, opl_em, lr, act_em)
    return [a + dr.detach(w_le[c] + w_lr[c]) for c, a in enumerate(acc)]


def _backward_step(adj, lane, acc, opl, le, act_le, opl_em, lr, act_em, ratio, scale):
    """Back-propagate this vertex's own terms and its BSDF value's share of everything still to come;
    returns the adjoint-weighted contributions still to come after this vertex."""
    w_le = adj.weights(lane, opl, le, act_le)
    w_lr = adj.weights(lane, opl_em, lr, act_em)
    rest = [a - dr.detach(w_le[c] + w_lr[c]) for c, a in enumerate(acc)]
    obj = mi.Float(0)
    for c in range(len(rest)):
        obj += w_le[c] + w_lr[c] + rest[c] * dr.replace_grad(mi.Float(1), ratio[c])
    dr.backward_from(scale * obj)
    return rest


def _forward_step(hist, lane, score, opl, le, act_le, opl_em, lr, act_em, ratio, mono):
    """Record the derivative of this vertex's terms, ``d c = (d c at fixed throughput) + c S``, and add the
    derivative of this vertex's log BSDF value to ``S`` (spectral: per wavelength, summed per channel)."""
    n = len(score)
    grads = dr.forward_to(*le, *lr, *ratio)
    grads = list(grads) if isinstance(grads, (list, tuple)) else [grads]
    out_le = [dr.detach(grads[c]) + dr.detach(le[c]) * score[c] for c in range(n)]
    out_lr = [dr.detach(grads[n + c]) + dr.detach(lr[c]) * score[c] for c in range(n)]
    if N_WL > 1:
        out_le = [sum(out_le[c:c + N_WL], mi.Float(0)) for c in range(0, n, N_WL)]
        out_lr = [sum(out_lr[c:c + N_WL], mi.Float(0)) for c in range(0, n, N_WL)]
    hist.record(lane, opl, out_le[0] if mono else out_le, act_le)
    hist.record(lane, opl_em, out_lr[0] if mono else out_lr, act_em)
    return [score[c] + dr.detach(grads[2 * n + c]) for c in range(n)]


@dr.syntax
def _replay(integrator, scene, rng, lane, ray, throughput, origin, adj, mode: str, extra, scale: float):
    """One path of ``transient_path`` (same sampling), in one of three modes.

    ``weight``: returns ``A_c = sum_j delta[b_j, c] c_{j,c}`` per channel (a list). ``backward``: ``extra``
    is that list; back-propagates. ``forward``: ``extra`` is the derivative histogram; records ``d c_j``.
    """
    ctx = mi.BSDFContext()
    wavelengths = ray.wavelengths
    channels, rotation = integrator._channel_setup(ray)
    ray = mi.Ray3f(dr.detach(ray))
    depth = mi.UInt32(0)
    beta = mi.Spectrum(dr.detach(throughput))
    eta = mi.Float(1)
    active = mi.Bool(True)
    prev_si = dr.zeros(mi.SurfaceInteraction3f)
    prev_bsdf_pdf = mi.Float(1)
    prev_bsdf_delta = mi.Bool(True)
    si = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=True)
    opl = dr.select(si.is_valid(), dr.norm(si.p - origin), dr.inf)
    n_ch = (1 if channels is None else len(channels)) * N_WL  # (spectral: per channel and wavelength)
    acc = [mi.Float(0) for _ in range(n_ch)]  # weight mode: A so far; backward mode: A still to come
    if dr.hint(mode == "backward", mode="scalar"):
        acc = [mi.Float(a) for a in extra]
    score = [mi.Float(0) for _ in range(n_ch)]  # forward mode: derivative of the log-throughput per channel
    max_depth = integrator.max_depth
    rr_depth = integrator.rr_depth
    grads = dr.hint(mode != "weight", mode="scalar")

    while active:
        with dr.resume_grad(when=grads):
            # ---- emitter hit
            ds = mi.DirectionSample3f(scene, si=si, ref=prev_si)
            em_pdf = dr.detach(scene.pdf_emitter_direction(prev_si, ds, ~prev_bsdf_delta))
            Le = beta * _mis(prev_bsdf_pdf, em_pdf) * ds.emitter.eval(si, prev_bsdf_pdf > 0)
            Le_v = _values(Le, wavelengths, channels, rotation)
            act_le = active & (ds.emitter != None)  # noqa: E711

            active_next = active & si.is_valid() & (depth + 1 < max_depth)
            bsdf = si.bsdf(ray)

            # ---- next-event estimation (emitter radiance and BSDF value attached)
            active_em = active_next & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
            ds, em_weight = scene.sample_emitter_direction(
                si, mi.Point2f(rng.next_float32(), rng.next_float32()), True, active_em)
            active_em &= dr.detach(ds.pdf) != 0
            wo = si.to_local(ds.d)
            bsdf_val, bsdf_pdf = bsdf.eval_pdf(ctx, si, wo, active_em)
            mis_em = dr.select(ds.delta, 1, _mis(dr.detach(ds.pdf), dr.detach(bsdf_pdf)))
            Lr = beta * mis_em * bsdf_val * em_weight
            Lr_v = _values(Lr, wavelengths, channels, rotation)
            opl_em = opl + segment_index(bsdf, si, wo, eta, active_em) * dr.detach(ds.dist)

            # ---- BSDF sampling (detached), and the attached value of the sampled direction
            with dr.suspend_grad():
                bs, bsdf_weight = bsdf.sample(ctx, si, rng.next_float32(),
                                              mi.Point2f(rng.next_float32(), rng.next_float32()), active_next)
            smooth = active_next & ~mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
            f_att = bsdf.eval(ctx, si, bs.wo, smooth)
            ratio = _channel_ratio(f_att, bsdf_weight * bs.pdf, smooth, n_ch)
            if dr.hint(mode == "weight", mode="scalar"):
                acc = _accumulate(adj, lane, acc, opl, Le_v, act_le, opl_em, Lr_v, active_em)
            elif dr.hint(mode == "backward", mode="scalar"):
                acc = _backward_step(adj, lane, acc, opl, Le_v, act_le, opl_em, Lr_v, active_em, ratio, scale)
            else:
                score = _forward_step(extra, lane, score, opl, Le_v, act_le, opl_em, Lr_v, active_em, ratio,
                                      channels is None)

        ray = si.spawn_ray(si.to_world(bs.wo))
        eta *= bs.eta
        beta *= bsdf_weight
        prev_si = dr.detach(si, True)
        prev_bsdf_pdf = bs.pdf
        prev_bsdf_delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)

        depth[si.is_valid()] += 1
        beta_max = dr.max(mi.unpolarized_spectrum(beta))
        rr_prob = dr.minimum(beta_max * dr.square(eta), 0.95)
        rr_active = depth >= rr_depth
        rr_continue = rng.next_float32() < rr_prob
        beta[rr_active] *= dr.rcp(rr_prob)
        active = active_next & (~rr_active | rr_continue) & (beta_max != 0)

        si_next = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=False, active=active)
        opl = dr.select(si_next.is_valid(), opl + eta * dr.norm(si_next.p - si.p), dr.inf)
        si = si_next
    return acc
