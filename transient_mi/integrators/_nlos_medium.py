r"""NLOS captures through a homogeneous medium (fog): the medium's constants and the Dr.Jit kernel
(:func:`nlos_medium_pass`).

``transient_volpath`` under a ``spad_array`` whose sensor medium is a ``homogeneous`` medium (the fog
filling the scene: laser, detector, relay wall and hidden geometry all sit in it) renders the capture with
this kernel; without a sensor medium the NLOS renderer runs the surface kernel
(:mod:`transient_mi.integrators._nlos_kernel`) unchanged. The radiometry of the surface estimator
(:mod:`transient_mi.integrators.transient_nlos_path`) carries over; every segment is attenuated by
``exp(-sigma_t d)``, and the medium adds volume vertices and the laser beam as a light source.

Estimator (unbiased)
--------------------
``sigma_t`` (1/m) and ``sigma_s = albedo sigma_t`` are the medium's coefficients, ``rho(w_i, w_o)`` its
phase function (1/sr; Mitsuba's convention, ``w_i`` pointing back along the path), ``N`` the photons per
pulse, ``L`` the laser origin, ``S`` the lane's laser spot, ``l = |L - S|``, ``w_L = (S - L) / l``.

* **Free flights.** Every traced segment (the detector ray ``D -> q`` through the pixel's patch, and
  every BSDF-, phase- or hidden-geometry-sampled segment after it) samples a distance
  ``t ~ sigma_t exp(-sigma_t t)`` (``Medium.sample_interaction``'s distribution for homogeneous media).
  If ``t`` is shorter than the distance ``d`` to the first surface the path continues from the medium
  vertex ``x + t w`` with its throughput times ``sigma_s / sigma_t`` (the albedo); otherwise (probability
  ``exp(-sigma_t d)``, which cancels the segment's transmittance) from the surface; a ray that leaves the
  scene always gets a medium vertex (the fog is infinite). The detector ray's radiance is so estimated
  as ``int_0^d T(t) sigma_s L_s dt + T(d) L(p)``: the same sensor weight ``W0`` serves both terms.
* **Hidden-geometry MIS at the wall point** (as without a medium): the direction leaving the wall point
  is drawn by the one-sample mixture of hidden-geometry and BSDF sampling, its weight
  ``f cos / (alpha p_hidden(w) + (1 - alpha) p_bsdf(w))`` with ``p_hidden`` computed from the *first
  surface* along ``w`` (the density of the directions of the un-occluded hidden samples); the free
  flight is then drawn along ``w``. The weight depends on the direction only, so it is a valid
  direction-sampling estimator of the whole incident radiance (surface and volume parts) along ``w``:
  a medium vertex before the hidden point changes nothing in the pdfs.
* **Medium vertices** continue by phase-function sampling (weight ``rho / pdf``, 1 for the phase
  functions Mitsuba samples exactly); surface vertices by BSDF sampling, as without a medium.
  ``max_depth`` counts every segment from the detector to the laser, medium vertices included
  (``volpath``'s meaning: ``D - M - S - L`` and ``D - M - B - L`` have depth 3); Russian roulette as the
  surface kernel.
* **Next-event estimation from every vertex** ``X`` (wall point, hidden surface vertices, medium
  vertices; ``f_X`` is ``f cos`` on a surface, ``rho`` in the medium):

  (a) to the laser spot: ``beta W0 f_X(w_XS) f_s(S) cos_S / |S - X|^2 exp(-sigma_t (|X - S| + l)) V``
      (the surface connection times the transmittance of both segments), at path length
      ``opl + |X - S| + l``;
  (b) to the laser **beam**: the beam loses ``N sigma_s exp(-sigma_t s) ds`` photons into scattering
      on ``[s, s + ds]``, radiated with the intensity ``rho(-w_L, w)`` per photon. A point
      ``B = L + s w_L``, ``s`` in ``[0, l]``, is drawn by *equiangular sampling* (Kulla and Fajardo
      2012): with ``s0 = (X - L) . w_L`` and ``h`` the distance from ``X`` to the beam line,
      ``pdf(s) = h / ((theta_b - theta_a) r^2)``, ``r = |B - X|``, ``theta_a = atan(-s0 / h)``,
      ``theta_b = atan((l - s0) / h)``, which cancels the ``1 / r^2`` of the connection. Contribution
      ``beta W0 f_X(w_XB) sigma_s rho(-w_L, w_BX) exp(-sigma_t (s + r)) (theta_b - theta_a) / h V(X, B)``
      (times ``N``), at path length ``opl + r + s``. From the detector ray's own medium vertex this is
      the fog's single backscatter of the beam into the pixel, the dominant fog return of real
      captures. A wall point on the beam line (``h = 0``: only with ``pixel_sampling="center"`` when a
      patch centre is a laser spot) sees an infinitely thin beam end-on, whose irradiance is infinite:
      that connection is left out (a real beam has a width).

  (a) reaches a point and (b) a line that no sampled path can hit, so neither needs an MIS weight.
* **Wall return** ``L -> S -> D`` in closed form, times ``exp(-sigma_t (l + |S - D|))``.
* **Time.** Media have ``n = 1``: every segment counts its length; time zero is the pulse leaving the
  laser. ``include_first_last`` must be true (the detector and laser legs have no wall-relative meaning
  when light scatters before reaching the wall).
* **Random numbers.** The surface path draws from the same streams as the surface kernel (the QMC patch
  point and first bounce, PCG32 for deeper bounces and Russian roulette); the medium's numbers (free
  flights, phase directions, beam points) come from a second PCG32 stream per lane and kernel launch. As
  ``sigma_t -> 0`` (no medium vertex, transmittances round to 1) the capture so equals the clear one
  sample by sample, up to float rounding of the vanishing beam term.

Supported: a ``homogeneous`` medium as the sensor's medium with any Mitsuba phase function; extinction
equal in every colour channel (the albedo may vary). Refused in one line: heterogeneous media, media inside
shapes (``interior`` / ``exterior``), ``include_first_last=false``.
"""

from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from transient_mi.integrators._lanes import to_mono
from transient_mi.integrators._nlos_kernel import _first_bounce, _of, _sensor_weight, gather_spot
from transient_mi.integrators._nlos_samples import PixelQMC, lane_pixels
from transient_mi.integrators._optical_path import segment_index
from transient_mi.props import PluginParameterError

#: Salt of the medium's PCG32 streams (decorrelates them from the surface streams of the same seed).
MEDIUM_STREAM_SALT = 0x6A09E667
#: A wall point closer than this (m) to the beam line sees the beam end-on: no beam connection (see above).
BEAM_LINE_EPS_M = 1e-6


@dataclass
class NLOSMedium:
    """The homogeneous medium an NLOS capture is rendered through (host values, validated).

    ``sigma_t``: extinction (1/m, one value); ``sigma_s``: scattering coefficient per colour channel (1/m);
    ``phase``: the medium's phase function object; ``medium``: the Mitsuba medium.
    """

    medium: object
    sigma_t: float
    sigma_s: tuple
    phase: object

    @property
    def albedo(self) -> tuple:
        return tuple(s / self.sigma_t if self.sigma_t > 0 else 0.0 for s in self.sigma_s)

    @classmethod
    def from_sensor(cls, scene, sensor, setup, plugin: str) -> "NLOSMedium | None":
        """The sensor's medium (None without one), refused in one line where the estimator does not apply."""
        medium = sensor.get_medium()
        if medium is None:
            return None
        mid = medium.id() or type(medium).__name__
        if not medium.is_homogeneous():
            raise PluginParameterError(
                f"{plugin}: the spad_array's medium {mid!r} is heterogeneous; NLOS captures support a "
                "homogeneous medium only (heterogeneous media: camera sensors)")
        for shape in scene.shapes():
            if shape.interior_medium() is not None or shape.exterior_medium() is not None:
                raise PluginParameterError(
                    f"{plugin}: shape {shape.id()!r} has an interior/exterior medium; NLOS captures support "
                    "one homogeneous medium filling the scene (the spad_array's), not media inside shapes")
        if not setup.include_first_last:
            raise PluginParameterError(
                f"{plugin}: include_first_last=false with the medium {mid!r}; NLOS captures through a medium "
                "need include_first_last=true (light scattered before the wall has no wall-relative time)")
        if setup.windows:
            raise PluginParameterError(
                f"{plugin}: the scene has a window (a shape with a purely delta-transmissive or null BSDF) and "
                f"the medium {mid!r}; NLOS captures through a medium do not follow the device legs through "
                "windows (render the window scene without the medium, with transient_nlos_path)")
        if setup.laser.divergence_mrad > 0:
            raise PluginParameterError(
                f"pulsed_laser: divergence_mrad={setup.laser.divergence_mrad:g} with the medium {mid!r}; NLOS "
                "captures through a medium need a collimated beam (divergence_mrad=0)")
        mei = dr.zeros(mi.MediumInteraction3f, 1)
        sig_s, _, sig_t = medium.get_scattering_coefficients(mei)
        st = np.asarray(mi.unpolarized_spectrum(sig_t), dtype=np.float64).ravel()
        ss = np.asarray(mi.unpolarized_spectrum(sig_s), dtype=np.float64).ravel()
        if np.ptp(st) > 1e-6 * max(float(st.max()), 1e-30):
            raise PluginParameterError(
                f"{plugin}: the medium {mid!r} has sigma_t={st.tolist()} varying with colour; NLOS captures "
                "need the same extinction in every channel (the albedo may vary)")
        return cls(medium=medium, sigma_t=float(st[0]), sigma_s=tuple(float(v) for v in ss),
                   phase=medium.phase_function())

    def manifest_entry(self) -> dict:
        """What the capture's manifest records about the medium (``geometry.medium``): its extinction and
        single-scattering albedo (per colour channel) and its phase function, so a reconstruction can
        compensate the attenuation."""
        return {"type": "homogeneous", "id": self.medium.id() or None, "sigma_t_per_m": self.sigma_t,
                "albedo": list(self.albedo), "phase": str(self.phase).split("[", 1)[0].strip(),
                "phase_description": " ".join(str(self.phase).split())}

    def wall_return(self, setup) -> dict:
        """The closed-form wall return of ``setup`` attenuated along ``L -> S -> D`` (``opl_m`` is that length:
        ``include_first_last`` is true)."""
        wr = dict(setup.wall_return)
        wr["photons"] = wr["photons"] * np.exp(-self.sigma_t * wr["opl_m"])
        return wr


@dataclass
class MediumConstants:
    """What the kernel reads about the medium: opaque Dr.Jit values (one compiled kernel for every
    coefficient) and the phase function."""

    sigma_t: "mi.Float"
    sigma_s: "mi.Spectrum"
    albedo: "mi.Spectrum"
    phase: object

    @classmethod
    def build(cls, fog: NLOSMedium) -> "MediumConstants":
        def spec(vals):
            return mi.Spectrum(*[_of(v) for v in vals]) if len(vals) > 1 else mi.Spectrum(_of(vals[0]))
        return cls(sigma_t=_of(fog.sigma_t), sigma_s=spec(fog.sigma_s), albedo=spec(fog.albedo), phase=fog.phase)


def _mei(p, wi, wavelengths):
    """A medium interaction at ``p`` with ``wi`` (world, pointing back along the path) for the phase function."""
    mei = dr.zeros(mi.MediumInteraction3f)
    mei.p = mi.Point3f(p)
    mei.wi = mi.Vector3f(wi)
    mei.sh_frame = mi.Frame3f(mei.wi)
    mei.wavelengths = wavelengths
    mei.t = mi.Float(0.0)
    return mei


def _shadow_ray(si, med, xm, target):
    """The shadow ray from the vertex (surface ``si``, or the medium point ``xm`` where ``med``) to ``target``."""
    ray_s = si.spawn_ray_to(target)
    to_t = target - xm
    dist = dr.norm(to_t)
    ray_m = mi.Ray3f(xm, to_t / dist, dist * (1.0 - mi.math.ShadowEpsilon), si.time, si.wavelengths)
    return mi.Ray3f(dr.select(med, ray_m.o, ray_s.o), dr.select(med, ray_m.d, ray_s.d),
                    dr.select(med, ray_m.maxt, ray_s.maxt), si.time, si.wavelengths)


def _vertex_f(si, bsdf, med, xm, wim, d, active, ctx, mc):
    """``f_X`` for the direction ``d`` (world) leaving the vertex: ``f cos`` on a surface, the phase function
    in the medium."""
    f_s = mi.Spectrum(bsdf.eval(ctx, si, si.to_local(d), active & ~med))
    f_m, _ = mc.phase.eval_pdf(mi.PhaseFunctionContext(), _mei(xm, wim, si.wavelengths), d, active & med)
    return dr.select(med, mi.Spectrum(f_m), f_s)


def _connect_one(scene, hist, lane, si, bsdf, med, xm, wim, beta, w0, opl, active, c, mc, si_s, bsdf_s, sub,
                 u_beam, wall_ptr, ctx, eta=None):
    """Connect the vertex to the spot ``si_s`` (a) and to its laser beam (b); record in sub-slot ``sub``.

    ``eta``: the relative index the path is in (None: 1), as :func:`~._nlos_kernel._connect_one` (a
    connection transmitting through a rough dielectric runs at its far side's index)."""
    x = dr.select(med, xm, si.p)
    # ---- (a) the laser spot
    spot_p = si_s.p
    to_s = spot_p - x
    dist_s = dr.norm(to_s)
    d_s = to_s / dist_s
    f_x = _vertex_f(si, bsdf, med, xm, wim, d_s, active, ctx, mc)
    i_s = bsdf_s.eval(ctx, si_s, si_s.to_local(-d_s), active)
    tr = dr.exp(-mc.sigma_t * (dist_s + si_s.t))
    val = to_mono(beta * f_x * i_s, si.wavelengths) * (w0 * tr / dr.square(dist_s))
    path_s = dist_s
    if eta is not None:
        path_s = dr.select(med, eta, segment_index(bsdf, si, si.to_local(d_s), eta, active & ~med)) * dist_s
    ok = active & (val > 0) & si_s.is_valid()
    if c.planar_wall:  # a wall point and a spot on the same plane: cos(theta_S) = 0 exactly
        ok &= med | (si.shape != wall_ptr)
    ok &= ~scene.ray_test(_shadow_ray(si, med, xm, spot_p), ok)
    hist.record(lane, opl + path_s + si_s.t, val, ok, sub=sub)

    # ---- (b) the beam L -> S: equiangular sampling of the beam point B
    ell = si_s.t
    w_l = (spot_p - c.laser_origin) / ell
    rel = x - c.laser_origin
    s0 = dr.dot(rel, w_l)
    h = dr.norm(rel - s0 * w_l)
    hs = dr.maximum(h, 1e-30)
    th_a = dr.atan2(-s0, hs)
    th_b = dr.atan2(ell - s0, hs)
    s = dr.clip(s0 + hs * dr.tan(th_a + u_beam * (th_b - th_a)), 0.0, ell)
    b = c.laser_origin + s * w_l
    to_b = b - x
    r = dr.norm(to_b)
    d_b = to_b / r
    f_xb = _vertex_f(si, bsdf, med, xm, wim, d_b, active, ctx, mc)
    rho_b, _ = mc.phase.eval_pdf(mi.PhaseFunctionContext(), _mei(b, -w_l, si.wavelengths), -d_b, active)
    inv = (th_b - th_a) / hs  # 1 / (pdf(s) r^2)
    val_b = to_mono(beta * f_xb * mc.sigma_s * mi.Spectrum(rho_b), si.wavelengths) * \
        (w0 * dr.exp(-mc.sigma_t * (s + r)) * inv)
    ok_b = active & si_s.is_valid() & (h > BEAM_LINE_EPS_M) & (val_b > 0) & dr.isfinite(val_b)
    ok_b &= ~scene.ray_test(_shadow_ray(si, med, xm, b), ok_b)
    path_b = r
    if eta is not None:
        path_b = dr.select(med, eta, segment_index(bsdf, si, si.to_local(d_b), eta, active & ~med)) * r
    hist.record(lane, opl + path_b + s, val_b, ok_b, sub=sub)


@dr.syntax
def _connect(scene, hist, lane, si, med, xm, wim, beta, w0, opl, depth, active, c, mc, spot, group, wall_ptr,
             rng_m, ctx, eta=None):
    """Next-event estimation from the vertex to the laser spot(s) and beam(s) of the lane (see module);
    ``eta`` as :func:`_connect_one`."""
    bsdf = si.bsdf()
    active_nee = active & (depth + 2 <= c.max_depth) & (med | mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth))
    if dr.hint(group is None, mode="scalar"):
        _connect_one(scene, hist, lane, si, bsdf, med, xm, wim, beta, w0, opl, active_nee, c, mc, spot[0],
                     spot[1], mi.UInt32(0), rng_m.next_float32(), wall_ptr, ctx, eta)
        return
    b = mi.UInt32(0)
    while active_nee & (b < c.n_group_spots):
        spot_b = gather_spot(group, b, active_nee & (b < c.n_group_spots), si.wavelengths)
        si_s = spot_b[0]
        bsdf_s = spot_b[1]
        _connect_one(scene, hist, lane, si, bsdf, med, xm, wim, beta, w0, opl, active_nee, c, mc, si_s, bsdf_s,
                     b, rng_m.next_float32(), wall_ptr, ctx, eta)
        b += 1


def _free_flight(u, sigma_t):
    """A distance ``t ~ sigma_t exp(-sigma_t t)`` (m) from the uniform ``u`` (``u = 0``: infinite)."""
    return -dr.log(u) / sigma_t


def _medium_rng(c, layout, j0):
    """The medium's PCG32 stream per lane for the launch starting at sample ``j0`` (see module)."""
    lane = dr.arange(mi.UInt32, layout.n_lanes)
    idx = lane + dr.opaque(mi.UInt32, j0) * dr.opaque(mi.UInt32, layout.n_lanes)
    v0, v1 = mi.sample_tea_32(c.seed ^ mi.UInt32(MEDIUM_STREAM_SALT), idx)
    rng = mi.PCG32()
    rng.seed(v0, v1)
    return rng


@dr.syntax
def nlos_medium_pass(scene, hist, rng, layout, j0, j1, c, ks, mc: MediumConstants):
    """The samples ``[j0, j1)`` of every lane through the medium ``mc``; as
    :func:`~._nlos_kernel.nlos_pass` (same arguments, same lanes and streams) for the estimator of this
    module. Returns the (surface) PCG32 state."""
    hidden_ptrs, distr, wall_ptr, group = ks.hidden_ptrs, ks.hidden_distr, ks.wall_ptr, ks.group
    rng_m = _medium_rng(c, layout, j0)
    K = layout.streams
    lanes = lane_pixels(c, layout)
    lane, pixel, k, centre = lanes[0], lanes[1], lanes[2], lanes[3]

    spot = None
    if dr.hint(c.confocal, mode="scalar"):
        laser_ray = mi.Ray3f(c.laser_origin, dr.normalize(centre - c.laser_origin))
        si_s = scene.ray_intersect(laser_ray, ray_flags=mi.RayFlags.All, coherent=True)
        spot = (si_s, si_s.bsdf())

    qmc = PixelQMC(c, pixel)

    if dr.hint(c.patch_center_only, mode="scalar"):
        if dr.hint(c.spot_is_wall_point, mode="scalar"):
            si_c = dr.detach(spot[0])
            to_c = si_c.p - c.detector
            si_c.wi = si_c.to_local(-dr.normalize(to_c))
        else:
            si_c = scene.ray_intersect(mi.Ray3f(c.detector, dr.normalize(centre - c.detector)),
                                       ray_flags=mi.RayFlags.All, coherent=True)
        to_c = centre - c.detector
        w0_c = _sensor_weight(c, dr.normalize(to_c), dr.squared_norm(to_c))
        dist_c = dr.norm(si_c.p - c.detector)
        d0_c = (si_c.p - c.detector) / dist_c

    j = mi.UInt32(dr.opaque(mi.UInt32, j0))
    j_end = dr.opaque(mi.UInt32, j1)
    spp = dr.opaque(mi.UInt32, layout.spp)
    ctx = mi.BSDFContext()
    pctx = mi.PhaseFunctionContext()
    deeper = c.max_depth_static > 4

    while (j < j_end) & (k + j * K < spp):
        i_sample = k + j * K
        u = qmc.numbers(c, rng, i_sample)
        # ---- vertex 1: a medium vertex on the detector ray, or the patch point p
        if dr.hint(c.patch_center_only, mode="scalar"):
            si = si_c
            w0 = w0_c
            d_wall = dist_c
            d0 = d0_c
        else:
            q = centre + (u[0] - 0.5) * c.footprint_x + (u[1] - 0.5) * c.footprint_y
            to_q = q - c.detector
            dist_q = dr.norm(to_q)
            d0 = to_q / dist_q
            w0 = _sensor_weight(c, d0, dr.square(dist_q))
            si = scene.ray_intersect(mi.Ray3f(c.detector, d0), ray_flags=mi.RayFlags.All, coherent=True)
            d_wall = si.t
        t1 = _free_flight(rng_m.next_float32(), mc.sigma_t)
        med = t1 < d_wall
        xm = c.detector + dr.minimum(t1, d_wall) * d0
        wim = -d0
        active = si.is_valid() | med
        beta = mi.Spectrum(1.0)
        beta[med] = mc.albedo
        opl = dr.select(med, t1, d_wall)
        _connect(scene, hist, lane, si, med, xm, wim, beta, w0, opl, mi.Int32(1), active, c, mc, spot, group,
                 wall_ptr, rng_m, ctx)

        # ---- vertex 2: from the wall point by one-sample MIS, from a medium vertex by phase sampling
        active &= 5 <= c.max_depth + 1  # i.e. max_depth >= 4
        si2, weight, eta, _ = _first_bounce(scene, si, active & ~med, u[2:], rng, c, hidden_ptrs, distr,
                                            wall_ptr, ctx)
        from_m = active & med
        wo_m, ph_w, _ = mc.phase.sample(pctx, _mei(xm, wim, si.wavelengths), rng_m.next_float32(),
                                        mi.Point2f(rng_m.next_float32(), rng_m.next_float32()), from_m)
        ray_m = mi.Ray3f(xm, wo_m)
        si_m = scene.ray_intersect(ray_m, ray_flags=mi.RayFlags.All, coherent=False, active=from_m)
        si2[from_m] = si_m
        weight[from_m] = mi.Spectrum(ph_w)
        eta[from_m] = 1.0
        x1 = dr.select(med, xm, si.p)
        d2 = dr.select(si2.is_valid(), -si2.to_world(si2.wi), -si2.wi)  # the traced direction
        seg = dr.select(si2.is_valid(), dr.norm(si2.p - x1), dr.inf)
        t2 = _free_flight(rng_m.next_float32(), mc.sigma_t)
        med = t2 < seg
        xm = x1 + t2 * d2
        wim = -d2
        beta = beta * weight
        beta[med] *= mc.albedo
        active &= (med | si2.is_valid()) & (dr.max(mi.unpolarized_spectrum(weight)) > 0)
        opl = opl + eta * dr.select(med, t2, seg)
        si = si2
        _connect(scene, hist, lane, si, med, xm, wim, beta, w0, opl, mi.Int32(2), active, c, mc, spot, group,
                 wall_ptr, rng_m, ctx)

        # ---- further vertices: BSDF or phase sampling, free flights, connections, Russian roulette
        if dr.hint(deeper, mode="scalar"):
            depth = mi.Int32(2)
            while active:
                active_next = active & (depth + 3 <= c.max_depth)
                bsdf = si.bsdf()
                bs, bsdf_w = bsdf.sample(ctx, si, rng.next_float32(), mi.Point2f(rng.next_float32(),
                                                                                 rng.next_float32()),
                                         active_next & ~med)
                ph_next = active_next & med
                wo_m, ph_w, _ = mc.phase.sample(pctx, _mei(xm, wim, si.wavelengths), rng_m.next_float32(),
                                                mi.Point2f(rng_m.next_float32(), rng_m.next_float32()), ph_next)
                ray_s = si.spawn_ray(si.to_world(bs.wo))
                ray = mi.Ray3f(dr.select(med, xm, ray_s.o), dr.select(med, wo_m, ray_s.d))
                si_next = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=False, active=active_next)
                x_prev = dr.select(med, xm, si.p)
                beta *= dr.select(med, mi.Spectrum(ph_w), bsdf_w)
                eta *= dr.select(med, 1.0, bs.eta)
                seg = dr.select(si_next.is_valid(), dr.norm(si_next.p - x_prev), dr.inf)
                t_n = _free_flight(rng_m.next_float32(), mc.sigma_t)
                med_n = t_n < seg
                xm = x_prev + t_n * ray.d
                wim = -ray.d
                beta[med_n] *= mc.albedo
                opl = opl + eta * dr.select(med_n, t_n, seg)
                depth += 1
                beta_max = dr.max(mi.unpolarized_spectrum(beta))
                rr_prob = dr.minimum(beta_max * dr.square(eta), 0.95)
                rr_active = (depth - 1) >= c.rr_depth
                rr_continue = rng.next_float32() < rr_prob
                beta[rr_active] *= dr.rcp(rr_prob)
                active = active_next & (med_n | si_next.is_valid()) & (~rr_active | rr_continue) & (beta_max > 0)
                med = med_n
                si = si_next
                _connect(scene, hist, lane, si, med, xm, wim, beta, w0, opl, depth, active, c, mc, spot, group,
                         wall_ptr, rng_m, ctx, eta=eta)
        j += 1
    return rng
