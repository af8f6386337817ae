"""The path vertices of the differentiable NLOS estimator (:mod:`._nlos_ad`): connections to the laser spot(s),
the one-sample MIS at the patch point, and the path replay of the vertices beyond the hidden one.

Each function draws the same random numbers as its counterpart in :mod:`._nlos_kernel` (so the derivative
kernel replays the primal's samples); ``rec`` is a recorder of :mod:`._nlos_ad_terms`. Distances in metres.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from transient_mi.integrators._lanes import to_mono
from transient_mi.integrators._nlos_ad_terms import _FLAGS, Backward
from transient_mi.integrators._nlos_kernel import VISIBILITY_REL_TOL
from transient_mi.integrators._optical_path import segment_index


def connect(scene, rec, lane, si, beta, w0, opl, active, c, spot, group, wall_ptr, ctx, n_att, geometry,
             visible=None, depth=1, eta=None, score=None):
    """Connect vertex ``si`` to the laser spot(s) and record (as ``_nlos_kernel._connect_spots``)."""
    bsdf = si.bsdf()
    active = active & (depth + 2 <= c.max_depth) & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
    if c.planar_wall:
        active &= si.shape != wall_ptr
    if group is None:
        connect_one(scene, rec, lane, si, bsdf, beta, w0, opl, active, c, spot[0], spot[1], mi.UInt32(0), ctx,
                     n_att, geometry, visible, eta, score)
    else:
        connect_group(scene, rec, lane, si, bsdf, beta, w0, opl, active, c, group, ctx, n_att, geometry, eta, score)


def connect_group(scene, rec, lane, si, bsdf, beta, w0, opl, active, c, group, ctx, n_att, geometry, eta=None,
                   score=None):
    """The spots of an array capture's group one after another, unrolled (``group = (n, fields)``: a Python
    loop; a symbolic loop around the back-propagation would nest it in the sample loop)."""
    n, fields = group
    for b in range(n):
        idx = mi.UInt32(b)
        si_s = dr.zeros(mi.SurfaceInteraction3f)
        si_s.p = dr.gather(mi.Point3f, fields[0], idx)
        si_s.n = dr.gather(mi.Normal3f, fields[1], idx)
        si_s.sh_frame = mi.Frame3f(dr.gather(mi.Vector3f, fields[2], idx), dr.gather(mi.Vector3f, fields[3], idx),
                                   dr.gather(mi.Normal3f, fields[4], idx))
        si_s.uv = dr.gather(mi.Point2f, fields[5], idx)
        si_s.wi = dr.gather(mi.Vector3f, fields[6], idx)
        si_s.t = dr.gather(mi.Float, fields[7], idx)
        si_s.shape = dr.gather(mi.ShapePtr, fields[8], idx)
        si_s.wavelengths = si.wavelengths
        bsdf_s = dr.gather(mi.BSDFPtr, fields[9], idx)
        connect_one(scene, rec, lane, si, bsdf, beta, w0, opl, active, c, si_s, bsdf_s, idx, ctx, n_att, geometry,
                     None, eta, score)


def connect_one(scene, rec, lane, si, bsdf, beta, w0, opl, active, c, si_s, bsdf_s, sub, ctx, n_att, geometry,
                 visible, eta=None, score=None):
    with dr.resume_grad():
        to_s = si_s.p - si.p
        dist_s = dr.norm(to_s)
        d_s = to_s / dist_s
        wo = si.to_local(d_s)
        f_x = bsdf.eval(ctx, si, wo, active)
        path_s = dist_s if eta is None else segment_index(bsdf, si, wo, eta, active) * dist_s
        i_s = bsdf_s.eval(ctx, si_s, si_s.to_local(-d_s), active)
        val = to_mono(beta * f_x * i_s, si.wavelengths) * (w0 / dr.square(dist_s)) * n_att()
        ok = active & (dr.detach(val) > 0) & si_s.is_valid()
        if visible is None:
            ok &= ~scene.ray_test(dr.detach(si).spawn_ray_to(dr.detach(si_s.p)), ok)
        else:
            ok &= visible
        rec.record(lane, sub, opl + path_s + c.first_last_factor * si_s.t, val, ok, geometry, score)


def first_bounce(scene, si, active, u, rng, c, ks, ctx, geometry):
    """The primal's one-sample MIS at the patch point (:func:`._nlos_kernel._first_bounce`, same draws), with
    the BSDF value attached and, for hidden-geometry samples, the hidden vertex following its shape.

    Returns ``(si_next, weight, eta, active)``; ``si_next`` is attached (p, n, frame, wi) where it follows a
    shape; ``eta`` the relative index after the bounce (as the primal's).
    """
    bsdf = si.bsdf()
    alpha = c.hidden_geometry_prob
    use_hg = active & (u[0] < alpha)
    if ks.hidden_ptrs is not None:
        idx = ks.hidden_distr.sample(u[1], use_hg)
        shape = dr.gather(mi.ShapePtr, ks.hidden_ptrs, idx, use_hg)
        ps = shape.sample_position(0.0, mi.Point2f(u[2], u[3]), use_hg)
        p_hg = dr.detach(ps.p)
        o_hg = si.spawn_ray_to(p_hg).o
        to_x = p_hg - o_hg
        dist_x = dr.norm(to_x)
        d_hg = to_x / dist_x
    else:
        shape = dr.zeros(mi.ShapePtr)
        dist_x = mi.Float(0.0)
        o_hg = mi.Point3f(si.p)
        d_hg = mi.Vector3f(0.0, 0.0, 1.0)
    bs, bsdf_w = bsdf.sample(ctx, si, rng.next_float32(), mi.Point2f(u[4], u[5]), active & ~use_hg)
    ray_b = si.spawn_ray(si.to_world(bs.wo))
    ray = mi.Ray3f(dr.select(use_hg, o_hg, ray_b.o), dr.select(use_hg, d_hg, ray_b.d))
    flags = mi.RayFlags.All | (mi.RayFlags.FollowShape if geometry else mi.RayFlags.Empty)
    si_next = scene.ray_intersect(dr.detach(ray), ray_flags=flags, coherent=False, active=active)
    with dr.suspend_grad():
        f_det, pdf_b = bsdf.eval_pdf(ctx, si, si.to_local(ray.d), active)
        on_hidden = si_next.is_valid() & (si_next.shape != ks.wall_ptr)
        cos_y = dr.abs(dr.dot(si_next.n, ray.d))
        dist2_y = dr.squared_norm(si_next.p - si.p)
        pdf_h = dr.select(on_hidden & (cos_y > 0), dist2_y / (cos_y * c.hidden_area_m2), 0.0)
        pdf_mix = alpha * pdf_h + (1.0 - alpha) * pdf_b
        hg_ok = si_next.is_valid() & (si_next.shape == shape) & \
            (dr.abs(si_next.t - dist_x) <= VISIBILITY_REL_TOL * dist_x)
        delta_lobe = ~use_hg & mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
        mis_h = dr.select(pdf_mix > 0, pdf_h / pdf_mix, 0.0)  # area-sampling's share (detached)
    with dr.resume_grad():
        if geometry:
            # area measure: f cos_p * cos_X A / |X - p|^2 * (pdf_h / pdf_mix), every factor at the moving X
            to_y = si_next.p - si.p
            d2 = dr.squared_norm(to_y)
            d_y = to_y * dr.rsqrt(d2)
            si_next.wi = si_next.to_local(-d_y)
            f_att = bsdf.eval(ctx, si, si.to_local(d_y), active)
            g = dr.abs(dr.dot(si_next.n, d_y)) * c.hidden_area_m2 / d2
            weight = dr.select(use_hg & on_hidden, f_att * g * mis_h, 0.0)
        else:
            f_att = bsdf.eval(ctx, si, si.to_local(ray.d), active)
            weight = dr.select(pdf_mix > 0, f_att / dr.select(pdf_mix > 0, pdf_mix, 1.0), 0.0)
        weight = mi.Spectrum(weight)
        weight = dr.select(use_hg & ~hg_ok, 0.0, weight)
        weight = dr.select(delta_lobe, dr.detach(bsdf_w) / (1.0 - alpha), weight)
    eta = dr.select(use_hg, 1.0, bs.eta)
    return si_next, weight, eta, active & si_next.is_valid()


def unit_ratio(f, ok=True):
    """``f / detach(f)`` (mono: channel 0): value 1, derivative ``df / f``; 1 where ``f`` is 0 or not ``ok``."""
    x = mi.Float(f[0]) if isinstance(f, mi.Spectrum) and not isinstance(f, mi.Float) else mi.Float(f)
    d = dr.detach(x)
    good = mi.Bool(ok) & (d != 0)
    return dr.select(good, x / dr.select(good, d, 1.0), 1.0)


def deeper(scene, rec, rng, lane, si2, weight, w0, opl2, eta, active, c, spot, group, wall_ptr, ctx, n_att):
    """Vertices beyond the hidden vertex (``max_depth > 4``, BSDF parameters, mono): path replay.

    Reverse mode (PRB): a first walk with a copy of the random stream sums ``A = sum_j delta_j c_j`` over the
    deeper contributions (detached); the first bounce's BSDF value then back-propagates its share
    ``A f / detach(f)``, and a second walk with the same numbers back-propagates, at each vertex, its own
    contributions plus ``A_rest f_k / detach(f_k)`` for the BSDF value of the direction sampled there.
    Forward mode: one walk carrying the derivative of the log-throughput.
    """
    si2 = dr.detach(si2)
    w_det = mi.Spectrum(dr.detach(weight))
    opl2 = mi.Float(dr.detach(opl2))
    with dr.resume_grad():
        ratio_w = unit_ratio(weight)
    args = (scene, rec, lane, w0, c, spot, group, wall_ptr, ctx, n_att)
    if isinstance(rec, Backward):
        saved, rec._pending = rec._pending, []  # (the walks take their own vertices' terms from the recorder)
        rng_w = mi.PCG32()
        rng_w.state, rng_w.inc = mi.UInt64(rng.state), mi.UInt64(rng.inc)
        A = walk(*args, "weight", rng_w, si2, w_det, opl2, eta, active, mi.Float(0.0))
        terms = []
        walk(*args, "backward", rng, si2, w_det, opl2, eta, active, A, terms)
        # back-propagated with the sample: vertices 1 and 2, the first bounce's share of A, the deeper vertices
        rec._pending = saved + [A * ratio_w] + terms
    else:
        with dr.resume_grad():
            s0 = dr.detach(dr.forward_to(ratio_w, flags=_FLAGS))
        walk(*args, "forward", rng, si2, w_det, opl2, eta, active, s0)


def walk(scene, rec, lane, w0, c, spot, group, wall_ptr, ctx, n_att, mode, rng, si, beta, opl, eta, active, acc,
          terms=None):
    """The primal's deeper loop (:func:`._nlos_kernel.nlos_pass`, same draws) in one of three modes:
    ``weight`` returns ``A`` (``acc`` starts at 0), ``backward`` back-propagates (``acc`` = ``A``),
    ``forward`` records tangents (``acc`` = the log-throughput's derivative so far). ``terms``: the list the
    backward walk appends each vertex's objective to.

    Unrolled in Python (``max_depth - 3`` iterations; a symbolic loop nested in the sample loop around these
    AD operations does not compile), with the random stream advanced only where the primal's loop runs.
    """
    depth = mi.Int32(2)
    active = mi.Bool(active)
    for _ in range(c.max_depth_static - 3):
        head = mi.Bool(active)
        active_next = head & (depth + 3 <= c.max_depth)
        bsdf = si.bsdf()
        u1 = rng.next_float32(head)
        u2 = mi.Point2f(rng.next_float32(head), rng.next_float32(head))
        with dr.suspend_grad():  # sampling detached: the sampled BSDF value's derivative is ``ratio``
            bs, bsdf_w = bsdf.sample(ctx, si, u1, u2, active_next)
        ratio = mi.Float(1.0)
        if mode != "weight":
            with dr.resume_grad():
                smooth = active_next & ~mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
                ratio = unit_ratio(bsdf.eval(ctx, si, bs.wo, smooth), smooth)
        ray = si.spawn_ray(si.to_world(bs.wo))
        si_next = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=False, active=active_next)
        beta = beta * bsdf_w
        eta = eta * bs.eta
        opl = opl + eta * dr.norm(si_next.p - si.p)
        depth = depth + 1
        beta_max = dr.max(mi.unpolarized_spectrum(beta))
        rr_prob = dr.minimum(beta_max * dr.square(eta), 0.95)
        rr_active = (depth - 1) >= c.rr_depth
        rr_continue = rng.next_float32(head) < rr_prob
        beta = dr.select(rr_active, beta * dr.rcp(rr_prob), beta)
        active = active_next & si_next.is_valid() & (~rr_active | rr_continue) & (beta_max > 0)
        if mode == "forward":
            with dr.resume_grad():
                acc = acc + dr.select(active_next, dr.detach(dr.forward_to(ratio, flags=_FLAGS)), 0.0)
            connect(scene, rec, lane, si_next, beta, w0, opl, active, c, spot, group, wall_ptr, ctx, n_att, False,
                     depth=depth, eta=eta, score=acc)
        else:
            connect(scene, rec, lane, si_next, beta, w0, opl, active, c, spot, group, wall_ptr, ctx, n_att, False,
                     depth=depth, eta=eta)
            with dr.resume_grad():
                own = rec.take()
                if mode == "weight":
                    acc = acc + dr.detach(own)
                else:
                    terms.append(acc * ratio + own)
                    acc = acc - dr.detach(own)
        si = si_next
    return acc
