r"""The NLOS estimator: photons per laser pulse reaching each SPAD pixel, per time bin.

This module holds the scene analysis of an NLOS capture (:class:`NLOSSetup`:
relay wall, hidden geometry, laser spots, pixel patches, validation) and the
vectorised path tracer used by the ``spad_array`` sensor (:func:`render_spot`).

Radiometry (what one bin of an ideal capture holds)
---------------------------------------------------
All quantities are per laser pulse; distances in metres.

1. Photons per pulse: ``N = E_pulse / (h c / lambda)``
   (:func:`transient_core.units.photons_per_pulse`).
2. The beam hits the wall at the laser spot ``S`` (first surface hit by the
   ray from the laser origin ``L`` towards the scan point). All ``N``
   photons arrive at ``S``; the wall re-emits them like a point source of
   radiant intensity (photons per steradian)
   ``I(w) = N f_s(S; w_L, w) cos(theta_S(w))``, with ``f_s`` the wall's
   BSDF (1/sr) and ``w_L`` the direction back to the laser. (Mitsuba's
   ``bsdf.eval`` with ``si.wi`` towards the laser returns ``f_s cos``.)
3. A surface point ``X`` with normal ``n_X`` receives the irradiance (photons
   per m^2) ``E(X) = I(w_SX) cos(theta_X) / |S - X|^2`` (if ``S`` and ``X``
   see each other) and scatters radiance
   ``L(X, w_o) = f_X(w_XS, w_o) E(X)``. Further bounces follow the
   rendering equation.
4. SPAD pixel ``k`` is focused on its wall patch ``A_k`` (a square of side
   ``pixel_footprint_m`` in the wall plane; on a non-planar wall, the part
   of the surface seen through that square from the detector ``D``). It
   collects the light leaving each patch point ``p`` towards the aperture,
   a disc of area ``A_ap = pi (aperture_diameter_m / 2)^2`` at ``D`` facing
   the array's ``target``, which subtends the solid angle
   ``A_ap cos(theta_ap) / |p - D|^2``. The ideal capture is
   ``Phi_k = int_{A_k} L(p, w_pD) cos(theta_p) A_ap cos(theta_ap) / |p - D|^2 dA_p``
   (photons), resolved by arrival time.
5. Arrival time: the optical path length of the whole path divided by c,
   time zero being the pulse leaving the laser. With
   ``include_first_last=false`` the first (``|L - S|``) and last
   (``|p - D|``) segments are left out of the recorded path length (the
   actual sampled segments).
6. The wall's own first-bounce return (``L -> S -> D``) is a delta in space
   and time: the pixel whose patch contains ``S`` receives
   ``N f_s(S; w_L, w_SD) cos(theta_S) A_ap cos(theta_ap) / |S - D|^2``
   photons at path length ``|L - S| + |S - D|`` (0 without first/last),
   added in closed form (no sampling noise); ``include_wall_return=false``
   leaves it out.

Estimator (unbiased)
--------------------
Per sample, for the lane's pixel ``k`` (and its laser spot ``S``: the
array's current spot, or in confocal mode the spot on patch ``k``):

* **Patch sampling.** ``q`` uniform on the planar square patch (pdf
  ``1/A_pix``); ``p`` = first surface hit of the ray ``D -> q``. In the
  solid angle from ``D``, ``dA_q cos(theta_q)/|q - D|^2 = dA_p cos(theta_p)/|p - D|^2``,
  so the sensor weight is ``W0 = A_ap cos(theta_ap) A_pix cos(theta_q) / |q - D|^2``
  and ``W0 L(p, w_pD)`` is an unbiased estimate of ``Phi_k``.
* **Laser-spot connection (next-event estimation).** At every path vertex
  ``X`` (the patch point included) the spot is connected deterministically:
  contribution ``beta W0 f_X(w_i, w_XS) cos(theta_X) I(w_SX) / |S - X|^2 V(X, S)``,
  recorded at the path's length plus ``|X - S|``. ``S`` is a point, so no
  other strategy can reach it: no MIS weight is needed.
* **Next direction at the patch point: one-sample MIS** between BSDF
  sampling (probability ``1 - alpha``) and hidden-geometry sampling
  (probability ``alpha``, parameter ``hidden_geometry_prob`` of
  ``transient_path``): a hidden shape is chosen in proportion to its area
  and a point ``X`` uniformly on it (area pdf ``1/A_hidden`` for every
  hidden point), as in Royo et al. 2022, "Non-line-of-sight transient
  rendering". The ray towards ``X`` is traced; if its first hit is not
  ``X`` (occluded) the sample contributes nothing. Either way the
  continuation vertex ``Y`` is weighted with the balance heuristic,
  ``f cos / (alpha p_hidden(w) + (1 - alpha) p_bsdf(w))`` with
  ``p_hidden(w) = |Y - p|^2 / (|cos theta_Y| A_hidden)`` when ``Y`` lies on
  hidden geometry and 0 otherwise. This one-sample MIS estimator is
  unbiased wherever BSDF sampling alone is (``alpha < 1``); with
  ``alpha = 1`` paths whose second vertex is on the relay wall (impossible
  on a planar wall) are not sampled. Delta BSDF lobes are weighted by
  ``1 / (1 - alpha)``.
* **Further vertices:** BSDF sampling and laser-spot connection up to
  ``max_depth`` path segments (detector to laser, Mitsuba's meaning:
  ``max_depth = 4`` records up to three-bounce light ``D-p-X-S-L``,
  ``2`` only the wall return), Russian roulette from ``rr_depth`` on.
* **Planar relay wall:** the connection from a vertex on the wall to the
  spot (on the same plane) has ``cos(theta_S) = 0`` exactly and is skipped.
* **Randomised QMC:** the patch point and the five numbers used at the
  patch point (strategy, hidden shape, point on it, BSDF direction) come
  from an R_d Kronecker sequence over the pixel's samples with a uniform
  random shift per pixel and replicate (Cranley-Patterson rotation): every
  sample is still uniformly distributed (unbiased); the error falls faster
  than ``1/sqrt(spp)``. Deeper dimensions use PCG32 streams. ``rqmc=false``
  (integrator parameter) draws every dimension from PCG32 (plain Monte
  Carlo), for comparisons.
* **Spot groups (array captures):** :func:`render_spots` renders several
  spots together; they share each sample's detector-side sub-path and
  differ only in the final spot connection (each estimate unbiased).
* **Patch centres only** (``pixel_sampling="center"``): the wall point is
  the patch centre (the point approximation of mitransient/y-tal); in
  confocal captures it is the laser spot itself, so the segment back to
  the spot is the one just traced and needs no shadow ray.

The *relay wall* is the shape hit by the ray from the detector to the
array's ``target``; *hidden geometry* is every other shape. Other emitters
of the scene are ignored: only the laser lights an NLOS capture.

Histograms are accumulated per SIMD lane (:mod:`._lanes`): same seed, same
bytes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import drjit as dr
import mitsuba as mi
import numpy as np

from transient_mi.integrators._lanes import LaneHistogram, LaneLayout, dropped_fraction, seed_rng, to_mono
from transient_mi.integrators._replicates import (DEFAULT_REPLICATES, ReplicateStats, effective_replicates,
                                                  replicate_seed)
from transient_mi.time_axis import apply_kernel
from transient_mi.props import PluginParameterError
from transient_mi.wall import WallFrame, ray_plane_point

#: Relative tolerance on the hit distance when checking that a hidden-geometry
#: sample is the first surface along its ray.
VISIBILITY_REL_TOL = 1e-4
#: ``max_depth`` value standing for "unlimited".
UNLIMITED_DEPTH = 1 << 30


#: Dimensions drawn from the randomised low-discrepancy sequence: patch point (2), strategy choice (1),
#: hidden shape (1), point on it (2), BSDF direction (2) at the patch point.
QMC_DIMS = 8


def kronecker_generators(d: int = QMC_DIMS) -> list[int]:
    """Generators of the R_d Kronecker sequence (Roberts 2018) as 32-bit fixed-point fractions.

    ``phi_d`` is the positive root of ``x^(d+1) = x + 1``; dimension ``k``
    advances by ``frac(phi_d^-(k+1))`` per sample.
    """
    phi = 2.0
    for _ in range(100):
        phi = (1.0 + phi) ** (1.0 / (d + 1))
    return [int((phi ** -(k + 1) % 1.0) * 2.0 ** 32) & 0xFFFFFFFF for k in range(d)]


def _ovec(v) -> "mi.Vector3f":
    v = [float(c) for c in v]
    return mi.Vector3f(dr.opaque(mi.Float, v[0]), dr.opaque(mi.Float, v[1]), dr.opaque(mi.Float, v[2]))


def _opt(v) -> "mi.Point3f":
    return mi.Point3f(_ovec(v))


def _of(x) -> "mi.Float":
    return dr.opaque(mi.Float, float(x))


def _fmt(p) -> str:
    return "(" + ", ".join(f"{float(c):.4g}" for c in p) + ")"


@dataclass
class NLOSSetup:
    """Everything the estimator and the manifest need about one NLOS capture.

    Built (and validated) by :meth:`build`; positions in metres, world frame.

    Attributes
    ----------
    capture : {"array", "confocal"}
    width, height : int
        SPAD pixels.
    frame : WallFrame
        Wall frame centred on the array's ``target``.
    footprint_m : float
        Side of a pixel's square wall patch.
    pitch_m : float
        Distance between neighbouring patch centres (>= footprint_m).
    detector, aperture_normal : ndarray (3,)
        Detector position and the unit normal of its aperture (towards ``target``).
    aperture_area_m2 : float
    laser_origin : ndarray (3,)
    photons_per_pulse : float
    spot_targets : ndarray (n_spots, 3)
        Where the laser is aimed (scan grid, or patch centres in confocal mode).
    spots : ndarray (n_spots, 3)
        Laser spots ``S`` (first hits of the laser rays).
    pixel_centers, pixel_normals : ndarray (height, width, 3)
        Surface point seen at each patch centre and its normal.
    wall_return : dict of ndarrays
        Closed-form first-bounce return per spot: ``pixel`` (flat pixel index
        or -1), ``photons`` (per pulse), ``opl_m``.
    """

    capture: str
    width: int
    height: int
    frame: WallFrame
    footprint_m: float
    pitch_m: float
    detector: np.ndarray
    aperture_normal: np.ndarray
    aperture_area_m2: float
    aperture_diameter_m: float
    include_first_last: bool
    include_wall_return: bool
    laser: object
    laser_origin: np.ndarray
    photons_per_pulse: float
    spot_targets: np.ndarray
    spots: np.ndarray
    spot_grid: tuple
    pixel_centers: np.ndarray
    pixel_normals: np.ndarray
    wall_size_m: tuple
    relay_wall: object
    hidden_shapes: list
    hidden_area_m2: float
    planar_wall: bool = False
    pixel_sampling: str = "area"
    wall_return: dict = field(default_factory=dict)

    @property
    def n_spots(self) -> int:
        return len(self.spots)

    @property
    def n_files(self) -> int:
        return 1 if self.capture == "confocal" else self.n_spots

    # ---------------------------------------------------------------- build

    @classmethod
    def build(cls, scene, sensor) -> "NLOSSetup":
        """Analyse ``scene`` for ``sensor`` (a ``spad_array``) and validate the geometry.

        Raises
        ------
        PluginParameterError
            No or several lasers, a target that hits no surface, patches off
            the relay wall, laser spots off the wall, occluded spots.
        """
        name = sensor.NAME
        film = sensor.film()
        W, H = film.width, film.height
        lasers = [e for e in scene.emitters() if hasattr(e, "is_pulsed_laser")]
        if len(lasers) != 1:
            raise PluginParameterError(
                f"{name}: the scene has {len(lasers)} pulsed_laser emitters; an NLOS capture needs exactly one")
        laser = lasers[0]
        frame = sensor.frame
        D = sensor.origin
        fp = sensor.pixel_footprint_m
        pitch = sensor.pixel_pitch_m

        # ---- relay wall: the shape hit at the array's target
        si_t = _intersect(scene, D[None], (sensor.target - D)[None])
        if not bool(si_t["valid"][0]):
            raise PluginParameterError(
                f"{name}: the ray from origin={_fmt(D)} to target={_fmt(sensor.target)} hits no surface; "
                "target must be a point on the relay wall")
        wall = si_t["shape"][0]
        thick = _thickness_along(wall, frame)
        if thick > 0.25 * max(_extent_in_frame(wall, frame)):
            raise PluginParameterError(
                f"{name}: the relay wall (the shape hit at target={_fmt(sensor.target)}) extends {thick:.3g} m "
                "along wall_normal: it was probably merged with hidden geometry by Mitsuba's scene optimisation "
                "(shapes with equivalent BSDFs are merged); load the scene with optimize=False "
                "(transient_mi.scene_io.load_scene and `transient-mi render` do)")

        # ---- the laser's scan plane must be the wall plane
        if np.dot(laser.frame.normal, frame.normal) < 1 - 1e-6:
            raise PluginParameterError(
                f"pulsed_laser: wall_normal={_fmt(laser.frame.normal)} differs from the spad_array's "
                f"wall_normal={_fmt(frame.normal)}; they must describe the same relay wall")
        if frame.height(laser.origin) <= 0:
            raise PluginParameterError(
                f"pulsed_laser: origin={_fmt(laser.origin)} is behind the relay wall (its height along "
                f"wall_normal {_fmt(frame.normal)} is {frame.height(laser.origin):.4g} m); "
                "the laser must be on the hidden-space side (> 0)")

        # ---- patches must lie on the relay wall: test every patch corner
        corners = frame.grid_corners(W, H, pitch, shrink=1e-4, cell=fp).reshape(-1, 3)
        hit = _intersect(scene, np.broadcast_to(D, corners.shape), corners - D)
        on_wall = hit["valid"] & _same_shape(hit["shape"], wall)
        if not on_wall.all():
            bad = int(np.argmin(on_wall)) // 4
            iy, ix = divmod(bad, W)
            if hit["valid"][bad * 4: bad * 4 + 4].all():
                first = bad * 4 + int(np.argmin(on_wall[bad * 4: bad * 4 + 4]))
                sid = hit["shape"][first].id()
                raise PluginParameterError(
                    f"{name}: the wall patch of pixel (x={ix}, y={iy}) is hidden from the detector at "
                    f"origin={_fmt(D)} by another shape{' (' + repr(sid) + ')' if sid else ''}; "
                    "move the detector or the occluding object")
            raise PluginParameterError(
                f"{name}: the {W} x {H} pixel array with pixel_pitch_m={pitch:g} "
                f"({(W - 1) * pitch + fp:.4g} m x {(H - 1) * pitch + fp:.4g} m centred on target="
                f"{_fmt(sensor.target)}) is larger than the relay wall: the patch of pixel (x={ix}, y={iy}) "
                "extends beyond it; use fewer pixels or a smaller pixel_pitch_m/pixel_footprint_m")
        centers_plane = frame.grid(W, H, pitch).reshape(-1, 3)
        hc = _intersect(scene, np.broadcast_to(D, centers_plane.shape), centers_plane - D)
        pixel_centers = hc["p"].reshape(H, W, 3)
        pixel_normals = hc["n"].reshape(H, W, 3)

        # ---- laser spots
        if sensor.capture == "confocal":
            spot_targets = centers_plane
            spot_grid = (H, W)
        else:
            spot_targets = laser.spot_targets()
            spot_grid = (laser.spots_y, laser.spots_x)
        Lo = laser.origin
        hs = _intersect(scene, np.broadcast_to(Lo, spot_targets.shape), spot_targets - Lo)
        ok = hs["valid"] & _same_shape(hs["shape"], wall)
        if not ok.all():
            j = int(np.argmin(ok))
            what = "hits nothing" if not hs["valid"][j] else "hits another surface first"
            where = ("the patch centre of pixel %d" % j if sensor.capture == "confocal" else
                     f"scan point {j} (spots_x={laser.spots_x}, spots_y={laser.spots_y}, "
                     f"spot_spacing_m={laser.spot_spacing_m:g} around target={_fmt(laser.target)})")
            raise PluginParameterError(
                f"pulsed_laser: laser spot {j} is off the relay wall: the ray from origin={_fmt(Lo)} to "
                f"{where} at {_fmt(spot_targets[j])} {what}; keep the scan grid on the wall")
        spots = hs["p"]

        aperture_normal = sensor.target - D
        aperture_normal = aperture_normal / np.linalg.norm(aperture_normal)
        wall_size = _extent_in_frame(wall, frame)
        hidden = [s for s in scene.shapes() if not _is(s, wall)]
        hidden_area = float(sum(float(s.surface_area()[0]) for s in hidden))

        setup = cls(
            capture=sensor.capture, width=W, height=H, frame=frame, footprint_m=fp, pitch_m=pitch, detector=D,
            aperture_normal=aperture_normal,
            aperture_area_m2=math.pi * (sensor.aperture_diameter_m / 2.0) ** 2,
            aperture_diameter_m=sensor.aperture_diameter_m,
            include_first_last=sensor.include_first_last, include_wall_return=sensor.include_wall_return,
            laser=laser, laser_origin=Lo, photons_per_pulse=laser.photons_per_pulse,
            spot_targets=np.asarray(spot_targets, dtype=np.float64), spots=spots, spot_grid=spot_grid,
            pixel_centers=pixel_centers, pixel_normals=pixel_normals, wall_size_m=wall_size,
            relay_wall=wall, hidden_shapes=hidden, hidden_area_m2=hidden_area,
            planar_wall=bool(thick <= 1e-6 * max(1.0, max(wall_size))),
            pixel_sampling=sensor.pixel_sampling,
        )
        setup.wall_return = setup._wall_return(scene, hs)
        return setup

    def _wall_return(self, scene, hs) -> dict:
        """Closed-form first-bounce return ``L -> S -> D`` for every spot (photons per pulse)."""
        S = self.spots
        n = len(S)
        D = self.detector
        ix, iy, inside = self.frame.cell_of(ray_plane_point(D, S, self.frame), self.width, self.height,
                                            self.pitch_m, cell=self.footprint_m)
        pixel = np.where(inside, iy * self.width + ix, -1)
        if self.capture == "confocal":  # pixel k is recorded with spot k only
            pixel = np.where(pixel == np.arange(n), pixel, -1)
        # f_s(S; w_L, w_SD) cos, evaluated by Mitsuba on the spot's surface interaction
        Lo = self.laser_origin
        d = S - Lo
        ray = mi.Ray3f(mi.Point3f(*[mi.Float(Lo[i] + 0 * d[:, i]) for i in range(3)]),
                       mi.Vector3f(*[mi.Float(c) for c in (d / np.linalg.norm(d, axis=1, keepdims=True)).T]))
        si = scene.ray_intersect(ray)
        toD = D - S
        dist = np.linalg.norm(toD, axis=1)
        w = toD / dist[:, None]
        wo = si.to_local(mi.Vector3f(*[mi.Float(c) for c in w.T]))
        f = to_mono(si.bsdf().eval(mi.BSDFContext(), si, wo), si.wavelengths)
        target_d = mi.Point3f(*[mi.Float(np.full(n, D[i])) for i in range(3)])
        occluded = scene.ray_test(si.spawn_ray_to(target_d))
        f = np.asarray(f.numpy(), dtype=np.float64)
        vis = ~np.asarray(occluded.numpy(), dtype=bool)
        cos_ap = np.clip(-(w @ self.aperture_normal), 0.0, None)
        photons = self.photons_per_pulse * f * self.aperture_area_m2 * cos_ap / dist ** 2
        photons = np.where(vis & (pixel >= 0) & self.include_wall_return, photons, 0.0)
        opl = (np.linalg.norm(d, axis=1) + dist) if self.include_first_last else np.zeros(n)
        return {"pixel": pixel.astype(np.int64), "photons": photons, "opl_m": opl}

    # ------------------------------------------------------------- manifest

    def geometry(self) -> dict:
        """The manifest's ``geometry`` entry."""
        return {
            "laser_origin": self.laser_origin.tolist(),
            "detector_origin": self.detector.tolist(),
            "spots": self.spots.tolist(),
            "spot_targets": self.spot_targets.tolist(),
            "spot_grid": list(self.spot_grid),
            "pixel_centers": self.pixel_centers.tolist(),
            "pixel_normals": self.pixel_normals.tolist(),
            "wall_normal": self.frame.normal.tolist(),
            "wall_frame": self.frame.as_dict(),
            "wall_size_m": list(self.wall_size_m),
            "pixel_footprint_m": self.footprint_m,
            "pixel_pitch_m": self.pitch_m,
            "aperture_diameter_m": self.aperture_diameter_m,
            "aperture_normal": self.aperture_normal.tolist(),
            "include_wall_return": self.include_wall_return,
            "pixel_sampling": self.pixel_sampling,
            "relay_wall": self.relay_wall.id(),
            "hidden_area_m2": self.hidden_area_m2,
        }


# ---------------------------------------------------------------------- helpers


def _intersect(scene, origins, directions) -> dict:
    """Intersect rays (numpy ``[n, 3]``) with the scene; returns numpy fields and shape pointers."""
    o = np.asarray(origins, dtype=np.float64)
    d = np.asarray(directions, dtype=np.float64)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    ray = mi.Ray3f(mi.Point3f(*[mi.Float(c) for c in o.T]), mi.Vector3f(*[mi.Float(c) for c in d.T]))
    si = scene.ray_intersect(ray)
    valid = np.asarray(si.is_valid().numpy(), dtype=bool)
    p = np.stack([np.asarray(c.numpy(), dtype=np.float64) for c in si.p], axis=1)
    nrm = np.stack([np.asarray(c.numpy(), dtype=np.float64) for c in si.n], axis=1)
    return {"valid": valid, "p": p, "n": nrm, "t": np.asarray(si.t.numpy(), dtype=np.float64),
            "shape": si.shape}


def _is(a, b) -> bool:
    try:
        return a.ptr == b.ptr  # type: ignore[attr-defined]
    except AttributeError:
        return a is b


def _same_shape(ptrs, shape) -> np.ndarray:
    eq = ptrs == mi.ShapePtr(shape)
    return np.asarray(eq.numpy(), dtype=bool)


def _bbox_corners(shape) -> np.ndarray:
    bb = shape.bbox()
    lo, hi = np.array(list(bb.min), dtype=np.float64), np.array(list(bb.max), dtype=np.float64)
    return np.array([[(hi if (i >> k) & 1 else lo)[k] for k in range(3)] for i in range(8)])


def _thickness_along(shape, frame: WallFrame) -> float:
    """Extent (metres) of ``shape``'s bounding box along the wall normal."""
    _, _, h = frame.to_wall(_bbox_corners(shape))
    return float(h.max() - h.min())


def _extent_in_frame(shape, frame: WallFrame) -> tuple[float, float]:
    """Size (metres) of ``shape``'s bounding box along the wall axes ``ex``, ``ey``."""
    u, v, _ = frame.to_wall(_bbox_corners(shape))
    return float(u.max() - u.min()), float(v.max() - v.min())


# ------------------------------------------------------------------ rendering


@dataclass
class _Consts:
    """Opaque per-capture values (one compiled kernel for every spot and setting)."""

    D: object
    c00: object
    step_x: object  # between patch centres (pitch)
    step_y: object
    patch_x: object  # across one patch (footprint)
    patch_y: object
    n_plane: object
    n_ap: object
    a_pix: object
    a_ap: object
    laser_origin: object
    first_last: object
    alpha: object
    hidden_area: object
    max_depth: object
    rr_depth: object
    width: object
    seed: object
    planar_wall: bool
    center_only: bool
    max_depth_static: int
    confocal: bool
    spot_is_vertex1: bool
    n_group: object
    rqmc: bool = True


#: Histogram floats held per kernel launch when an array capture renders a group of spots at once.
GROUP_HIST_FLOATS = 1 << 26
#: Most laser spots rendered together (sharing the detector-side sub-paths).
MAX_GROUP = 64
#: Lanes to aim for (enough to keep every CPU thread's SIMD units busy).
GROUP_TARGET_LANES = 1 << 10


def group_layout(n_pixels: int, spp: int, n_bins_ext: int, n_spots: int) -> tuple[int, int]:
    """``(streams K, spots per group)`` for an array capture; depends only on the configuration.

    Lanes ``n_pixels * K`` aim at :data:`GROUP_TARGET_LANES` (few lanes keep
    the per-lane histograms, which are zeroed and summed for every launch,
    small; each lane loops over many samples); a group holds as
    many spots as fit ``GROUP_HIST_FLOATS`` histogram values (at most
    :data:`MAX_GROUP`). Every group shares the detector-side sub-path of each
    sample (patch point, hidden vertex, further bounces) between its spots.
    """
    k = 1
    while k * 2 <= spp and n_pixels * k * 2 <= GROUP_TARGET_LANES:
        k *= 2
    per_spot = n_pixels * k * n_bins_ext
    g = max(1, min(MAX_GROUP, n_spots, GROUP_HIST_FLOATS // max(per_spot, 1)))
    return k, g


class _GroupHistogram(LaneHistogram):
    """Lane histograms with one sub-slot per spot of the group (slot = ``lane * G + spot``)."""

    def __init__(self, layout: LaneLayout, axis, pad: int, n_sub: int):
        super().__init__(layout, axis, pad)
        self.n_sub = n_sub
        n = layout.n_lanes * n_sub
        self.data = dr.zeros(mi.Float, n * self.n_bins_ext)
        self.lost = dr.zeros(mi.Float, n)
        self.dropped = dr.zeros(mi.UInt32, n)
        self.invalid = dr.zeros(mi.UInt32, n)
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
        if L.streams == 1:
            out = self.data * f
        else:
            idx = dr.arange(mi.UInt32, L.n_pixels * G * T)
            pixel = idx // (G * T)
            rest = idx - pixel * (G * T)
            base = pixel * (L.streams * G * T) + rest
            out = dr.zeros(mi.Float, L.n_pixels * G * T)
            for k in range(L.streams):  # unrolled: fixed summation order
                out += dr.gather(mi.Float, self.data, base + k * (G * T))
            out *= f
        dr.eval(out)
        lost = np.asarray(self.lost).reshape(L.n_pixels, L.streams, G).sum(axis=1, dtype=np.float64) * f
        dropped = np.asarray(self.dropped).reshape(L.n_pixels, L.streams, G).sum(axis=(0, 1), dtype=np.uint64)
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


def render_spot(setup: NLOSSetup, scene, film, options: dict, *, seed: int, spp: int, spot: int, progress=None):
    """Render laser spot ``spot`` of an array capture alone, or the confocal capture (``spot`` 0).

    See :func:`render_spots`; returns one ``TransientResult``.
    """
    return render_spots(setup, scene, film, options, seed=seed, spp=spp, spots=[spot], progress=progress)[0]


def render_spots(setup: NLOSSetup, scene, film, options: dict, *, seed: int, spp: int, spots, progress=None,
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
        From :meth:`NLOSSetup.build` for this ``scene``.
    scene : mitsuba.Scene
    film : transient_film
    options : dict
        ``max_depth`` (segments, -1 unlimited), ``rr_depth``,
        ``hidden_geometry_prob`` (alpha in [0, 1]), ``variance_replicates``
        (independent replicates, see :mod:`._replicates`).
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
    """
    from transient_mi.films.transient_film import TransientResult

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


def _render_replicate(setup: NLOSSetup, scene, film, options: dict, *, seed: int, spp: int, spots, progress=None):
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
    hist = _GroupHistogram(layout, axis, pad, G)
    rng = seed_rng(seed, layout.n_lanes)

    fr = setup.frame
    c00 = fr.grid(W, H, setup.pitch_m)[0, 0]
    max_depth = options.get("max_depth", -1)
    alpha = float(options.get("hidden_geometry_prob", 0.8)) if setup.hidden_shapes else 0.0
    center = setup.pixel_sampling == "center"
    c = _Consts(
        D=_opt(setup.detector), c00=_opt(c00), step_x=_ovec(fr.ex * setup.pitch_m),
        step_y=_ovec(fr.ey * setup.pitch_m), patch_x=_ovec(fr.ex * setup.footprint_m),
        patch_y=_ovec(fr.ey * setup.footprint_m), n_plane=_ovec(fr.normal), n_ap=_ovec(setup.aperture_normal),
        a_pix=_of(setup.footprint_m ** 2), a_ap=_of(setup.aperture_area_m2), laser_origin=_opt(setup.laser_origin),
        first_last=_of(1.0 if setup.include_first_last else 0.0),
        alpha=_of(alpha), hidden_area=_of(max(setup.hidden_area_m2, 1e-30)),
        max_depth=dr.opaque(mi.Int32, UNLIMITED_DEPTH if max_depth == -1 else int(max_depth)),
        rr_depth=dr.opaque(mi.Int32, int(options.get("rr_depth", 5))),
        width=dr.opaque(mi.UInt32, W),
        seed=dr.opaque(mi.UInt32, seed & 0xFFFFFFFF),
        planar_wall=setup.planar_wall,
        center_only=center,
        max_depth_static=UNLIMITED_DEPTH if max_depth == -1 else int(max_depth),
        confocal=confocal,
        # confocal + patch centre: the pixel's wall point *is* its laser spot, so the segment back to the
        # spot from the hidden vertex is the (already traced) segment from the wall point
        spot_is_vertex1=confocal and center,
        n_group=dr.opaque(mi.UInt32, G),
        rqmc=bool(options.get("rqmc", True)),
    )
    if setup.hidden_shapes:
        hidden_ptrs = mi.ShapePtr(setup.hidden_shapes)
        areas = [float(s.surface_area()[0]) for s in setup.hidden_shapes]
        distr = mi.DiscreteDistribution(mi.Float(areas))
    else:
        hidden_ptrs, distr = None, None
    wall_ptr = mi.ShapePtr(setup.relay_wall)

    # the laser spots of the group (array captures): one ray each, evaluated once
    group = None
    if not confocal:
        # (padded to >= 2 entries: Dr.Jit treats size-1 arrays as scalars, which must not reach a kernel
        # compiled for a gather from a real array)
        tg = setup.spot_targets[spots + [spots[-1]] * max(0, 2 - G)]
        Lo = setup.laser_origin
        d = tg - Lo
        d = d / np.linalg.norm(d, axis=1, keepdims=True)
        ray = mi.Ray3f(mi.Point3f(*[mi.Float(np.full(len(tg), Lo[i])) for i in range(3)]),
                       mi.Vector3f(*[mi.Float(d[:, i]) for i in range(3)]))
        si_g = scene.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=True)
        # what a BSDF evaluation at the spot needs (gathered per connection: keep it small)
        group = (si_g.p, si_g.n, si_g.sh_frame.s, si_g.sh_frame.t, si_g.sh_frame.n, si_g.uv, si_g.wi, si_g.t,
                 si_g.shape, si_g.bsdf())
        dr.eval(*group)

    total = layout.n_pixels * spp
    for j0, j1 in layout.passes():
        rng = _nlos_pass(scene, hist, rng, layout, j0, j1, c, hidden_ptrs, distr, wall_ptr, group)
        hist.evaluate(rng)  # one evaluation of the loop (evaluating rng separately would run it twice)
        if progress is not None:
            progress(min(total, layout.n_pixels * min(spp, j1 * K)), total)

    # closed-form first-bounce return of the wall (weighted by spp: collect() divides by it)
    wr = setup.wall_return
    all_spots = np.arange(setup.n_spots) if confocal else np.array(spots)
    sub = np.zeros(len(all_spots), dtype=np.uint32) if confocal else np.arange(G, dtype=np.uint32)
    pix = wr["pixel"][all_spots]
    sel = (pix >= 0) & (wr["photons"][all_spots] > 0)
    if sel.any():
        ph = wr["photons"][all_spots][sel] / setup.photons_per_pulse  # N is applied below
        lanes = mi.UInt32((pix[sel] * K).astype(np.uint32))
        hist.record(lanes, mi.Float(wr["opl_m"][all_spots][sel]), mi.Float(ph * spp), mi.Bool(True),
                    sub=mi.UInt32(sub[sel]))
        hist.evaluate()

    out = list(hist.collect_all(taps, scale=setup.photons_per_pulse))
    anomalies = {"invalid": hist.invalid_count(), "negative_fraction": hist.negative_fraction}
    return out, anomalies


@dr.syntax
def _connect_spots(scene, hist, lane, si, beta, w0, opl, depth, active, c, spot, group, wall_ptr, ctx,
                   visible=None):
    """Deterministic connection of vertex ``si`` to the laser spot(s) (next-event estimation).

    ``spot``: the lane's own spot ``(si_s, bsdf_s)`` (confocal), else ``group``
    holds the group's spots, connected one after another. ``visible``: the
    visibility when it is already known (confocal patch-centre captures).
    """
    bsdf = si.bsdf()
    active_nee = active & (depth + 2 <= c.max_depth) & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
    if dr.hint(c.planar_wall, mode="scalar"):
        # spot and vertex on the same plane: cos(theta_S) = 0 exactly, nothing to connect
        active_nee &= si.shape != wall_ptr
    if dr.hint(group is None, mode="scalar"):  # the lane's own spot: no loop over a group
        _connect_one(scene, hist, lane, si, bsdf, beta, w0, opl, active_nee, c, spot[0], spot[1], mi.UInt32(0),
                     ctx, visible)
        return
    b = mi.UInt32(0)
    while active_nee & (b < c.n_group):
        if dr.hint(group is None, mode="scalar"):
            si_s, bsdf_s = spot
        else:
            g_ok = active_nee & (b < c.n_group)
            si_s = dr.zeros(mi.SurfaceInteraction3f)
            si_s.p = dr.gather(mi.Point3f, group[0], b, g_ok)
            si_s.n = dr.gather(mi.Normal3f, group[1], b, g_ok)
            si_s.sh_frame = mi.Frame3f(dr.gather(mi.Vector3f, group[2], b, g_ok),
                                       dr.gather(mi.Vector3f, group[3], b, g_ok),
                                       dr.gather(mi.Normal3f, group[4], b, g_ok))
            si_s.uv = dr.gather(mi.Point2f, group[5], b, g_ok)
            si_s.wi = dr.gather(mi.Vector3f, group[6], b, g_ok)
            si_s.t = dr.gather(mi.Float, group[7], b, g_ok)
            si_s.shape = dr.gather(mi.ShapePtr, group[8], b, g_ok)
            si_s.wavelengths = si.wavelengths
            bsdf_s = dr.gather(mi.BSDFPtr, group[9], b, g_ok)
        _connect_one(scene, hist, lane, si, bsdf, beta, w0, opl, active_nee, c, si_s, bsdf_s, b, ctx, visible)
        b += 1


def _connect_one(scene, hist, lane, si, bsdf, beta, w0, opl, active, c, si_s, bsdf_s, sub, ctx, visible):
    """Connect vertex ``si`` to the spot ``si_s`` and record the contribution in sub-slot ``sub``."""
    spot_p = si_s.p
    to_s = spot_p - si.p
    dist_s = dr.norm(to_s)
    d_s = to_s / dist_s
    f_x = bsdf.eval(ctx, si, si.to_local(d_s), active)
    i_s = bsdf_s.eval(ctx, si_s, si_s.to_local(-d_s), active)
    val = to_mono(beta * f_x * i_s, si.wavelengths) * (w0 / dr.square(dist_s))
    ok = active & (val > 0) & si_s.is_valid()
    if visible is None:
        ok &= ~scene.ray_test(si.spawn_ray_to(spot_p), ok)
    else:
        ok &= visible
    hist.record(lane, opl + dist_s + c.first_last * si_s.t, val, ok, sub=sub)


def _first_bounce(scene, si, active, u, rng, c, hidden_ptrs, distr, wall_ptr, ctx):
    """Direction leaving the patch point: one-sample MIS between hidden-geometry and BSDF sampling.

    Returns ``(si_next, weight, eta)``; ``weight`` is ``f cos / (alpha p_hidden + (1 - alpha) p_bsdf)``
    (0 for an occluded hidden-geometry sample).
    """
    bsdf = si.bsdf()
    alpha = c.alpha
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
    cos_y = dr.abs(dr.dot(si_next.n, ray.d))
    dist2_y = dr.squared_norm(si_next.p - si.p)
    pdf_h = dr.select(on_hidden & (cos_y > 0), dist2_y / (cos_y * c.hidden_area), 0.0)
    pdf_mix = alpha * pdf_h + (1.0 - alpha) * pdf_b
    weight = mi.Spectrum(dr.select(pdf_mix > 0, f_val / pdf_mix, 0.0))
    hg_ok = si_next.is_valid() & (si_next.shape == shape) & \
        (dr.abs(si_next.t - dist_x) <= VISIBILITY_REL_TOL * dist_x)
    weight = dr.select(use_hg & ~hg_ok, 0.0, weight)
    delta_lobe = ~use_hg & mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
    weight = dr.select(delta_lobe, bsdf_w / (1.0 - alpha), weight)
    eta = dr.select(use_hg, 1.0, bs.eta)
    return si_next, weight, eta, active & si_next.is_valid()


@dr.syntax
def _nlos_pass(scene, hist, rng, layout, j0, j1, c, hidden_ptrs, distr, wall_ptr, group):
    K = layout.streams
    lane = dr.arange(mi.UInt32, layout.n_lanes)
    pixel = lane // K
    k = lane - pixel * K
    px = mi.Float(pixel % c.width)
    py = mi.Float(pixel // c.width)
    centre = c.c00 + px * c.step_x + py * c.step_y

    # ---- confocal: the laser spot of every lane is its own patch centre
    spot = None
    if dr.hint(c.confocal, mode="scalar"):
        laser_ray = mi.Ray3f(c.laser_origin, dr.normalize(centre - c.laser_origin))
        si_s = scene.ray_intersect(laser_ray, ray_flags=mi.RayFlags.All, coherent=True)
        spot = (si_s, si_s.bsdf())

    # ---- randomised QMC: an R_d sequence over the pixel's samples, shifted at random per pixel
    gen = [dr.opaque(mi.UInt32, g) for g in kronecker_generators()]
    shift = []
    for d in range(0, QMC_DIMS, 2):
        a, b = mi.sample_tea_32(pixel, c.seed ^ mi.UInt32(0x9E3779B9 * (d + 1) & 0xFFFFFFFF))
        shift += [a, b]

    # ---- patch centre only: the wall point (vertex 1) is the same for every sample
    if dr.hint(c.center_only, mode="scalar"):
        if dr.hint(c.spot_is_vertex1, mode="scalar"):
            si_c = dr.detach(spot[0])  # the laser spot itself, seen from the detector
            to_c = si_c.p - c.D
            si_c.wi = si_c.to_local(-dr.normalize(to_c))
        else:
            si_c = scene.ray_intersect(mi.Ray3f(c.D, dr.normalize(centre - c.D)), ray_flags=mi.RayFlags.All,
                                       coherent=True)
        to_c = centre - c.D
        d_c = dr.normalize(to_c)
        w0_c = c.a_ap * dr.maximum(dr.dot(d_c, c.n_ap), 0.0) * c.a_pix * dr.abs(dr.dot(d_c, c.n_plane)) / \
            dr.squared_norm(to_c)
        opl_c = c.first_last * dr.norm(si_c.p - c.D)

    j = mi.UInt32(dr.opaque(mi.UInt32, j0))
    j_end = dr.opaque(mi.UInt32, j1)
    spp = dr.opaque(mi.UInt32, layout.spp)
    ctx = mi.BSDFContext()
    deeper = c.max_depth_static > 4

    while (j < j_end) & (k + j * K < spp):
        i_sample = k + j * K
        if dr.hint(c.rqmc, mode="scalar"):
            u = [mi.Float((shift[d] + i_sample * gen[d]) >> 8) * (1.0 / (1 << 24)) for d in range(QMC_DIMS)]
        else:  # plain Monte Carlo (for comparisons: integrator parameter rqmc=false)
            u = [rng.next_float32() for d in range(QMC_DIMS)]
        # ---- patch point p (vertex 1) and the sensor weight
        if dr.hint(c.center_only, mode="scalar"):
            si = si_c
            w0 = w0_c
            opl = opl_c
        else:
            q = centre + (u[0] - 0.5) * c.patch_x + (u[1] - 0.5) * c.patch_y
            to_q = q - c.D
            dist_q = dr.norm(to_q)
            d0 = to_q / dist_q
            w0 = c.a_ap * dr.maximum(dr.dot(d0, c.n_ap), 0.0) * c.a_pix * dr.abs(dr.dot(d0, c.n_plane)) / \
                dr.square(dist_q)
            si = scene.ray_intersect(mi.Ray3f(c.D, d0), ray_flags=mi.RayFlags.All, coherent=True)
            opl = c.first_last * si.t
        active = si.is_valid()
        beta = mi.Spectrum(1.0)
        _connect_spots(scene, hist, lane, si, beta, w0, opl, mi.Int32(1), active, c, spot, group, wall_ptr, ctx)

        # ---- vertex 2 by one-sample MIS, then its spot connection (three-bounce light)
        active &= 5 <= c.max_depth + 1  # i.e. max_depth >= 4
        si2, weight, eta, active = _first_bounce(scene, si, active, u[2:], rng, c, hidden_ptrs, distr, wall_ptr,
                                                 ctx)
        beta = beta * weight
        opl = opl + dr.norm(si2.p - si.p)
        if dr.hint(c.spot_is_vertex1, mode="scalar"):
            # the segment vertex 2 -> spot is the segment just traced from the spot: visible
            _connect_spots(scene, hist, lane, si2, beta, w0, opl, mi.Int32(2), active, c, spot, group, wall_ptr,
                           ctx, visible=mi.Bool(True))
        else:
            _connect_spots(scene, hist, lane, si2, beta, w0, opl, mi.Int32(2), active, c, spot, group, wall_ptr,
                           ctx)

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
                opl = opl + dr.norm(si_next.p - si.p)
                depth += 1
                beta_max = dr.max(mi.unpolarized_spectrum(beta))
                rr_prob = dr.minimum(beta_max * dr.square(eta), 0.95)
                rr_active = (depth - 1) >= c.rr_depth
                rr_continue = rng.next_float32() < rr_prob
                beta[rr_active] *= dr.rcp(rr_prob)
                active = active_next & si_next.is_valid() & (~rr_active | rr_continue) & (beta_max > 0)
                _connect_spots(scene, hist, lane, si_next, beta, w0, opl, depth, active, c, spot, group, wall_ptr,
                               ctx)
                si = si_next
        j += 1
    return rng
