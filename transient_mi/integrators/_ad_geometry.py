r"""Geometry derivatives of camera views (``transient_path``): the path replay of :mod:`._ad` when a shape's
``to_world`` / ``vertex_positions`` / ``center`` (...) is being differentiated.

Which derivative
----------------
The *interior* derivative: every path vertex moves with the shape it lies on, the discontinuities (a shape's
silhouette, a shadow edge sweeping over a surface) are not differentiated (no reparameterisation; biased
there, see ``docs/differentiable.md``). The path integral is written in a measure whose variables do not
move with the parameters:

* the camera vertex ``x_1`` in the image plane's measure: the camera ray is fixed and ``x_1`` slides along
  it (Mitsuba's attached intersection, ``t`` differentiable: ``RayFlags.All`` without ``FollowShape``);
* every later vertex ``x_{k+1}`` in its shape's area measure: it sits at a fixed point of its shape and moves
  with it (``RayFlags.FollowShape``, the attached intersection of Mitsuba's ``prb_reparam``; the area
  density of a surface point is constant under rigid motion). The solid-angle sample of the primal becomes
  an area sample with the detached density ``p_w |cos_{k+1}| / d^2``, so each segment carries the factor
  ``F_k = f_k(wi, wo) |cos_{k+1}| / d_k^2`` (``f_k`` the BSDF value with its cosine, ``wi``, ``wo`` and
  ``d_k`` between the attached vertices) divided by its detached value: its derivative takes the place of
  PRB's ``f / detach(f)`` and holds every geometric derivative of the segment;
* a next-event sample is the emitter's own sample (a point light, or a point at a fixed position of an area
  emitter): its value (``f cos / d^2`` and the emitter's solid-angle density) is evaluated from the attached
  vertex. MIS weights stay detached: both strategies integrate over the same (area) variable, so the
  detached weights still sum to one when the vertices move.

Each vertex depends only on its own shape's parameters, so PRB's locality holds: the replay
(:func:`replay_geometry`) attaches the vertex ``x_k``, its predecessor (for ``wi``) and its successor (for
``F_k``) by tracing their detached rays again with ``FollowShape`` (three intersections per vertex).

Arrival time
------------
A contribution ``c_j`` arriving after the optical path length ``s_j`` (the sum of the segments before it)
is spread over the bins by the film's continuous Gaussian kernel ``w_b(s)`` (``kernel_sigma_ps > 0``,
required: refused otherwise); its adjoint gains ``c_j (ds_j/dtheta) sum_b delta_b dw_b/ds``
(:class:`~._nlos_ad_terms.TimeKernel`, as the NLOS estimator). Since ``ds_j/dtheta`` is the sum of the
segments' derivatives, PRB's "still to come" sum gets a second, time-weighted, member
``A_t = sum_j c_j sum_b delta_b dw_b/ds(s_j)``: each segment's length back-propagates the part of ``A_t``
after it. Forward mode carries the derivative of the path length so far next to that of the log-throughput.
The primal is unchanged (box bin then discrete taps): the sub-bin mismatch of :mod:`._nlos_ad` applies.

Not differentiated (biased): visibility and silhouettes (the boundary terms); a deformation's change of area
(scaling a shape, moving single vertices of a mesh: the area density is not differentiated); paths through
delta (specular) lobes (their segment factor is left at 1: a specular chain's vertices do not follow the
shapes in a consistent measure). Tested: rectangles (``to_world``) and a mesh (``vertex_positions``);
untested: moving emitters, spheres.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from transient_mi._upload import upload
from transient_mi.integrators._lanes import as_list, channel_values
from transient_mi.integrators._mis import detached_mis_weight as _mis
from transient_mi.integrators._nlos_ad_terms import TimeKernel
from transient_mi.integrators._optical_path import segment_index
from transient_mi.props import PluginParameterError

#: Parameter names (last key component) of a shape that move it.
GEOMETRY_KEYS = ("to_world", "vertex_positions", "vertex_normals", "center", "radius")

#: Whether the arrival time's derivative is recorded (tests switch it off to show its share).
ARRIVAL_TIME = True


def geometry_keys(params) -> list[str]:
    """The grad-enabled shape geometry parameters of ``params`` (a ``mi.SceneParameters`` or None)."""
    if params is None:
        return []
    keys = []
    for key in params.keys():
        _, _, node, _ = params.properties[key]
        if not isinstance(node, mi.Shape) or key.rsplit(".", 1)[-1] not in GEOMETRY_KEYS:
            continue
        try:
            on = dr.grad_enabled(params[key])
        except Exception:  # noqa: BLE001 (a value without AD support is not a parameter being differentiated)
            on = False
        if on:
            keys.append(key)
    return keys


def check_geometry(integrator, film, params) -> bool:
    """Whether shape geometry is being differentiated (a grad-enabled parameter of :data:`GEOMETRY_KEYS`);
    refuses it in one line in spectral variants and without a temporal kernel (``kernel_sigma_ps = 0``)."""
    keys = geometry_keys(params)
    if keys and mi.is_spectral:
        raise PluginParameterError(
            f"{integrator.NAME}: {keys[0]} is differentiated; derivatives with respect to geometry support *_mono "
            f"and *_rgb variants, not {mi.variant()}")
    if keys and not film.kernel_sigma_ps > 0:
        raise PluginParameterError(
            f"{integrator.NAME}: {keys[0]} is differentiated but the film's kernel_sigma_ps=0; derivatives with "
            "respect to geometry need a temporal kernel (kernel_sigma_ps > 0): a box time bin has no derivative "
            "with respect to arrival time")
    return bool(keys)


class TimeAdjoint:
    """``sum_b delta[pixel, b, c] dw_b/ds`` (1/m) of a contribution at path length ``s``: the arrival-time
    weight of its adjoint (``delta`` the incoming gradient ``[pixel, bin, channel]``, not the kernel-padded
    one)."""

    def __init__(self, grad_in, film, n_ch: int, K: int):
        axis = film.time_axis()
        self.T, self.C, self.K = axis.n_bins, n_ch, K
        P = film.width * film.height
        d = np.asarray(grad_in, dtype=np.float32).reshape(P * self.T * n_ch)
        self.delta = upload(mi.Float, d)
        self.kernel = TimeKernel(axis, film.kernel_sigma_ps, film.kernel_taps())

    def weights(self, lane, opl, values, active) -> list:
        """``[values[c] * sum_b delta[p, b, c] dw_b/ds(opl) for c]`` (detached; 0 where not ``active``)."""
        pixel = mi.UInt32(lane) // self.K
        ok = mi.Bool(active) & dr.isfinite(dr.detach(opl))
        g = [mi.Float(0) for _ in range(self.C)]
        for b, w in self.kernel.weights(opl):
            inb = ok & (b >= 0) & (b < self.T)
            base = (pixel * self.T + mi.UInt32(dr.maximum(b, 0))) * self.C
            for c in range(self.C):
                g[c] += dr.select(inb, dr.gather(mi.Float, self.delta, base + c, inb) * w, 0)
        return [dr.detach(dr.select(ok, v * g[c], 0)) for c, v in enumerate(values)]


class TimeTangent:
    """Forward mode: the arrival-time part of the histogram's tangent, ``c (ds/dtheta) dw_b/ds`` per lane,
    bin and channel (``[lane, bin, channel]``, each lane writing its own slot)."""

    def __init__(self, film, n_lanes: int, n_ch: int):
        axis = film.time_axis()
        self.T, self.C = axis.n_bins, n_ch
        self.kernel = TimeKernel(axis, film.kernel_sigma_ps, film.kernel_taps())
        self.data = dr.zeros(mi.Float, n_lanes * self.T * n_ch)

    def record(self, lane, opl, values, ds, active):
        """Add ``values[c] * ds * dw_b/ds(opl)`` (``ds``: the path length's tangent, m) to ``lane``'s bins."""
        for b, w in self.kernel.weights(opl):
            inb = mi.Bool(active) & (b >= 0) & (b < self.T) & dr.isfinite(ds)
            base = (mi.UInt32(lane) * self.T + mi.UInt32(dr.maximum(b, 0))) * self.C
            for c, v in enumerate(values):
                dr.scatter_reduce(dr.ReduceOp.Add, self.data, dr.detach(v) * ds * w, base + c, inb,
                                  mode=dr.ReduceMode.NoConflicts)

    def collect(self, layout) -> np.ndarray:
        """``[pixel, bin, channel]`` float64, the lanes of a pixel summed, divided by spp."""
        t = np.asarray(self.data, dtype=np.float64).reshape(layout.n_pixels, layout.streams, self.T, self.C)
        return t.sum(axis=1) / layout.spp


def _attach(scene, ray, camera, active):
    """The attached vertex found by the detached ``ray``: along the fixed ray where ``camera`` (the camera
    vertex, image-plane measure), else following its shape (area measure)."""
    si_f = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All | mi.RayFlags.FollowShape, coherent=False,
                               active=active & ~camera)
    si_c = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=True, active=active & camera)
    return dr.select(camera, si_c, si_f)


def _ratio(f_att, g, ok, n: int) -> list:
    """Per channel ``F / detach(F)`` with ``F = f g`` (1 where not ``ok`` or ``F`` is 0)."""
    a = mi.unpolarized_spectrum(f_att)
    out = []
    for c in range(n):
        x = a[c] * g
        d = dr.detach(x)
        good = ok & (d > 0)
        out.append(dr.select(good, x / dr.select(good, d, 1), 1))
    return out


def _weight_step(adj, tadj, timed, acc, acc_t, lane, opl, le, act_le, opl_em, lr, act_em):
    """Weight pass: ``A += delta . c`` and ``A_t += c sum_b delta_b dw_b/ds`` for this vertex's terms."""
    w_le = adj.weights(lane, opl, le, act_le)
    w_lr = adj.weights(lane, opl_em, lr, act_em)
    acc = [a + dr.detach(w_le[c] + w_lr[c]) for c, a in enumerate(acc)]
    if timed:
        t_le = tadj.weights(lane, opl, le, act_le)
        t_lr = tadj.weights(lane, opl_em, lr, act_em)
        acc_t = [a + t_le[c] + t_lr[c] for c, a in enumerate(acc_t)]
    return acc, acc_t


def _backward_step(adj, tadj, timed, acc, acc_t, lane, opl, le, act_le, opl_em, lr, act_em, ratio, seg_cam, seg_em,
                   seg_out, scale):
    """Back-propagate this vertex's own terms, the next segment's factor's share of everything after it, and
    the arrival-time terms of the segments (camera segment: all of ``A_t``; the next-event segment: its own
    term; the next segment: ``A_t`` after this vertex). Returns ``(A, A_t)`` still to come."""
    w_le = adj.weights(lane, opl, le, act_le)
    w_lr = adj.weights(lane, opl_em, lr, act_em)
    rest = [a - dr.detach(w_le[c] + w_lr[c]) for c, a in enumerate(acc)]
    obj = mi.Float(0)
    for c in range(len(rest)):
        obj += w_le[c] + w_lr[c] + rest[c] * dr.replace_grad(mi.Float(1), ratio[c])
    if timed:
        t_le = tadj.weights(lane, opl, le, act_le)
        t_lr = tadj.weights(lane, opl_em, lr, act_em)
        rest_t = [a - t_le[c] - t_lr[c] for c, a in enumerate(acc_t)]
        for c in range(len(rest)):
            obj += acc_t[c] * seg_cam + t_lr[c] * seg_em + rest_t[c] * seg_out
        acc_t = rest_t
    dr.backward_from(scale * obj, flags=dr.ADFlag.Default | dr.ADFlag.AllowNoGrad)
    return rest, acc_t


def _forward_step(hist, time_tangent, timed, mono, score, score_t, lane, opl, le, act_le, opl_em, lr, act_em, ratio,
                  seg_cam, seg_em, seg_out):
    """Record this vertex's tangents (``d c`` at fixed throughput ``+ c S``, and the arrival-time part with the
    path length's derivative so far) and advance ``S`` and the path length's derivative."""
    n = len(score)
    outs = dr.forward_to(*le, *lr, *ratio, seg_cam, seg_em, seg_out, flags=dr.ADFlag.Default | dr.ADFlag.AllowNoGrad)
    outs = [dr.detach(o) for o in outs]
    score_t = score_t + outs[3 * n]
    d_em = score_t + outs[3 * n + 1]
    out_le = [outs[c] + dr.detach(le[c]) * score[c] for c in range(n)]
    out_lr = [outs[n + c] + dr.detach(lr[c]) * score[c] for c in range(n)]
    hist.record(lane, opl, out_le[0] if mono else out_le, act_le)
    hist.record(lane, opl_em, out_lr[0] if mono else out_lr, act_em)
    if timed:
        time_tangent.record(lane, opl, le, score_t, act_le)
        time_tangent.record(lane, opl_em, lr, d_em, act_em)
    return [score[c] + outs[2 * n + c] for c in range(n)], score_t + outs[3 * n + 2]



@dr.syntax
def replay_geometry(integrator, scene, rng, lane, ray, throughput, origin, adj, tadj, mode: str, extra, scale,
                    time_tangent=None):
    """One path of ``transient_path`` (the primal's sampling) with every vertex attached to its shape.

    ``weight``: returns ``(A, A_t)`` per channel (lists). ``backward``: ``extra`` is that pair;
    back-propagates. ``forward``: ``extra`` is the derivative histogram and ``time_tangent`` a
    :class:`TimeTangent`; records the tangents.
    """
    ctx = mi.BSDFContext()
    wavelengths = ray.wavelengths
    channels, rotation = integrator._channel_setup(ray)
    ray = mi.Ray3f(dr.detach(ray))
    origin = mi.Point3f(dr.detach(origin))
    with dr.suspend_grad():
        si = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=True)
    opl = dr.select(si.is_valid(), dr.norm(si.p - origin), dr.inf)
    ray_k = mi.Ray3f(ray)  # the ray that found si
    ray_p = mi.Ray3f(ray)  # the ray that found the previous vertex (depth > 0)
    depth = mi.UInt32(0)
    beta = mi.Spectrum(dr.detach(throughput))
    eta = mi.Float(1)
    active = mi.Bool(True)
    prev_si = dr.zeros(mi.SurfaceInteraction3f)
    prev_bsdf_pdf = mi.Float(1)
    prev_bsdf_delta = mi.Bool(True)
    n_ch = 1 if channels is None else len(channels)
    acc = [mi.Float(0) for _ in range(n_ch)]  # weight: A so far; backward: A still to come
    acc_t = [mi.Float(0) for _ in range(n_ch)]  # the same, time-weighted
    if dr.hint(mode == "backward", mode="scalar"):
        acc = [mi.Float(a) for a in extra[0]]
        acc_t = [mi.Float(a) for a in extra[1]]
    score = [mi.Float(0) for _ in range(n_ch)]  # forward: derivative of the log-throughput
    score_t = mi.Float(0)  # forward: derivative of the path length so far
    max_depth = integrator.max_depth
    rr_depth = integrator.rr_depth
    grads = dr.hint(mode != "weight", mode="scalar")
    timed = dr.hint(ARRIVAL_TIME, mode="scalar")

    while active:
        first = depth == 0
        with dr.resume_grad(when=grads):
            # ---- the vertex and its predecessor, attached
            x = _attach(scene, ray_k, first, active)
            xp = _attach(scene, ray_p, depth == 1, active & ~first)
            p_prev = dr.select(first, origin, xp.p)
            to_x = x.p - p_prev
            dist_in = dr.norm(to_x)
            x.wi = dr.select(first | ~x.is_valid(), x.wi, x.to_local(-to_x / dist_in))  # (escaped: -ray.d)
            seg_cam = dr.select(first, dist_in, 0)  # the camera segment (its later segments: seg_out)

            # ---- emitter hit
            ds = mi.DirectionSample3f(scene, si=x, ref=prev_si)
            with dr.suspend_grad():
                em_pdf = scene.pdf_emitter_direction(prev_si, mi.DirectionSample3f(scene, si=si, ref=prev_si),
                                                     ~prev_bsdf_delta)
            Le = beta * _mis(prev_bsdf_pdf, em_pdf) * ds.emitter.eval(x, prev_bsdf_pdf > 0)
            Le_v = as_list(channel_values(Le, wavelengths, channels, rotation))
            act_le = active & (ds.emitter != None)  # noqa: E711

            active_next = active & si.is_valid() & (depth + 1 < max_depth)
            bsdf = si.bsdf(ray)

            # ---- next-event estimation from the attached vertex
            active_em = active_next & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
            ds, em_weight = scene.sample_emitter_direction(
                x, mi.Point2f(rng.next_float32(), rng.next_float32()), True, active_em)
            active_em &= dr.detach(ds.pdf) != 0
            wo = x.to_local(ds.d)
            bsdf_val, bsdf_pdf = bsdf.eval_pdf(ctx, x, wo, active_em)
            mis_em = dr.select(ds.delta, 1, _mis(dr.detach(ds.pdf), dr.detach(bsdf_pdf)))
            Lr = beta * mis_em * bsdf_val * em_weight
            Lr_v = as_list(channel_values(Lr, wavelengths, channels, rotation))
            n_em = dr.detach(segment_index(bsdf, si, dr.detach(wo), eta, active_em))
            seg_em = n_em * ds.dist
            opl_em = opl + dr.detach(seg_em)

        # ---- BSDF sampling, Russian roulette and the next vertex (detached, as the primal)
        with dr.suspend_grad():
            bs, bsdf_weight = bsdf.sample(ctx, si, rng.next_float32(),
                                          mi.Point2f(rng.next_float32(), rng.next_float32()), active_next)
        ray_next = si.spawn_ray(si.to_world(bs.wo))
        eta_next = eta * bs.eta
        beta *= bsdf_weight
        depth[si.is_valid()] += 1
        beta_max = dr.max(mi.unpolarized_spectrum(beta))
        rr_prob = dr.minimum(beta_max * dr.square(eta_next), 0.95)
        rr_active = depth >= rr_depth
        rr_continue = rng.next_float32() < rr_prob
        beta[rr_active] *= dr.rcp(rr_prob)
        active_cont = active_next & (~rr_active | rr_continue) & (beta_max != 0)
        with dr.suspend_grad():
            si_next = scene.ray_intersect(ray_next, ray_flags=mi.RayFlags.All, coherent=False, active=active_cont)

        with dr.resume_grad(when=grads):
            # ---- the segment to the next vertex: F = f cos |cos'| / d^2 and its length, attached
            smooth = active_cont & si_next.is_valid() & ~mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
            y = _attach(scene, ray_next, mi.Bool(False), smooth)
            to_y = y.p - x.p
            d2 = dr.squared_norm(to_y)
            d2 = dr.select(smooth & (d2 > 0), d2, 1)
            d_y = to_y * dr.rsqrt(d2)
            f_att = bsdf.eval(ctx, x, x.to_local(d_y), smooth)
            ratio = _ratio(f_att, dr.abs(dr.dot(y.n, d_y)) / d2, smooth, n_ch)
            seg_out = dr.select(smooth, eta_next * dr.sqrt(d2), 0)

            terms = (lane, opl, Le_v, act_le, opl_em, Lr_v, active_em)
            if dr.hint(mode == "weight", mode="scalar"):
                acc, acc_t = _weight_step(adj, tadj, timed, acc, acc_t, *terms)
            elif dr.hint(mode == "backward", mode="scalar"):
                acc, acc_t = _backward_step(adj, tadj, timed, acc, acc_t, *terms, ratio, seg_cam, seg_em, seg_out,
                                            scale)
            else:
                score, score_t = _forward_step(extra, time_tangent, timed, channels is None, score, score_t, *terms,
                                               ratio, seg_cam, seg_em, seg_out)

        eta = eta_next
        prev_si = dr.detach(si, True)
        prev_bsdf_pdf = bs.pdf
        prev_bsdf_delta = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
        active = active_cont
        ray_p = mi.Ray3f(ray_k)
        ray_k = mi.Ray3f(ray_next)
        ray = ray_next
        opl = dr.select(si_next.is_valid(), opl + eta * dr.norm(si_next.p - si.p), dr.inf)
        si = si_next
    if dr.hint(mode == "weight", mode="scalar"):
        return acc, acc_t
    return acc
