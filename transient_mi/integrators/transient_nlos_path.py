r"""Integrator ``transient_nlos_path``: the NLOS estimator, photons per laser pulse reaching each SPAD pixel,
per time bin.

It renders captures of a ``spad_array`` sensor lit by a ``pulsed_laser``
(laser-spot and hidden-geometry sampling, below); ``transient_path`` under a
``spad_array`` delegates to the same code (:func:`render_nlos`) with its own
parameters, so both give the same bytes for the same seed. The code is split
by job:

* :mod:`transient_mi.sensors._nlos_setup`: the scene analysis
  (:class:`~transient_mi.sensors._nlos_setup.NLOSSetup`: relay wall, hidden
  geometry, laser spots, pixel patches, the closed-form wall return,
  validation), cached by the sensor;
* :mod:`transient_mi.integrators._nlos_render`: replicates, spot groups and
  their histograms (:func:`~transient_mi.integrators._nlos_render.render_spots`);
* :mod:`transient_mi.integrators._nlos_kernel`: the Dr.Jit kernel (patch
  point, spot connections, one-sample MIS, randomised QMC);
* :mod:`transient_mi.integrators._device_legs`: the device legs (laser ->
  spot, detector -> patch) through windows, and divergent-beam spots;
* this module: the plug-in, its parameters and the render call.

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
   Through windows (below) ``T_L N`` photons arrive and ``w_L`` is the
   refracted beam's direction; a divergent beam (``pulsed_laser``
   ``divergence_mrad``) spreads the ``N`` photons over a footprint of spots
   ``S(w)``, ``w`` distributed like the beam's angular profile.
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
   (photons), resolved by arrival time. Through windows the pixel keeps its
   cone of directions and the radiance arriving at ``D`` is ``T_D`` times the
   radiance leaving the (displaced) wall point along the refracted ray.
5. Arrival time: the optical path length of the whole path divided by c,
   time zero being the pulse leaving the laser. With
   ``include_first_last=false`` the first (``|L - S|``) and last
   (``|p - D|``) segments are left out of the recorded path length (the
   actual sampled segments); through windows these two legs count with their
   optical path length ``sum_i n_i d_i``.
6. The wall's own first-bounce return (``L -> S -> D``) is a delta in space
   and time: the pixel whose patch contains ``S`` receives
   ``N f_s(S; w_L, w_SD) cos(theta_S) A_ap cos(theta_ap) / |S - D|^2``
   photons at path length ``|L - S| + |S - D|`` (0 without first/last),
   added in closed form (no sampling noise); ``include_wall_return=false``
   leaves it out. Through windows: ``N T_L T_D f_s cos(theta_S) A_ap
   cos(theta_ap) / (cos(theta_S) J)`` with ``J`` the wall area per solid
   angle at ``D`` along the refracted leg (``|S - D|^2 / cos(theta_S)``
   without window), in the pixel whose cone of directions holds that leg, at
   the legs' optical path length. A divergent beam's return is integrated
   over its footprint by a fixed 64 x 64 quadrature of beam directions
   (energy and width exact, see :mod:`transient_mi.sensors._nlos_setup`).

Estimator (unbiased)
--------------------
Per sample, for the lane's pixel ``k`` (and its laser spot ``S``: the
array's current spot, or in confocal mode the spot on patch ``k``):

* **Device legs through windows.** A *window* is a shape whose BSDF has no
  smooth component and transmits (``dielectric``, ``thindielectric``,
  ``null``). The detector ray ``D -> q`` and the laser ray ``L -> S`` follow
  the transmitted branch of every window they meet (up to 8 interfaces) to
  the first smooth surface, deterministically: Snell refraction, the leg's
  weight times the Fresnel transmittance of each interface (a
  ``thindielectric``'s total transmittance), its optical path ``n_i d_i``
  per segment (:mod:`transient_mi.integrators._device_legs`). Reflections
  at the windows (ghosts, relative amplitude ~``R^2``) are not rendered.
  Scenes without windows compile none of this (same bytes as before).
* **Divergent beam.** With ``divergence_mrad > 0`` every spot connection
  samples its own beam direction (PCG32) and connects to the spot it hits:
  an unbiased estimate of the footprint's light.

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
  (probability ``alpha``, integrator parameter ``hidden_geometry_prob``):
  a hidden shape is chosen in proportion to its area and a point ``X``
  uniformly on it (area pdf ``1/A_hidden`` for every hidden point), as in
  Royo et al. 2022, "Non-line-of-sight transient rendering". The ray towards ``X`` is traced; if its first hit is not
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
* **Spot groups (array captures):** :func:`~._nlos_render.render_spots`
  renders several spots together; they share each sample's detector-side sub-path and
  differ only in the final spot connection (each estimate unbiased).
* **Patch centres only** (``pixel_sampling="center"``): the wall point is
  the patch centre (the point approximation of mitransient/y-tal); in
  confocal captures it is the laser spot itself, so the segment back to
  the spot is the one just traced and needs no shadow ray (not through
  windows or with a divergent beam: there the spot is traced on its own).

The *relay wall* is the shape hit by the ray (through windows) from the
detector to the array's ``target``; *hidden geometry* is every other shape
with a smooth BSDF component (a shape with only delta lobes, a window or a
mirror, contributes nothing to a spot connection, so sampling points on it
would only waste samples: it is left out of hidden-geometry sampling and of
the MIS weight). Other emitters of the scene are ignored: only the laser
lights an NLOS capture.

Fog: a ``spad_array`` with a sensor medium is refused here (and by
``transient_path``) in one line; ``transient_volpath`` renders it, with this
estimator extended to a homogeneous medium (free flights, medium vertices,
connections to the laser beam: :mod:`transient_mi.integrators._nlos_medium`).

Histograms are accumulated per SIMD lane (:mod:`._lanes`): same seed, same
bytes.

Differentiable rendering
------------------------
``mi.render(scene, params)`` then ``dr.backward`` / ``dr.forward`` differentiate a capture (spot 0 of an
array capture, or the confocal capture) with the same samples as the primal: BSDF values (hidden and
relay-wall reflectances) and the laser's ``pulse_energy_j`` (exposed by ``mi.traverse``) for a finite
``max_depth`` up to 16 (beyond three-bounce light in *_mono variants), the closed-form wall return, and
hidden-shape geometry up to three-bounce light (``max_depth <= 4``; translation, rotation: the interior
derivative, with the arrival time through the film's temporal kernel; visibility and silhouette terms
are not differentiated). See :mod:`transient_mi.integrators._nlos_ad` and
``docs/differentiable.md``. With ``estimator="quadrature"`` the derivative is that of the deterministic
estimator (BSDF values and ``pulse_energy_j``; geometry refused):
:mod:`transient_mi.integrators._nlos_quadrature_ad`.
"""

from __future__ import annotations

import mitsuba as mi

from transient_mi.integrators._path_options import (as_int, check_render_call, estimator_suffix, read_nlos_options,
                                                     read_path_params, render_tensor, replicates_for)
from transient_mi.props import PluginParameterError
from transient_mi.integrators._sensor_checks import is_nlos_sensor

PLUGIN = ("integrator", "transient_nlos_path", "TransientNLOSPath")


def sensor_name(sensor) -> str:
    """How an error names ``sensor``: its class and, if it has one, its id (``PerspectiveCamera 'cam'``)."""
    kind = str(sensor).split("[", 1)[0].strip() or type(sensor).__name__
    sid = sensor.id()
    return f"{kind} {sid!r}" if sid else kind


def render_nlos(integrator, scene, sensor, *, seed: int, spp: int, spot: int | None = None, spots=None,
                progress=None, replicate_offset: int = 0, replicates: int | None = None, media: bool = False):
    """Render an NLOS capture's laser spot, spot group or confocal capture with ``integrator``'s parameters.

    The render call of ``transient_nlos_path`` and of ``transient_path`` under a ``spad_array`` (checked
    already by :func:`~._path_options.check_render_call`). ``integrator`` provides ``max_depth_param``,
    ``rr_depth``, ``nlos_options`` (``rqmc``, ``hidden_geometry_prob``; read at every call) and
    ``replicates_for``. Returns one ``TransientResult`` for ``spot`` (default 0), a list for ``spots``; the
    film keeps the (last) result. ``media``: the caller renders through the sensor's medium
    (``transient_volpath``, :mod:`~._nlos_medium`); otherwise a sensor medium is refused in one line.
    """
    from transient_mi.integrators._nlos_render import render_spots

    options = dict(integrator.nlos_options)
    options["plugin"] = integrator.NAME
    options["variance_replicates"] = integrator.replicates_for(True)
    options.setdefault("max_depth", integrator.max_depth_param)
    options.setdefault("rr_depth", integrator.rr_depth)
    group = [0 if spot is None else int(spot)] if spots is None else [int(j) for j in spots]
    film = sensor.film()
    medium = sensor.get_medium()
    if medium is not None and not media:
        raise PluginParameterError(
            f"{integrator.NAME}: the sensor {sensor_name(sensor)} sits in the medium "
            f"{medium.id() or type(medium).__name__!r}; NLOS captures through a medium: use transient_volpath")
    setup = sensor.nlos_setup(scene)
    if medium is not None:
        from transient_mi.integrators._nlos_medium import NLOSMedium
        options["medium"] = NLOSMedium.from_sensor(scene, sensor, setup, integrator.NAME)
    results = render_spots(setup, scene, film, options, seed=seed, spp=spp, spots=group,
                           progress=progress, replicate_offset=replicate_offset, replicates=replicates)
    film.set_result(results[-1])
    return results if spots is not None else results[0]


class TransientNLOSPath(mi.CppADIntegrator):
    r"""NLOS path tracer (``transient_nlos_path``).

    Renders the capture of a ``spad_array`` sensor lit by exactly one
    ``pulsed_laser``: the expected photons per laser pulse reaching every
    SPAD pixel, per time bin, by path tracing from the detector through the
    pixel's relay-wall patch into the hidden scene, with deterministic
    connections to the laser spot at every vertex and one-sample MIS between
    hidden-geometry and BSDF sampling at the wall (the radiometry and the
    estimator are documented in :mod:`transient_mi.integrators.transient_nlos_path`).
    Array captures give one result per laser spot; spots rendered together
    (``spots=``) share every sample's detector-side sub-path.

    It needs an NLOS sensor: a camera sensor is refused when rendering (use
    ``transient_path`` for camera views). ``transient_path`` under a
    ``spad_array`` runs this same estimator with its own parameters (same
    names, same defaults): same seed, same bytes.

    .. list-table::
       :header-rows: 1

       * - Parameter
         - Type
         - Description
       * - ``max_depth``
         - integer
         - Longest path in path segments from the detector to the laser
           (Mitsuba's meaning): 1 or 2 = only the wall's own first-bounce
           return (``detector - spot - laser``, added in closed form at any
           depth unless the sensor's ``include_wall_return`` is false),
           3 = also wall points lit by the spot (nothing on a planar wall),
           4 = three-bounce NLOS light (``detector - wall - hidden - spot -
           laser``, the signal NLOS reconstruction uses), 5 and more:
           further bounces; -1 = unlimited, with Russian roulette (default).
           >= 1 or -1.
       * - ``rr_depth``
         - integer
         - Depth at which Russian roulette starts, >= 1 (default 5).
       * - ``variance_replicates``
         - integer
         - Independent replicates each render is split into, in [1, 1024]
           (default 1: no variance; ``transient-mi render`` uses 8 for NLOS
           captures): the capture stores their mean and the variance of
           every bin (see :mod:`transient_mi.integrators._replicates`);
           ``gcd(spp, variance_replicates)`` are used.
       * - ``rqmc``
         - boolean
         - Randomised quasi-Monte Carlo (a shifted Kronecker sequence) for
           the patch point and the first bounce (default true); false draws
           them from PCG32 (plain Monte Carlo), for comparisons.
       * - ``hidden_geometry_prob``
         - float
         - Probability of hidden-geometry sampling (vs BSDF sampling) for
           the direction leaving the relay-wall patch point, in [0, 1]
           (default 0.8); 0 is BSDF sampling only. Unused in scenes without
           hidden geometry.
       * - ``estimator``
         - string
         - ``monte_carlo`` (default: the path tracer above) or
           ``quadrature``: the deterministic three-bounce estimator
           (:mod:`transient_mi.integrators._nlos_quadrature`; no samples, no
           noise: ``spp`` and the replicates are ignored, and the capture
           stores an error estimate instead of a variance). It renders mesh
           hidden shapes behind a planar wall, without windows, media or a
           divergent beam; other captures are refused in one line. With
           ``max_depth`` above 4 (or -1) the light beyond three bounces is
           added by this Monte Carlo estimator without the three-bounce
           connection and the wall return (``spp`` and the replicates then
           set its noise): the capture stores the remainder's variance and
           the quadrature's error side by side
           (:mod:`transient_mi.capture_error`).
       * - ``element_size_m``
         - float
         - ``quadrature``: longest edge of a hidden-surface element, m, in
           [1e-5, 10] (default 0.01). The error falls as its square, the cost
           rises as its inverse square.
       * - ``patch_cells``
         - integer
         - ``quadrature``: cells per side of a pixel's wall patch, in [1, 64]
           (default 4; the error estimate compares with half as many,
           ``m // 2``, so an odd count above one states far more error
           than it has: prefer even; with one, the cells' part of the error
           is estimated on the coarse elements, one cell against two; one
           point, the centre, with ``pixel_sampling="center"``).
       * - ``refine_levels``
         - integer
         - ``quadrature``: times an element of mixed visibility is split in
           four, in [0, 8] (default 1: on the paper scene, 8 x 8 pixels, 8 ps bins,
           one cell per patch, levels 0, 1, 2, 3 stated error ratios 0.13,
           0.10, 0.095, 0.093 at 10 ms in 1.5, 2.2, 3.8 and 4.4 s,
           bench/results/quadrature_settings_a8_b8.json; the light still
           mixed is bounded).
       * - ``element_slope``
         - boolean
         - ``quadrature``: weight each element linearly in arrival time
           (its weight's regression on its vertices' arrival times: exact
           bin masses of that weight, docs/quadrature.md) (default true);
           false takes the weight at the centroid alone, as before
           2026-12-07, for comparisons.

    Determinism: each SIMD lane accumulates its own histogram slot (see
    :mod:`transient_mi.integrators._lanes`), so the same seed gives the same
    bytes.

    Variants: renders need a JIT variant (``llvm_*``, ``cuda_*``);
    ``scalar_*`` variants load scenes and construct the plug-ins.
    """

    NAME = "transient_nlos_path"

    def __init__(self, props: mi.Properties):
        super().__init__(props)
        self.max_depth_param, self.rr_depth, replicates = read_path_params(props, self.NAME)
        #: None: the default for the sensor (see :meth:`replicates_for`)
        self.variance_replicates = replicates
        #: ``rqmc``, ``hidden_geometry_prob`` (read at every render: studies may change them)
        self.nlos_options = read_nlos_options(props, self.NAME)

    def replicates_for(self, nlos: bool = True) -> int:
        """Replicates a render is split into (see :func:`~._path_options.replicates_for`)."""
        return replicates_for(self.variance_replicates)

    # ---------------------------------------------------------------- API

    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True, progress=None):
        """Render and return the histograms as ``mi.TensorXf [height, width, n_bins]`` (spot 0).

        The film keeps the full :class:`~transient_mi.films.transient_film.TransientResult`; the sensor's
        scene analysis is rebuilt (see :func:`~._path_options.render_tensor`).
        """
        return render_tensor(self, scene, sensor, seed, spp, progress)

    def render_backward(self, scene, params, grad_in, sensor=0, seed=0, spp=0):
        """Reverse mode (what ``dr.backward`` after ``mi.render(scene, params)`` calls): propagate ``grad_in``
        (``[height, width, n_bins]``, spot 0 or the confocal capture) to the scene parameters. What is
        differentiated: :mod:`transient_mi.integrators._nlos_ad` (a finite ``max_depth``); with
        ``estimator="quadrature"``, :mod:`transient_mi.integrators._nlos_quadrature_ad` (BSDF values and
        ``pulse_energy_j``, no geometry)."""
        from transient_mi.integrators._nlos_ad import nlos_backward

        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        if self.nlos_options.get("estimator") == "quadrature":
            from transient_mi.integrators._nlos_quadrature_ad import quadrature_backward

            quadrature_backward(self, scene, params, grad_in, sensor)
            return
        nlos_backward(self, scene, params, grad_in, sensor, as_int(seed), as_int(spp))

    def render_forward(self, scene, params, sensor=0, seed=0, spp=0):
        """Forward mode (``dr.forward``): the derivative of the capture along the parameters' tangents."""
        from transient_mi.integrators._nlos_ad import nlos_forward

        if isinstance(sensor, int):
            sensor = scene.sensors()[sensor]
        if self.nlos_options.get("estimator") == "quadrature":
            from transient_mi.integrators._nlos_quadrature_ad import quadrature_forward

            return quadrature_forward(self, scene, params, sensor)
        return nlos_forward(self, scene, params, sensor, as_int(seed), as_int(spp))

    def render_transient(self, scene, sensor, *, seed: int = 0, spp: int = 0, spot: int | None = None,
                         spots=None, progress=None, replicate_offset: int = 0, replicates: int | None = None):
        """Render one laser spot (or a group of spots, or the confocal capture) of an NLOS capture.

        Parameters
        ----------
        scene, sensor
            Mitsuba scene and its ``spad_array`` sensor (whose film is a transient film).
        seed : int
            Seed of the random streams (0 <= seed < 2**32).
        spp : int
            Samples per pixel; 0 takes the sensor's sampler value.
        spot : int, optional
            Laser spot to render (scan order; default 0, the only one of a confocal capture).
        spots : sequence of int, optional
            A group of laser spots to render together (array captures, see
            ``spad_array.spot_groups``); a list of results is returned.
        progress : callable, optional
            ``progress(done_paths, total_paths)`` after every kernel launch.
        replicate_offset : int
            Index of the first replicate: a later batch of a progressive
            render (``render --noise-target``) continues the replicate seeds
            (see :mod:`transient_mi.integrators._replicates`).
        replicates : int, optional
            Replicates of this call (overrides ``variance_replicates``; must
            divide ``spp``).

        Returns
        -------
        TransientResult, or a list of them for ``spots``
            Histograms ``[height, width, n_bins]`` in photons per pulse per bin.
        """
        if not is_nlos_sensor(sensor):
            raise PluginParameterError(
                f"{self.NAME}: the sensor {sensor_name(sensor)} is not an NLOS sensor; {self.NAME} renders "
                "spad_array captures (use transient_path for cameras)")
        _, spp = check_render_call(self.NAME, sensor, seed, spp, replicates)
        return render_nlos(self, scene, sensor, seed=seed, spp=spp, spot=spot, spots=spots, progress=progress,
                           replicate_offset=replicate_offset, replicates=replicates)

    def to_string(self):
        o = self.nlos_options
        return (f"TransientNLOSPath[max_depth={self.max_depth_param}, rr_depth={self.rr_depth}, "
                f"variance_replicates={self.variance_replicates or 'default'}, "
                f"hidden_geometry_prob={o['hidden_geometry_prob']:g}, rqmc={str(o['rqmc']).lower()}"
                f"{estimator_suffix(o)}]")
