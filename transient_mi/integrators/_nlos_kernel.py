r"""The Dr.Jit kernel of the NLOS estimator: one pass of samples over every lane (:func:`nlos_pass`).

The estimator it implements (patch sampling, laser-spot connections, one-sample MIS between
hidden-geometry and BSDF sampling at the patch point, randomised QMC, spot groups) is documented in
:mod:`transient_mi.integrators.transient_nlos_path`; the lane layout and histograms in
:mod:`transient_mi.integrators._lanes`. The per-capture numbers the kernel reads are the fields of
:class:`KernelConstants`, opaque Dr.Jit values, so one compiled kernel serves every spot, seed and setting;
the scene-side inputs (hidden shapes, relay wall, the group's laser spots) are :class:`KernelScene`.
Distances in metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from transient_mi._upload import upload
from transient_mi.integrators._device_legs import beam_spot, trace_leg
from transient_mi.integrators._lanes import to_mono
from transient_mi.integrators._nlos_samples import PixelQMC, lane_pixels
from transient_mi.integrators._optical_path import segment_index

#: Relative tolerance on the hit distance when checking that a hidden-geometry
#: sample is the first surface along its ray.
VISIBILITY_REL_TOL = 1e-4
#: ``max_depth`` value standing for "unlimited".
UNLIMITED_DEPTH = 1 << 30
def _ovec(v) -> "mi.Vector3f":
    v = [float(c) for c in v]
    return mi.Vector3f(dr.opaque(mi.Float, v[0]), dr.opaque(mi.Float, v[1]), dr.opaque(mi.Float, v[2]))


def _opt(v) -> "mi.Point3f":
    return mi.Point3f(_ovec(v))


def _of(x) -> "mi.Float":
    return dr.opaque(mi.Float, float(x))


@dataclass
class KernelConstants:
    """Per-capture values the kernel reads (world frame, metres).

    The Dr.Jit fields are opaque (one compiled kernel for every spot, seed and setting); the plain Python
    fields (``bool``, ``int``) select the kernel's structure at trace time. Built by :meth:`build`.
    """

    #: detector (aperture centre) ``D``, m
    detector: "mi.Point3f"
    #: centre of pixel (0, 0)'s patch in the wall plane, m
    patch_origin: "mi.Point3f"
    #: from one patch centre to the next along the wall's x / y axis (``pixel_pitch_m`` long), m
    pitch_x: "mi.Vector3f"
    pitch_y: "mi.Vector3f"
    #: across one patch along the wall's x / y axis (``pixel_footprint_m`` long), m
    footprint_x: "mi.Vector3f"
    footprint_y: "mi.Vector3f"
    #: unit normal of the wall plane (towards laser and detector)
    wall_normal: "mi.Vector3f"
    #: unit normal of the detector's aperture (towards the array's target)
    aperture_normal: "mi.Vector3f"
    #: area of one pixel's wall patch (``pixel_footprint_m ** 2``), m^2
    pixel_area_m2: "mi.Float"
    #: area of the aperture disc, m^2
    aperture_area_m2: "mi.Float"
    #: laser origin ``L``, m
    laser_origin: "mi.Point3f"
    #: 1 if the first (laser -> spot) and last (patch point -> detector) segments count in the recorded
    #: path length (``include_first_last``), else 0
    first_last_factor: "mi.Float"
    #: probability ``alpha`` of hidden-geometry sampling at the patch point (0 without hidden shapes)
    hidden_geometry_prob: "mi.Float"
    #: total area of the hidden shapes (floored at 1e-30), m^2
    hidden_area_m2: "mi.Float"
    #: longest path in segments, Mitsuba's meaning (:data:`UNLIMITED_DEPTH` for -1)
    max_depth: "mi.Int32"
    #: depth at which Russian roulette starts
    rr_depth: "mi.Int32"
    #: pixels per row of the array
    width_px: "mi.UInt32"
    #: seed of this replicate's random streams and QMC shifts
    seed: "mi.UInt32"
    #: the relay wall is planar: a wall vertex and a spot on it cannot see each other (cos = 0)
    planar_wall: bool
    #: ``pixel_sampling="center"``: the wall point is the patch centre
    patch_center_only: bool
    #: ``max_depth`` as a host integer: whether the kernel traces vertices beyond the hidden vertex
    max_depth_static: int
    #: confocal capture: every lane's laser spot is on its own patch centre
    confocal: bool
    #: confocal with patch centres: the pixel's wall point *is* its laser spot, so the segment back to the
    #: spot from the hidden vertex is the (already traced) segment from the wall point
    spot_is_wall_point: bool
    #: spots of the group (array captures; 1 in confocal captures)
    n_group_spots: "mi.UInt32"
    #: randomised QMC for the patch point and the first bounce (else PCG32 only)
    rqmc: bool = True
    #: the scene has windows: the detector and laser legs are traced through them
    #: (:func:`~transient_mi.integrators._device_legs.trace_leg`)
    windows: bool = False
    #: some non-wall shape is not hidden geometry (no smooth BSDF component): the MIS weight at the patch
    #: point checks the BSDF of the vertex it reached
    hidden_excludes: bool = False
    #: the laser beam diverges: every spot connection samples a beam direction
    #: (:func:`~transient_mi.integrators._device_legs.beam_spot`)
    divergent: bool = False
    #: standard deviation of each tangent-plane component of the beam direction, rad (``pulsed_laser``'s
    #: ``beam_sigma_rad``; used when ``divergent``)
    beam_sigma: object = None
    #: the Monte Carlo *remainder* of ``estimator="quadrature"`` with ``max_depth`` > 4: leave out the
    #: three-bounce connection (vertex 2 to the spot, ``D-p-X-S``) and the closed-form wall return, which the
    #: quadrature gives (:mod:`~._nlos_quadrature`); every other path is recorded as usual. False by default:
    #: the Monte Carlo kernel is then unchanged.
    skip_three_bounce: bool = False

    @classmethod
    def build(cls, setup, options: dict, *, seed: int, n_group: int) -> "KernelConstants":
        """The constants for ``setup`` (:class:`~transient_mi.sensors._nlos_setup.NLOSSetup`) and the
        estimator ``options`` (``max_depth``, ``rr_depth``, ``hidden_geometry_prob``, ``rqmc``)."""
        fr = setup.frame
        confocal = setup.capture == "confocal"
        c00 = fr.grid(setup.width, setup.height, setup.pitch_m)[0, 0]
        max_depth = options.get("max_depth", -1)
        alpha = float(options.get("hidden_geometry_prob", 0.8)) if setup.hidden_shapes else 0.0
        center = setup.pixel_sampling == "center"
        divergent = setup.laser.divergence_mrad > 0
        return cls(
            detector=_opt(setup.detector), patch_origin=_opt(c00), pitch_x=_ovec(fr.ex * setup.pitch_m),
            pitch_y=_ovec(fr.ey * setup.pitch_m), footprint_x=_ovec(fr.ex * setup.footprint_m),
            footprint_y=_ovec(fr.ey * setup.footprint_m), wall_normal=_ovec(fr.normal),
            aperture_normal=_ovec(setup.aperture_normal), pixel_area_m2=_of(setup.footprint_m ** 2),
            aperture_area_m2=_of(setup.aperture_area_m2), laser_origin=_opt(setup.laser_origin),
            first_last_factor=_of(1.0 if setup.include_first_last else 0.0),
            hidden_geometry_prob=_of(alpha), hidden_area_m2=_of(max(setup.hidden_area_m2, 1e-30)),
            max_depth=dr.opaque(mi.Int32, UNLIMITED_DEPTH if max_depth == -1 else int(max_depth)),
            rr_depth=dr.opaque(mi.Int32, int(options.get("rr_depth", 5))),
            width_px=dr.opaque(mi.UInt32, setup.width),
            seed=dr.opaque(mi.UInt32, seed & 0xFFFFFFFF),
            planar_wall=setup.planar_wall,
            patch_center_only=center,
            max_depth_static=UNLIMITED_DEPTH if max_depth == -1 else int(max_depth),
            confocal=confocal,
            spot_is_wall_point=confocal and center and not setup.windows and not divergent,
            n_group_spots=dr.opaque(mi.UInt32, n_group),
            rqmc=bool(options.get("rqmc", True)),
            windows=setup.windows,
            hidden_excludes=setup.hidden_excludes,
            divergent=divergent,
            beam_sigma=_of(setup.laser.beam_sigma_rad),
            skip_three_bounce=bool(options.get("skip_three_bounce", False)),
        )


@dataclass
class KernelScene:
    """The scene-side inputs of the kernel. Built by :meth:`build`.

    ``hidden_ptrs`` and ``hidden_distr``: the hidden shapes and the discrete distribution choosing one in
    proportion to its area (None without hidden geometry); ``wall_ptr``: the relay wall; ``group``: what a
    BSDF evaluation at each laser spot of the group needs (surface-interaction fields, shape and BSDF
    pointers), None in confocal captures (each lane traces its own spot). In scenes with windows the
    laser legs are traced through them: the ``t`` entry then holds the leg's optical path length and an
    11th entry its transmittance. With a divergent beam ``group`` holds only the beam axes (unit vectors
    from the laser towards the spot targets): each connection samples its own spot.
    """

    hidden_ptrs: object
    hidden_distr: object
    wall_ptr: object
    group: tuple | None

    @classmethod
    def build(cls, scene, setup, spots: list[int]) -> "KernelScene":
        if setup.hidden_shapes:
            hidden_ptrs = mi.ShapePtr(setup.hidden_shapes)
            areas = [float(s.surface_area()[0]) for s in setup.hidden_shapes]
            distr = mi.DiscreteDistribution(mi.Float(areas))
        else:
            hidden_ptrs, distr = None, None
        wall_ptr = mi.ShapePtr(setup.relay_wall)

        # the laser spots of the group (array captures): one ray each, evaluated once
        group = None
        if setup.capture != "confocal":
            # (padded to >= 2 entries: Dr.Jit treats size-1 arrays as scalars, which must not reach a kernel
            # compiled for a gather from a real array)
            tg = setup.spot_targets[spots + [spots[-1]] * max(0, 2 - len(spots))]
            Lo = setup.laser_origin
            d = tg - Lo
            d = d / np.linalg.norm(d, axis=1, keepdims=True)
            if setup.laser.divergence_mrad > 0:
                axes = mi.Vector3f(*[upload(mi.Float, d[:, i]) for i in range(3)])
                dr.eval(axes)
                return cls(hidden_ptrs, distr, wall_ptr, (axes,))
            ray = mi.Ray3f(mi.Point3f(*[upload(mi.Float, np.full(len(tg), Lo[i])) for i in range(3)]),
                           mi.Vector3f(*[upload(mi.Float, d[:, i]) for i in range(3)]))
            if setup.windows:
                si_g, thr_g, opl_g = trace_leg(scene, ray.o, ray.d)
                si_g.t = opl_g  # what the record adds for the laser leg (first_last_factor * t)
            else:
                si_g = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=True)
            # what a BSDF evaluation at the spot needs (gathered per connection: keep it small)
            group = (si_g.p, si_g.n, si_g.sh_frame.s, si_g.sh_frame.t, si_g.sh_frame.n, si_g.uv, si_g.wi,
                     si_g.t, si_g.shape, si_g.bsdf())
            if setup.windows:
                group = group + (thr_g,)
            dr.eval(*group)
        return cls(hidden_ptrs, distr, wall_ptr, group)


def gather_spot(group, b, active, wavelengths) -> list:
    """``[si_s, bsdf_s]``: the surface interaction at the group's laser spot ``b`` (the fields a BSDF
    evaluation needs, from :class:`KernelScene`'s ``group``) and its BSDF."""
    si_s = dr.zeros(mi.SurfaceInteraction3f)
    si_s.p = dr.gather(mi.Point3f, group[0], b, active)
    si_s.n = dr.gather(mi.Normal3f, group[1], b, active)
    si_s.sh_frame = mi.Frame3f(dr.gather(mi.Vector3f, group[2], b, active),
                               dr.gather(mi.Vector3f, group[3], b, active),
                               dr.gather(mi.Normal3f, group[4], b, active))
    si_s.uv = dr.gather(mi.Point2f, group[5], b, active)
    si_s.wi = dr.gather(mi.Vector3f, group[6], b, active)
    si_s.t = dr.gather(mi.Float, group[7], b, active)
    si_s.shape = dr.gather(mi.ShapePtr, group[8], b, active)
    si_s.wavelengths = wavelengths
    return [si_s, dr.gather(mi.BSDFPtr, group[9], b, active)]


@dr.syntax
def _connect_spots(scene, hist, lane, si, beta, w0, opl, depth, active, c, spot, group, wall_ptr, ctx,
                   visible=None, eta=None, rng=None):
    """Deterministic connection of vertex ``si`` to the laser spot(s) (next-event estimation).

    ``spot``: the lane's own spot ``(si_s, bsdf_s)`` (confocal), else ``group``
    holds the group's spots, connected one after another. ``visible``: the
    visibility when it is already known (confocal patch-centre captures).
    ``eta``: the relative refractive index the path is in at ``si`` (None: 1,
    the relay wall's side; see :mod:`transient_mi.integrators._optical_path`). ``rng``: the PCG32 streams
    a divergent beam samples its directions from (``spot`` is then ``(axis,)`` and ``group`` ``(axes,)``).
    """
    bsdf = si.bsdf()
    active_nee = active & (depth + 2 <= c.max_depth) & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
    if dr.hint(c.planar_wall, mode="scalar"):
        # spot and vertex on the same plane: cos(theta_S) = 0 exactly, nothing to connect
        active_nee &= si.shape != wall_ptr
    if dr.hint(group is None, mode="scalar"):  # the lane's own spot: no loop over a group
        if dr.hint(c.divergent, mode="scalar"):
            si_s, bsdf_s, thr_s = beam_spot(scene, c.laser_origin, c.beam_sigma, spot[0], rng, active_nee,
                                              si.wavelengths)
            _connect_one(scene, hist, lane, si, bsdf, beta, w0, opl, active_nee, c, si_s, bsdf_s, mi.UInt32(0),
                         ctx, visible, eta, thr_s)
            return
        _connect_one(scene, hist, lane, si, bsdf, beta, w0, opl, active_nee, c, spot[0], spot[1], mi.UInt32(0),
                     ctx, visible, eta, spot[2] if c.windows else None)
        return
    b = mi.UInt32(0)
    while active_nee & (b < c.n_group_spots):
        thr_s = None
        if dr.hint(group is None, mode="scalar"):
            si_s, bsdf_s = spot
        elif dr.hint(c.divergent, mode="scalar"):
            axis = dr.gather(mi.Vector3f, group[0], b, active_nee & (b < c.n_group_spots))
            si_s, bsdf_s, thr_s = beam_spot(scene, c.laser_origin, c.beam_sigma, axis, rng,
                                            active_nee & (b < c.n_group_spots), si.wavelengths)
        else:
            spot_b = gather_spot(group, b, active_nee & (b < c.n_group_spots), si.wavelengths)
            si_s = spot_b[0]
            bsdf_s = spot_b[1]
        if dr.hint(c.windows and not c.divergent, mode="scalar"):
            thr_s = dr.gather(mi.Float, group[10], b, active_nee & (b < c.n_group_spots))
        _connect_one(scene, hist, lane, si, bsdf, beta, w0, opl, active_nee, c, si_s, bsdf_s, b, ctx, visible, eta,
                     thr_s)
        b += 1


def _connect_one(scene, hist, lane, si, bsdf, beta, w0, opl, active, c, si_s, bsdf_s, sub, ctx, visible,
                 eta=None, spot_weight=None):
    """Connect vertex ``si`` to the spot ``si_s`` and record the contribution in sub-slot ``sub``.

    ``spot_weight``: the laser leg's transmittance through windows (None: 1).
    """
    spot_p = si_s.p
    to_s = spot_p - si.p
    dist_s = dr.norm(to_s)
    d_s = to_s / dist_s
    wo = si.to_local(d_s)
    f_x = bsdf.eval(ctx, si, wo, active)
    path_s = dist_s  # optical length of the connection: it runs at c / n (a rough dielectric's transmission changes n)
    if eta is not None:
        path_s = segment_index(bsdf, si, wo, eta, active) * dist_s
    i_s = bsdf_s.eval(ctx, si_s, si_s.to_local(-d_s), active)
    val = to_mono(beta * f_x * i_s, si.wavelengths) * (w0 / dr.square(dist_s))
    if spot_weight is not None:
        val = val * spot_weight
    ok = active & (val > 0) & si_s.is_valid()
    if visible is None:
        ok &= ~scene.ray_test(si.spawn_ray_to(spot_p), ok)
    else:
        ok &= visible
    hist.record(lane, opl + path_s + c.first_last_factor * si_s.t, val, ok, sub=sub)


def _first_bounce(scene, si, active, u, rng, c, hidden_ptrs, distr, wall_ptr, ctx):
    """Direction leaving the patch point: one-sample MIS between hidden-geometry and BSDF sampling.

    Returns ``(si_next, weight, eta, active)``; ``weight`` is ``f cos / (alpha p_hidden + (1 - alpha) p_bsdf)``
    (0 for an occluded hidden-geometry sample).
    """
    bsdf = si.bsdf()
    alpha = c.hidden_geometry_prob
    use_hg = active & (u[0] < alpha)
    if hidden_ptrs is not None:
        idx = distr.sample(u[1], use_hg)
        shape = dr.gather(mi.ShapePtr, hidden_ptrs, idx, use_hg)
        ps = shape.sample_position(0.0, mi.Point2f(u[2], u[3]), use_hg)
        o_hg = si.spawn_ray_to(ps.p).o  # offset origin, as for any spawned ray
        to_x = ps.p - o_hg
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
    si_next = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=False, active=active)
    f_val, pdf_b = bsdf.eval_pdf(ctx, si, si.to_local(ray.d), active)
    on_hidden = si_next.is_valid() & (si_next.shape != wall_ptr)
    if dr.hint(c.hidden_excludes, mode="scalar"):  # shapes without a smooth component are not hidden geometry
        on_hidden &= mi.has_flag(si_next.bsdf().flags(), mi.BSDFFlags.Smooth)
    cos_y = dr.abs(dr.dot(si_next.n, ray.d))
    dist2_y = dr.squared_norm(si_next.p - si.p)
    pdf_h = dr.select(on_hidden & (cos_y > 0), dist2_y / (cos_y * c.hidden_area_m2), 0.0)
    pdf_mix = alpha * pdf_h + (1.0 - alpha) * pdf_b
    weight = mi.Spectrum(dr.select(pdf_mix > 0, f_val / pdf_mix, 0.0))
    hg_ok = si_next.is_valid() & (si_next.shape == shape) & \
        (dr.abs(si_next.t - dist_x) <= VISIBILITY_REL_TOL * dist_x)
    weight = dr.select(use_hg & ~hg_ok, 0.0, weight)
    delta_lobe = ~use_hg & mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
    weight = dr.select(delta_lobe, bsdf_w / (1.0 - alpha), weight)
    eta = dr.select(use_hg, 1.0, bs.eta)
    return si_next, weight, eta, active & si_next.is_valid()


def _sensor_weight(c: KernelConstants, d, dist2):
    """``W0 = A_ap cos(theta_ap) A_pix cos(theta_q) / |q - D|^2`` (m^2 sr) for the direction ``d`` from the
    detector to the patch point ``q`` at squared distance ``dist2`` (m^2); 0 behind the aperture."""
    return c.aperture_area_m2 * dr.maximum(dr.dot(d, c.aperture_normal), 0.0) * c.pixel_area_m2 * \
        dr.abs(dr.dot(d, c.wall_normal)) / dist2


@dr.syntax
def nlos_pass(scene, hist, rng, layout, j0, j1, c: KernelConstants, ks: KernelScene):
    """Trace the samples ``[j0, j1)`` of every lane (``k + j K``, :class:`~._lanes.LaneLayout`) and record
    their contributions in ``hist`` (a group histogram, one sub-slot per spot); returns the PCG32 state.
    """
    hidden_ptrs, distr, wall_ptr, group = ks.hidden_ptrs, ks.hidden_distr, ks.wall_ptr, ks.group
    K = layout.streams
    lanes = lane_pixels(c, layout)
    lane, pixel, k, centre = lanes[0], lanes[1], lanes[2], lanes[3]

    # ---- confocal: the laser spot of every lane is its own patch centre
    spot = None
    if dr.hint(c.confocal, mode="scalar"):
        laser_ray = mi.Ray3f(c.laser_origin, dr.normalize(centre - c.laser_origin))
        if dr.hint(c.divergent, mode="scalar"):  # every connection samples its spot around the axis
            spot = (laser_ray.d,)
        elif dr.hint(c.windows, mode="scalar"):
            si_s, thr_s, opl_s = trace_leg(scene, laser_ray.o, laser_ray.d)
            si_s.t = opl_s  # what the record adds for the laser leg
            spot = (si_s, si_s.bsdf(), thr_s)
        else:
            si_s = scene.ray_intersect(laser_ray, ray_flags=mi.RayFlags.All, coherent=True)
            spot = (si_s, si_s.bsdf())

    # ---- randomised QMC: an R_d sequence over the pixel's samples, shifted at random per pixel
    qmc = PixelQMC(c, pixel)

    # ---- patch centre only: the wall point (vertex 1) is the same for every sample
    if dr.hint(c.patch_center_only, mode="scalar"):
        if dr.hint(c.spot_is_wall_point, mode="scalar"):
            si_c = dr.detach(spot[0])  # the laser spot itself, seen from the detector
            to_c = si_c.p - c.detector
            si_c.wi = si_c.to_local(-dr.normalize(to_c))
        elif dr.hint(c.windows, mode="scalar"):
            si_c, thr_c, opl_leg_c = trace_leg(scene, c.detector, dr.normalize(centre - c.detector))
        else:
            si_c = scene.ray_intersect(mi.Ray3f(c.detector, dr.normalize(centre - c.detector)),
                                       ray_flags=mi.RayFlags.All, coherent=True)
        to_c = centre - c.detector
        w0_c = _sensor_weight(c, dr.normalize(to_c), dr.squared_norm(to_c))
        if dr.hint(c.windows, mode="scalar"):
            w0_c = w0_c * thr_c  # radiance through the windows: times their transmittance
            opl_c = c.first_last_factor * opl_leg_c
        else:
            opl_c = c.first_last_factor * dr.norm(si_c.p - c.detector)

    j = mi.UInt32(dr.opaque(mi.UInt32, j0))
    j_end = dr.opaque(mi.UInt32, j1)
    spp = dr.opaque(mi.UInt32, layout.spp)
    ctx = mi.BSDFContext()
    deeper = c.max_depth_static > 4

    while (j < j_end) & (k + j * K < spp):
        i_sample = k + j * K
        u = qmc.numbers(c, rng, i_sample)
        # ---- patch point p (vertex 1) and the sensor weight
        if dr.hint(c.patch_center_only, mode="scalar"):
            si = si_c
            w0 = w0_c
            opl = opl_c
        else:
            q = centre + (u[0] - 0.5) * c.footprint_x + (u[1] - 0.5) * c.footprint_y
            to_q = q - c.detector
            dist_q = dr.norm(to_q)
            d0 = to_q / dist_q
            w0 = _sensor_weight(c, d0, dr.square(dist_q))
            if dr.hint(c.windows, mode="scalar"):  # through the windows: transmittance and optical length
                si, thr_d, opl_d = trace_leg(scene, c.detector, d0)
                w0 = w0 * thr_d
                opl = c.first_last_factor * opl_d
            else:
                si = scene.ray_intersect(mi.Ray3f(c.detector, d0), ray_flags=mi.RayFlags.All, coherent=True)
                opl = c.first_last_factor * si.t
        active = si.is_valid()
        beta = mi.Spectrum(1.0)
        _connect_spots(scene, hist, lane, si, beta, w0, opl, mi.Int32(1), active, c, spot, group, wall_ptr, ctx,
                       rng=rng)

        # ---- vertex 2 by one-sample MIS, then its spot connection (three-bounce light)
        active &= 5 <= c.max_depth + 1  # i.e. max_depth >= 4
        si2, weight, eta, active = _first_bounce(scene, si, active, u[2:], rng, c, hidden_ptrs, distr, wall_ptr,
                                                 ctx)
        beta = beta * weight
        opl = opl + dr.norm(si2.p - si.p)
        if dr.hint(c.skip_three_bounce, mode="scalar"):
            pass  # the remainder of estimator=quadrature: the quadrature gives this connection
        elif dr.hint(c.spot_is_wall_point, mode="scalar"):
            # the segment vertex 2 -> spot is the segment just traced from the spot: visible
            _connect_spots(scene, hist, lane, si2, beta, w0, opl, mi.Int32(2), active, c, spot, group, wall_ptr,
                           ctx, visible=mi.Bool(True), rng=rng)
        else:
            _connect_spots(scene, hist, lane, si2, beta, w0, opl, mi.Int32(2), active, c, spot, group, wall_ptr,
                           ctx, rng=rng)

        # ---- further vertices: BSDF sampling, spot connections, Russian roulette
        if dr.hint(deeper, mode="scalar"):
            depth = mi.Int32(2)
            si = si2
            while active:
                active_next = active & (depth + 3 <= c.max_depth)
                bsdf = si.bsdf()
                bs, bsdf_w = bsdf.sample(ctx, si, rng.next_float32(), mi.Point2f(rng.next_float32(),
                                                                                 rng.next_float32()), active_next)
                ray = si.spawn_ray(si.to_world(bs.wo))
                si_next = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=False, active=active_next)
                beta *= bsdf_w
                eta *= bs.eta
                opl = opl + eta * dr.norm(si_next.p - si.p)  # the segment's medium: relative index eta
                depth += 1
                beta_max = dr.max(mi.unpolarized_spectrum(beta))
                rr_prob = dr.minimum(beta_max * dr.square(eta), 0.95)
                rr_active = (depth - 1) >= c.rr_depth
                rr_continue = rng.next_float32() < rr_prob
                beta[rr_active] *= dr.rcp(rr_prob)
                active = active_next & si_next.is_valid() & (~rr_active | rr_continue) & (beta_max > 0)
                _connect_spots(scene, hist, lane, si_next, beta, w0, opl, depth, active, c, spot, group, wall_ptr,
                               ctx, eta=eta, rng=rng)
                si = si_next
        j += 1
    return rng
