r"""Device legs of an NLOS capture through windows: the detector ray ``D -> wall`` and the laser ray
``L -> spot`` followed through delta-transmissive interfaces (and the spots of a divergent laser beam,
:func:`beam_spot`).

A *window* is a shape whose BSDF has no smooth component but transmits (``dielectric``,
``thindielectric``) or is a ``null`` boundary: a glass pane between the device (laser, SPAD array) and
the relay wall. :func:`trace_leg` follows a device ray deterministically along the **transmitted**
branch of every window it meets, up to :data:`MAX_INTERFACES` interfaces, and stops at the first
surface with a smooth BSDF component (the relay-wall point or laser spot; or any other surface, which
scene validation refuses in front of the wall). Per interface:

* the direction refracts (Snell's law, as the BSDF's delta sample with ``sample1`` picking the
  transmission lobe: ``dielectric`` refracts, ``thindielectric`` and ``null`` pass straight through);
* the leg's throughput is multiplied by the interface's transmittance ``T = bs.pdf * weight`` of that
  sample in importance transport (no ``eta^2`` radiance factor): ``T = 1 - R(theta_i)`` with ``R`` the
  unpolarised Fresnel reflectance of a smooth ``dielectric`` (times its ``specular_transmittance``);
  the total transmittance ``1 - R_total`` of a ``thindielectric`` (its internal reflections summed);
  1 for ``null``. Total internal reflection ends the leg (throughput 0);
* the optical path length grows by ``eta_i d_i``: the segment's length times the relative index
  ``eta`` of the medium it crosses (the product of the sampled ``bs.eta``, relative to the device's
  medium, as in :mod:`transient_mi.integrators._optical_path`). A ``thindielectric`` has no thickness
  and adds no delay.

Reflections at the windows (ghost spots and ghost patches, internal reflections inside a pane) are
**not rendered**: their relative amplitude is about ``R^2`` per pane and leg (``R = 0.04`` for
``n = 1.5``: 0.16 %), and they arrive at other places and times than the transmitted light.

Radiometry through a window (the pane in air on both sides, as the legs begin and end in the same
medium): radiance along a ray is multiplied by the transmittance ``T`` of each interface (the
``n^2`` factors of entering and leaving cancel); the laser's photons reaching the spot are ``T_L N``.
The detector's pixel sees the same cone of directions as without the window (its patch square in the
wall plane, seen from ``D``), so its patch is displaced by the pane's lateral offset; the point
source ``S`` of the wall's own return is seen through the window under a *generalised* geometry term:
with ``J = dA_wall / dOmega_D`` (wall area per solid angle at ``D``, of the detector leg towards
``S``; ``J = |S - D|^2 / cos(theta_S)`` without window), the photons reaching the aperture are
``T_L T_D N f_s cos(theta_S) A_ap cos(theta_ap) / (cos(theta_S) J)`` (étendue conservation,
``cos_S dA_S dOmega_S = cos_D dA_D dOmega_D``). :func:`leg_jacobian` evaluates ``J`` by central
differences of :func:`trace_leg` (relative error about ``1e-5`` in float32).

Units: metres; directions unit vectors in the world frame.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from transient_mi._upload import upload

#: Most window interfaces a device leg crosses (a pane has two); a leg still on a window after that many
#: is dropped (throughput 0).
MAX_INTERFACES = 8
#: ``sample1`` of the BSDF sample that picks the transmission lobe of a delta dielectric
#: (``dielectric`` / ``thindielectric`` reflect when ``sample1 <= R``).
_PICK_TRANSMISSION = 0.99999994
#: Half-angle (rad) of the central differences of :func:`leg_jacobian`.
JACOBIAN_EPS_RAD = 3e-3


def is_window_bsdf(bsdf) -> bool:
    """Host-side: ``bsdf`` is a window (no smooth component; delta transmission or ``null``)."""
    if bsdf is None:
        return False
    fl = int(bsdf.flags())
    smooth = int(mi.BSDFFlags.Smooth)
    passes = int(mi.BSDFFlags.DeltaTransmission) | int(mi.BSDFFlags.Null)
    return not (fl & smooth) and bool(fl & passes)


def has_smooth_component(bsdf) -> bool:
    """Host-side: ``bsdf`` has a smooth (non-delta) component, so a next-event connection can reach it."""
    return bsdf is not None and bool(int(bsdf.flags()) & int(mi.BSDFFlags.Smooth))


def window_shapes(scene) -> list:
    """The scene's window shapes (see :func:`is_window_bsdf`)."""
    return [s for s in scene.shapes() if is_window_bsdf(s.bsdf())]


def _continue_ray(si, d_world, d_local):
    """The ray leaving ``si`` along ``d_world``, its origin moved *along the ray* (not along the normal, as
    ``spawn_ray`` does: that would shift a refracted ray sideways by up to 1e-4 m) far enough from the
    surface for float32 (``1e-6 (1 + max|p|)`` m along the normal)."""
    cos_o = dr.maximum(dr.abs(mi.Frame3f.cos_theta(d_local)), 1e-3)
    step = 1e-6 * (1.0 + dr.max(dr.abs(si.p))) / cos_o
    return mi.Ray3f(si.p + step * d_world, d_world)


def _on_window(si, active):
    """Per lane: ``si`` lies on a window (no smooth component; delta transmission or null)."""
    fl = si.bsdf().flags()
    passes = mi.has_flag(fl, mi.BSDFFlags.DeltaTransmission) | mi.has_flag(fl, mi.BSDFFlags.Null)
    return active & si.is_valid() & ~mi.has_flag(fl, mi.BSDFFlags.Smooth) & passes


@dr.syntax
def trace_leg(scene, origin, direction, active=True):
    """Follow the device ray ``origin + t direction`` through windows to its first smooth surface.

    Parameters
    ----------
    origin : mi.Point3f
        Detector or laser position, m.
    direction : mi.Vector3f
        Unit direction of the leg's first segment.

    Returns
    -------
    (si, throughput, opl)
        ``si``: the surface interaction at the end of the leg (``si.wi`` along the last, refracted
        segment; ``si.t`` that segment's length only); ``throughput`` (mi.Float): the product of the
        interfaces' transmittances (0 when the leg ends on a window: more than :data:`MAX_INTERFACES`
        interfaces or total internal reflection); ``opl`` (mi.Float, m): the optical path length
        ``sum_i eta_i d_i`` from ``origin`` to the end point.
    """
    active = mi.Bool(active)
    ray = mi.Ray3f(mi.Point3f(origin), mi.Vector3f(direction))
    si = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=True, active=active)
    opl = dr.select(si.is_valid(), si.t, 0.0)
    thr = mi.Float(1.0)
    eta = mi.Float(1.0)
    n = mi.UInt32(0)
    ctx = mi.BSDFContext(mi.TransportMode.Importance)
    on_w = _on_window(si, active)
    while on_w & (n < MAX_INTERFACES):
        bsdf = si.bsdf()
        bs, w = bsdf.sample(ctx, si, _PICK_TRANSMISSION, mi.Point2f(0.5, 0.5), on_w)
        transmitted = mi.has_flag(bs.sampled_type, mi.BSDFFlags.DeltaTransmission) | \
            mi.has_flag(bs.sampled_type, mi.BSDFFlags.Null)
        t_val = dr.select(transmitted, bs.pdf * mi.unpolarized_spectrum(w)[0], 0.0)
        thr *= t_val
        eta *= dr.select(transmitted, bs.eta, 1.0)
        ray = _continue_ray(si, si.to_world(bs.wo), bs.wo)
        si_next = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=True, active=on_w & transmitted)
        opl += dr.select(si_next.is_valid(), eta * dr.norm(si_next.p - si.p), 0.0)
        si[on_w] = si_next
        n += 1
        on_w = _on_window(si, on_w & transmitted)
    thr = dr.select(_on_window(si, active) | ~si.is_valid(), 0.0, thr)
    return si, thr, opl


def beam_spot(scene, laser_origin, sigma, axis, rng, active, wavelengths):
    """A laser spot of a divergent beam around ``axis``: ``(si_s, bsdf_s, transmittance)``.

    The direction ``normalize(axis + sigma (x e1 + y e2))`` with ``x, y`` standard normal (from two PCG32
    numbers of ``rng``, :func:`mitsuba.warp.square_to_std_normal`; ``sigma`` in rad) has the beam's angular
    profile (``pulsed_laser`` ``divergence_mrad``), so the spot it hits is distributed like the beam's
    photons: using it for a spot connection is an unbiased estimate of the whole footprint's light. The
    leg is traced through windows (:func:`trace_leg`); ``si_s.t`` holds its optical path length.
    """
    g = mi.warp.square_to_std_normal(mi.Point2f(rng.next_float32(), rng.next_float32()))
    frame = mi.Frame3f(axis)
    d = dr.normalize(axis + sigma * (g.x * frame.s + g.y * frame.t))
    si_s, thr_s, opl_s = trace_leg(scene, laser_origin, d, active)
    si_s.t = opl_s
    si_s.wavelengths = wavelengths
    return si_s, si_s.bsdf(), thr_s


def leg_jacobian(scene, origin, direction, eps: float = JACOBIAN_EPS_RAD):
    """``J = dA / dOmega`` (m^2 / sr) of the leg map ``direction -> end point``, by central differences.

    ``J`` is the area on the end surface's tangent plane per unit solid angle at ``origin``: without any
    window ``J = t^2 / |cos(theta_end)|``. Host-side, vectorised: ``origin`` ``(3,)``, ``direction``
    ``(n, 3)`` unit vectors (numpy); returns ``J`` ``(n,)`` (float64; 0 where a perturbed leg fails).
    """
    d = np.asarray(direction, dtype=np.float64)
    n = len(d)
    helper = np.where(np.abs(d[:, 2:3]) < 0.9, np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]]))
    u = np.cross(d, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(d, u)
    dirs = np.concatenate([d + eps * u, d - eps * u, d + eps * v, d - eps * v])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    o = np.broadcast_to(np.asarray(origin, dtype=np.float64), dirs.shape)
    si, thr, _ = trace_leg(scene, mi.Point3f(*[upload(mi.Float, c) for c in o.T]),
                           mi.Vector3f(*[upload(mi.Float, c) for c in dirs.T]))
    p = np.stack([np.asarray(c.numpy(), dtype=np.float64) for c in si.p], axis=1)
    ok = np.asarray(si.is_valid().numpy(), dtype=bool) & (np.asarray(thr.numpy()) > 0)
    dpa = (p[:n] - p[n:2 * n]) / (2 * eps)
    dpb = (p[2 * n:3 * n] - p[3 * n:]) / (2 * eps)
    # the perturbed directions normalize(d + a u + b v) cover solid angle da db at a = b = 0
    J = np.linalg.norm(np.cross(dpa, dpb), axis=1)
    good = ok[:n] & ok[n:2 * n] & ok[2 * n:3 * n] & ok[3 * n:]
    return np.where(good, J, 0.0)


def trace_legs_np(scene, origins, directions) -> dict:
    """Host-side :func:`trace_leg` for numpy rays ``[n, 3]`` (directions need not be normalised).

    Returns numpy fields ``valid``, ``p``, ``n`` (geometric normal), ``throughput``, ``opl_m`` and the
    Dr.Jit ``shape`` pointers and surface interaction ``si`` (for BSDF evaluations at the end points).
    """
    o = np.asarray(origins, dtype=np.float64)
    d = np.asarray(directions, dtype=np.float64)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    si, thr, opl = trace_leg(scene, mi.Point3f(*[upload(mi.Float, c) for c in o.T]),
                             mi.Vector3f(*[upload(mi.Float, c) for c in d.T]))
    valid = np.asarray(si.is_valid().numpy(), dtype=bool)
    p = np.stack([np.asarray(c.numpy(), dtype=np.float64) for c in si.p], axis=1)
    nrm = np.stack([np.asarray(c.numpy(), dtype=np.float64) for c in si.n], axis=1)
    return {"valid": valid, "p": p, "n": nrm, "throughput": np.asarray(thr.numpy(), dtype=np.float64),
            "opl_m": np.asarray(opl.numpy(), dtype=np.float64), "shape": si.shape, "si": si}


def aim_through_windows(scene, origin, points, iterations: int = 12, tol_m: float = 1e-7):
    """Directions from ``origin`` whose legs (through the windows) end at ``points`` ``[n, 3]``.

    Fixed-point iteration on the aim point: aim at ``a``, the leg ends at ``p(a)``, move ``a`` by
    ``points - p(a)`` (exact in one step for a plane-parallel pane, whose lateral offset depends on the
    direction only weakly). Returns ``(directions [n, 3], residual_m [n])``.
    """
    pts = np.asarray(points, dtype=np.float64)
    o = np.asarray(origin, dtype=np.float64)
    aim = pts.copy()
    res = np.full(len(pts), np.inf)
    for _ in range(iterations):
        legs = trace_legs_np(scene, np.broadcast_to(o, aim.shape), aim - o)
        err = pts - legs["p"]
        res = np.where(legs["valid"], np.linalg.norm(err, axis=1), np.inf)
        if np.all(res <= tol_m):
            break
        aim = aim + np.where(legs["valid"][:, None], err, 0.0)
    d = aim - o
    return d / np.linalg.norm(d, axis=1, keepdims=True), res
