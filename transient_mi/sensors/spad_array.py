"""Sensor ``spad_array``: a SPAD array focused on a grid of relay-wall patches (NLOS capture)."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from transient_mi.props import PluginParameterError, get_bool, get_choice, get_float, get_vector3
from transient_mi.wall import WallFrame

PLUGIN = ("sensor", "spad_array", "SpadArray")

#: Default side of a pixel's wall patch (1 cm, as in the reference experiment).
DEFAULT_PIXEL_FOOTPRINT_M = 0.01
#: Default diameter of the collecting lens (25.4 mm, a one-inch lens).
DEFAULT_APERTURE_DIAMETER_M = 0.0254


class SpadArray(mi.Sensor):
    r"""SPAD array looking at the relay wall (``spad_array``).

    Pixel ``(x, y)`` of a ``width`` x ``height`` array (from the
    ``transient_film`` child) is focused on a square wall patch of side
    ``pixel_footprint_m``; the patch centres form a grid of spacing
    ``pixel_pitch_m`` (default: the footprint, patches tiling the wall)
    centred on ``target`` in the wall plane, x along the wall's x axis (frame of
    :mod:`transient_mi.wall`), pixel (0, 0) at the smallest wall
    coordinates. Each pixel integrates the light leaving its whole patch
    towards the detector's aperture. The values recorded are the expected
    photons per laser pulse per time bin reaching the pixel (before any
    detector effect); the full radiometric chain and the estimator are
    documented in :mod:`transient_mi.integrators.transient_nlos_path`.

    The relay wall is the surface hit by the ray from ``origin`` to
    ``target``; every other shape is hidden geometry (the scene analysis:
    :mod:`transient_mi.sensors._nlos_setup`). Render with the
    ``transient_nlos_path`` integrator (``transient_path`` delegates to it)
    and exactly one ``pulsed_laser``. A ``homogeneous`` medium nested in the
    sensor (``<ref id="fog"/>``) is fog filling the scene: render with
    ``transient_volpath`` (see :mod:`transient_mi.integrators._nlos_medium`).

    Captures (``capture``):

    * ``array``: every pixel records every laser spot of the laser's scan
      grid; one file ``spot_NNNNN.exr`` per spot, in scan order.
    * ``confocal``: pixel ``k`` is recorded with the laser aimed at the
      centre of its own patch; one file (the laser's scan grid is not used).

    .. list-table::
       :header-rows: 1

       * - Parameter
         - Type
         - Description
       * - ``origin``
         - point
         - Detector (aperture centre) position, metres; must be on the
           hidden-space side of the wall (required).
       * - ``target``
         - point
         - Wall point at the centre of the area seen (required).
       * - ``wall_normal``
         - vector
         - Wall normal, pointing to the side of laser and detector
           (default 0, 0, 1).
       * - ``pixel_footprint_m``
         - float
         - Side of the square wall patch one pixel sees, metres, > 0
           (default 0.01).
       * - ``pixel_pitch_m``
         - float
         - Distance between neighbouring patch centres on the wall, metres,
           >= ``pixel_footprint_m`` (default: the footprint, so the patches
           tile the wall). A larger pitch spreads small patches over a large
           wall area, as in a focused SPAD array whose pixels each see
           1 cm^2 of a 1 m wall.
       * - ``array_extent_m``
         - float
         - Alternative to ``pixel_pitch_m``: the side of the wall square the
           array covers; pitch = ``array_extent_m / max(width, height)``
           (patch centres at the centres of that many equal cells). Lets a
           scene change the array size with ``$name`` parameters and keep
           the covered wall area.
       * - ``aperture_diameter_m``
         - float
         - Diameter of the collecting lens, metres, > 0 (default 0.0254);
           the aperture faces ``target``.
       * - ``capture``
         - string
         - ``array`` (default) or ``confocal``.
       * - ``include_first_last``
         - boolean
         - Whether the laser -> wall and wall -> detector segments are in
           the recorded path length (default true; time zero is always the
           pulse leaving the laser).
       * - ``include_wall_return``
         - boolean
         - Whether the wall's own first-bounce return (laser spot seen
           directly by the pixel whose patch contains it) is in the capture
           (default true). Skipping it saves nothing in rendering time but
           keeps the huge direct peak out of the data.
       * - ``pixel_sampling``
         - string
         - ``area`` (default): each pixel integrates over its whole wall
           patch. ``center``: only the light leaving the patch centre is
           traced, multiplied by the patch's solid angle (the point
           approximation used by mitransient and y-tal; faster to converge,
           not the patch integral).

    Errors (raised while the scene loads or before rendering starts):
    detector or laser behind the wall, zero-size footprint or aperture, a
    pixel array larger than the relay wall, laser spots off the wall.
    """

    NAME = "spad_array"

    def __init__(self, props: mi.Properties):
        super().__init__(props)
        name = self.NAME
        self.origin = np.array(get_vector3(props, name, "origin", None))
        self.target = np.array(get_vector3(props, name, "target", None))
        normal = get_vector3(props, name, "wall_normal", (0.0, 0.0, 1.0))
        try:
            self.frame = WallFrame.from_normal(self.target, normal)
        except ValueError as e:
            raise PluginParameterError(f"{name}: {e}") from None
        h = self.frame.height(self.origin)
        if not h > 0:
            raise PluginParameterError(
                f"{name}: origin={tuple(self.origin.tolist())} is behind the relay wall or on it (height "
                f"{h:.4g} m along wall_normal {tuple(self.frame.normal.tolist())} from target); the detector "
                "must be on the hidden-space side (height > 0)")
        self.pixel_footprint_m = get_float(props, name, "pixel_footprint_m", DEFAULT_PIXEL_FOOTPRINT_M,
                                           min_value=0.0, min_exclusive=True)
        if "array_extent_m" in props and "pixel_pitch_m" in props:
            raise PluginParameterError(f"{name}: give pixel_pitch_m or array_extent_m, not both")
        if "array_extent_m" in props:
            extent = get_float(props, name, "array_extent_m", None, min_value=0.0, min_exclusive=True)
            f = self.film()
            self.pixel_pitch_m = extent / max(int(f.size()[0]), int(f.size()[1]))
        else:
            self.pixel_pitch_m = get_float(props, name, "pixel_pitch_m", self.pixel_footprint_m,
                                           min_value=0.0, min_exclusive=True)
        if self.pixel_pitch_m < self.pixel_footprint_m * (1 - 1e-9):
            raise PluginParameterError(
                f"{name}: pixel_pitch_m={self.pixel_pitch_m:g} is smaller than pixel_footprint_m="
                f"{self.pixel_footprint_m:g}; neighbouring patches would overlap (pitch must be >= footprint)")
        self.aperture_diameter_m = get_float(props, name, "aperture_diameter_m", DEFAULT_APERTURE_DIAMETER_M,
                                             min_value=0.0, min_exclusive=True)
        self.capture = get_choice(props, name, "capture", "array", ("array", "confocal"))
        self.include_first_last = get_bool(props, name, "include_first_last", True)
        self.include_wall_return = get_bool(props, name, "include_wall_return", True)
        self.pixel_sampling = get_choice(props, name, "pixel_sampling", "area", ("area", "center"))
        film = self.film()
        if not hasattr(film, "is_transient"):
            raise PluginParameterError(f"{name}: needs a transient_film (or spad_film) child, got {type(film).__name__}")
        self._setup = None
        self._setup_scene_id = None

    # ------------------------------------------------------------ NLOS API

    def nlos_setup(self, scene):
        """The validated :class:`~transient_mi.sensors._nlos_setup.NLOSSetup` for ``scene`` (cached)."""
        from transient_mi.sensors._nlos_setup import NLOSSetup

        if not self._setup_is_for(scene):
            self._setup = None  # the old scene's shapes and laser go first
            self._setup = NLOSSetup.build(scene, self)
            self._setup_scene_id = id(scene)
        return self._setup

    def _setup_is_for(self, scene) -> bool:
        """Whether the cached setup was built for ``scene``.

        No reference to the scene is kept: the scene holds this sensor, and a reference back would be a
        cycle through C++ objects that Python's garbage collector cannot see, so every scene rendered
        would stay alive (and every later Dr.Jit call over emitters or shapes would trace its Python
        plug-ins again). The scene's ``id`` alone could be reused by a new scene after the old one is
        freed; the setup's relay wall, which the setup keeps alive, cannot: a new scene shares it only
        if it is the same scene.
        """
        if self._setup is None or self._setup_scene_id != id(scene):
            return False
        wall = self._setup.relay_wall
        return any(s is wall for s in scene.shapes())

    def forget_nlos_setup(self) -> None:
        """Drop the cached setup (the next :meth:`nlos_setup` rebuilds it: after ``params.update()``)."""
        self._setup = None
        self._setup_scene_id = None

    def capture_layout(self, scene) -> dict:
        """What the render pipeline needs to lay out the capture (see :mod:`transient_mi.render_capture`)."""
        s = self.nlos_setup(scene)
        geometry = s.geometry()
        if self.get_medium() is not None:  # fog: its coefficients (validated as the renderer validates them)
            from transient_mi.integrators._nlos_medium import NLOSMedium

            geometry["medium"] = NLOSMedium.from_sensor(scene, self, s, "transient_volpath").manifest_entry()
        return {
            "capture": s.capture,
            "n_files": s.n_files,
            "quantity": "photons_per_pulse",
            "include_first_last": s.include_first_last,
            "geometry": geometry,
            "laser": s.laser.laser_info(),
        }

    def spot_groups(self, scene, spp: int) -> list[list[int]]:
        """The groups of laser spots the render pipeline renders together (fixed for a configuration).

        Array captures: consecutive spots in scan order, as many per group as
        the histogram memory budget allows (see
        :func:`~transient_mi.integrators._nlos_render.group_layout`); the spots of a
        group share the detector-side sub-paths. Confocal: ``[[0]]``.
        """
        from transient_mi.integrators._nlos_render import group_layout

        s = self.nlos_setup(scene)
        if s.capture == "confocal":
            return [[0]]
        film = self.film()
        pad = len(film.kernel_taps()) // 2
        _, g = group_layout(s.width * s.height, spp, film.n_bins + 2 * pad, s.n_spots)
        return [list(range(a, min(a + g, s.n_spots))) for a in range(0, s.n_spots, g)]

    # ------------------------------------------ Mitsuba interface (debugging)

    def sample_ray(self, time, sample1, sample2, sample3, active=True):
        """A ray from the detector to the point ``sample2`` (film coordinates in [0, 1]^2) of the array's wall area."""
        film = self.film()
        W, H = film.width, film.height
        pitch = self.pixel_pitch_m
        fr = self.frame
        u = (sample2.x - 0.5) * (W * pitch)
        v = (sample2.y - 0.5) * (H * pitch)
        o = mi.Point3f(*[float(c) for c in self.origin])
        q = mi.Point3f(*[float(c) for c in fr.origin]) + u * mi.Vector3f(*fr.ex.tolist()) + \
            v * mi.Vector3f(*fr.ey.tolist())
        return mi.Ray3f(o, mi.Vector3f(dr.normalize(q - o))), mi.Spectrum(1.0)

    def sample_ray_differential(self, time, sample1, sample2, sample3, active=True):
        ray, w = self.sample_ray(time, sample1, sample2, sample3, active)
        return mi.RayDifferential3f(ray), w

    def bbox(self):
        p = mi.ScalarPoint3f(*[float(c) for c in self.origin])
        return mi.ScalarBoundingBox3f(p, p)

    def traverse(self, callback):
        pass

    def to_string(self):
        f = self.film()
        return (f"SpadArray[origin={tuple(self.origin.tolist())}, target={tuple(self.target.tolist())}, "
                f"pixels={f.width}x{f.height}, pixel_footprint_m={self.pixel_footprint_m:g}, "
                f"pixel_pitch_m={self.pixel_pitch_m:g}, "
                f"aperture_diameter_m={self.aperture_diameter_m:g}, capture={self.capture}, "
                f"include_first_last={self.include_first_last}, include_wall_return={self.include_wall_return}, "
                f"pixel_sampling={self.pixel_sampling}]")
