"""The scene analysis of an NLOS capture (:class:`NLOSSetup`): relay wall, laser spots, pixel patches, hidden
geometry, the closed-form wall return, and the validation of all of it.

Used by the ``spad_array`` sensor (:meth:`~transient_mi.sensors.spad_array.SpadArray.nlos_setup`, which
caches it per scene) and read by the NLOS estimator (:mod:`transient_mi.integrators.transient_nlos_path`)
and the capture manifest (:meth:`NLOSSetup.geometry`). The radiometry is documented in
:mod:`transient_mi.integrators.transient_nlos_path`. Positions in metres, world frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from statistics import NormalDist

import mitsuba as mi
import numpy as np

from transient_mi._upload import upload
from transient_mi.integrators import _device_legs as legs
from transient_mi.integrators._lanes import to_mono
from transient_mi.props import PluginParameterError
from transient_mi.wall import WallFrame, ray_plane_point


#: Beam directions per axis of the footprint quadrature of a divergent laser (``BEAM_NODES_PER_AXIS^2`` per
#: spot, see :func:`beam_nodes`).
BEAM_NODES_PER_AXIS = 64
#: Spots whose footprint quadrature is evaluated together (bounds the memory: 256 x 4096 legs, ~0.5 GB).
FOOTPRINT_SPOTS_PER_CHUNK = 256


def beam_nodes(k: int = BEAM_NODES_PER_AXIS) -> np.ndarray:
    """Standard-normal quadrature nodes ``x_i = Phi^-1((i + 1/2) / k) / s`` (``k`` of them, equal weights).

    ``s = sqrt(mean(Phi^-1((i + 1/2) / k)^2))`` rescales the midpoint rule so that the nodes' variance is
    exactly 1 (the plain midpoint rule truncates the tails: variance 0.980 for ``k = 64``): the product grid
    ``(x_i, x_j)`` keeps the beam's energy and its second moments (the footprint width) exact.
    """
    nd = NormalDist()
    x = np.array([nd.inv_cdf((i + 0.5) / k) for i in range(k)])
    return x / math.sqrt(float(np.mean(x ** 2)))


def _perpendicular_frame(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors ``e1, e2`` ``[n, 3]`` perpendicular to the unit vectors ``a`` ``[n, 3]`` and to each other."""
    helper = np.where(np.abs(a[:, 2:3]) < 0.9, np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]]))
    e1 = np.cross(a, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return e1, np.cross(a, e1)


def _fmt(p) -> str:
    return "(" + ", ".join(f"{float(c):.4g}" for c in p) + ")"


#: The id that names the relay wall in a scene (where a scene names it, the detector's target ray must hit it
#: first; a scene without it takes the shape hit at the target as its wall).
RELAY_WALL_ID = "relay_wall"


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
    #: the scene has windows (delta-transmissive shapes, see :mod:`transient_mi.integrators._device_legs`):
    #: the device legs are traced through them
    windows: bool = False
    #: some non-wall shape has no smooth BSDF component (a window, a mirror): it is not hidden geometry
    hidden_excludes: bool = False
    #: with windows: optical path lengths (m) of the laser legs ``L -> S`` (n_spots,) and of the detector
    #: legs ``D -> patch centre`` (height, width), recorded in the manifest for reconstruction
    spot_leg_opl_m: np.ndarray | None = None
    pixel_leg_opl_m: np.ndarray | None = None
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
        windows = bool(legs.window_shapes(scene))  # device legs then run through them (_device_legs)
        si_t = _intersect(scene, D[None], (sensor.target - D)[None], windows)
        if not bool(si_t["valid"][0]):
            raise PluginParameterError(
                f"{name}: the ray from origin={_fmt(D)} to target={_fmt(sensor.target)} hits no surface; "
                "target must be a point on the relay wall")
        wall = si_t["shape"][0]
        if wall.id() != RELAY_WALL_ID and any(s.id() == RELAY_WALL_ID for s in scene.shapes()):
            raise PluginParameterError(
                f"{name}: the ray from origin={_fmt(D)} to target={_fmt(sensor.target)} first hits shape "
                f"'{wall.id()}', not the relay wall (the shape with id '{RELAY_WALL_ID}'): nothing may stand between "
                "the detector and the wall; move that shape or the target")
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
        hit = _intersect(scene, np.broadcast_to(D, corners.shape), corners - D, windows)
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
        hc = _intersect(scene, np.broadcast_to(D, centers_plane.shape), centers_plane - D, windows)
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
        hs = _intersect(scene, np.broadcast_to(Lo, spot_targets.shape), spot_targets - Lo, windows)
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
        # hidden geometry: every other shape that a spot connection can reach (a smooth BSDF component);
        # a shape with only delta lobes (a window, a mirror) contributes nothing to a connection, so
        # sampling points on it would only waste samples
        others = [s for s in scene.shapes() if not _is(s, wall)]
        hidden = [s for s in others if legs.has_smooth_component(s.bsdf())]
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
            pixel_sampling=sensor.pixel_sampling, windows=windows, hidden_excludes=len(hidden) < len(others),
            spot_leg_opl_m=hs["opl_m"] if windows else None,
            pixel_leg_opl_m=hc["opl_m"].reshape(H, W) if windows else None,
        )
        setup.wall_return = setup._wall_return(scene, hs)
        return setup

    def _wall_return(self, scene, hs) -> dict:
        """Closed-form first-bounce return ``L -> S -> D`` for every spot (photons per pulse).

        Arrays ``pixel``, ``photons``, ``opl_m`` of shape ``(n_spots,)``; with a divergent beam
        ``(n_spots, M)``: the footprint integrated by the ``M = BEAM_NODES_PER_AXIS^2`` beam directions of
        :meth:`beam_directions`, each carrying ``N / M`` photons to its own point of the wall.
        """
        n = self.n_spots
        if self.laser.divergence_mrad > 0:
            parts = [self._footprint_return(scene, j0, min(n, j0 + FOOTPRINT_SPOTS_PER_CHUNK))
                     for j0 in range(0, n, FOOTPRINT_SPOTS_PER_CHUNK)]
            return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
        return (self._wall_return_windows if self.windows else self._wall_return_points)(scene, hs, np.arange(n))

    def _footprint_return(self, scene, j0: int, j1: int) -> dict:
        """The divergent beam's wall return of spots ``[j0, j1)``: arrays ``[j1 - j0, M]``."""
        dirs = self.beam_directions(j0, j1)  # [n, M, 3]
        n, M = dirs.shape[:2]
        Lo = self.laser_origin
        sub = legs.trace_legs_np(scene, np.broadcast_to(Lo, (n * M, 3)), dirs.reshape(-1, 3))
        spot_of = np.repeat(np.arange(j0, j1), M)
        wr = (self._wall_return_windows if self.windows else self._wall_return_points)(scene, sub, spot_of)
        on_wall = sub["valid"] & _same_shape(sub["shape"], self.relay_wall) & (sub["throughput"] > 0)
        wr["photons"] = np.where(on_wall, wr["photons"] / M, 0.0)
        return {k: v.reshape(n, M) for k, v in wr.items()}

    def beam_directions(self, j0: int = 0, j1: int | None = None) -> np.ndarray:
        """The divergent beam's quadrature directions ``[n, M, 3]`` of spots ``[j0, j1)`` (default all; unit
        vectors from the laser).

        ``normalize(a + sigma (x_i e1 + x_j e2))`` over the product grid of :func:`beam_nodes`, with ``a``
        the axis towards each spot target and ``sigma`` the laser's ``beam_sigma_rad``.
        """
        a = self.spot_targets[j0:j1] - self.laser_origin
        a = a / np.linalg.norm(a, axis=1, keepdims=True)
        e1, e2 = _perpendicular_frame(a)
        x = beam_nodes()
        gx, gy = np.meshgrid(x, x, indexing="ij")
        s = self.laser.beam_sigma_rad
        d = a[:, None, :] + s * (gx.reshape(1, -1, 1) * e1[:, None, :] + gy.reshape(1, -1, 1) * e2[:, None, :])
        return d / np.linalg.norm(d, axis=2, keepdims=True)

    def _wall_return_points(self, scene, hs, spot_of) -> dict:
        """:meth:`_wall_return` without windows, for the wall points ``hs["p"]`` lit by spot ``spot_of``."""
        S = hs["p"]
        n = len(S)
        D = self.detector
        ix, iy, inside = self.frame.cell_of(ray_plane_point(D, S, self.frame), self.width, self.height,
                                            self.pitch_m, cell=self.footprint_m)
        pixel = np.where(inside, iy * self.width + ix, -1)
        if self.capture == "confocal":  # pixel k is recorded with spot k only
            pixel = np.where(pixel == spot_of, pixel, -1)
        # f_s(S; w_L, w_SD) cos, evaluated by Mitsuba on the spot's surface interaction
        Lo = self.laser_origin
        d = S - Lo
        ray = mi.Ray3f(mi.Point3f(*[upload(mi.Float, Lo[i] + 0 * d[:, i]) for i in range(3)]),
                       mi.Vector3f(*[upload(mi.Float, c) for c in (d / np.linalg.norm(d, axis=1, keepdims=True)).T]))
        si = scene.ray_intersect(ray)
        toD = D - S
        dist = np.linalg.norm(toD, axis=1)
        w = toD / dist[:, None]
        wo = si.to_local(mi.Vector3f(*[upload(mi.Float, c) for c in w.T]))
        f = to_mono(si.bsdf().eval(mi.BSDFContext(), si, wo), si.wavelengths)
        target_d = mi.Point3f(*[upload(mi.Float, np.full(n, D[i])) for i in range(3)])
        occluded = scene.ray_test(si.spawn_ray_to(target_d))
        f = np.asarray(f.numpy(), dtype=np.float64)
        vis = ~np.asarray(occluded.numpy(), dtype=bool)
        cos_ap = np.clip(-(w @ self.aperture_normal), 0.0, None)
        photons = self.photons_per_pulse * f * self.aperture_area_m2 * cos_ap / dist ** 2
        photons = np.where(vis & (pixel >= 0) & self.include_wall_return, photons, 0.0)
        opl = (np.linalg.norm(d, axis=1) + dist) if self.include_first_last else np.zeros(n)
        return {"pixel": pixel.astype(np.int64), "photons": photons, "opl_m": opl}

    def _wall_return_windows(self, scene, hs, spot_of) -> dict:
        """:meth:`_wall_return` through windows: the legs ``L -> S`` and ``S -> D`` refract at every window.

        The detector direction that sees ``S`` is found by :func:`~transient_mi.integrators._device_legs.
        aim_through_windows`; the pixel is the one whose cone of directions holds it; the photons are
        ``N T_L T_D f_s cos(theta_S) A_ap cos(theta_ap) / (cos(theta_S) J)`` with ``J = dA_S / dOmega_D``
        of the detector leg (:func:`~transient_mi.integrators._device_legs.leg_jacobian`); the path length
        is the legs' optical lengths.
        """
        S = hs["p"]
        n = len(S)
        D = self.detector
        w, residual = legs.aim_through_windows(scene, D, S)
        ix, iy, inside = self.frame.cell_of(ray_plane_point(D, D + w, self.frame), self.width, self.height,
                                            self.pitch_m, cell=self.footprint_m)
        pixel = np.where(inside, iy * self.width + ix, -1)
        if self.capture == "confocal":
            pixel = np.where(pixel == spot_of, pixel, -1)
        det = legs.trace_legs_np(scene, np.broadcast_to(D, w.shape), w)
        si = hs["si"]
        # leaving S along the detector leg's last segment (towards the window): its ``wi``
        out_w = np.stack([np.asarray(c.numpy(), dtype=np.float64) for c in det["si"].to_world(det["si"].wi)],
                         axis=1)
        wo = si.to_local(mi.Vector3f(*[upload(mi.Float, c) for c in out_w.T]))
        f_cos = np.asarray(to_mono(si.bsdf().eval(mi.BSDFContext(), si, wo), si.wavelengths).numpy(),
                           dtype=np.float64)
        cos_s = np.abs(np.sum(out_w * hs["n"], axis=1))
        J = legs.leg_jacobian(scene, D, w)
        vis = det["valid"] & _same_shape(det["shape"], self.relay_wall) & (residual <= 1e-5) & (J > 0)
        cos_ap = np.clip(w @ self.aperture_normal, 0.0, None)
        with np.errstate(divide="ignore", invalid="ignore"):
            photons = (self.photons_per_pulse * hs["throughput"] * det["throughput"] * f_cos * self.aperture_area_m2
                       * cos_ap / (cos_s * J))
        photons = np.where(vis & (pixel >= 0) & (cos_s > 0) & self.include_wall_return, photons, 0.0)
        opl = (hs["opl_m"] + det["opl_m"]) if self.include_first_last else np.zeros(n)
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
            # through windows: the legs' optical path lengths (the first/last segments a reconstruction
            # subtracts; without windows they are the distances to laser_origin / detector_origin)
            **({"spot_leg_opl_m": self.spot_leg_opl_m.tolist(), "pixel_leg_opl_m": self.pixel_leg_opl_m.tolist()}
               if self.windows else {}),
        }


# ---------------------------------------------------------------------- helpers


def _intersect(scene, origins, directions, windows: bool = False) -> dict:
    """Intersect rays (numpy ``[n, 3]``) with the scene; returns numpy fields and shape pointers.

    ``windows``: follow the rays through the scene's windows (device legs,
    :func:`~transient_mi.integrators._device_legs.trace_legs_np`; adds ``throughput``, ``opl_m``, ``si``).
    """
    if windows:
        return legs.trace_legs_np(scene, origins, directions)
    o = np.asarray(origins, dtype=np.float64)
    d = np.asarray(directions, dtype=np.float64)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    ray = mi.Ray3f(mi.Point3f(*[upload(mi.Float, c) for c in o.T]), mi.Vector3f(*[upload(mi.Float, c) for c in d.T]))
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

