r"""Differentiable NLOS captures: ``render_backward`` / ``render_forward`` of ``transient_nlos_path``.

``mi.render(scene, params)`` on a ``spad_array`` scene returns spot 0 of an array capture (or the confocal
capture) as ``[height, width, n_bins]``; ``dr.backward`` / ``dr.forward`` then call the integrator's
``render_backward`` / ``render_forward``, which run :func:`nlos_backward` / :func:`nlos_forward` here. This
module: the checks, the sample loop and the entry points; the path vertices are in :mod:`._nlos_ad_paths`,
the recorders, the temporal kernel's derivative and the wall return in :mod:`._nlos_ad_terms`.

Same estimator, same samples
----------------------------
The kernel below (:func:`_ad_pass`) is the NLOS estimator of :mod:`._nlos_kernel` (detector - patch point
``p`` - hidden vertex ``X`` - laser spot ``S`` - laser, then further vertices up to ``max_depth``) with the
same lanes, replicates, seeds, randomised QMC numbers and PCG32 draws as the primal
(:func:`~._nlos_render.render_spots`), so for the same seed it replays the primal's samples exactly: its
values equal the primal's to float rounding (tested), and forward mode equals reverse mode on a scalar
loss. Up to the hidden vertex each contribution is computed with gradients attached and back-propagated
(reverse) or pushed forward (forward) at once, inside the sample loop. Beyond it (``max_depth`` 5 to 16:
BSDF parameters and the laser power, mono variants) the deeper vertices are replayed as in PRB
(:func:`~._nlos_ad_paths.deeper`): a first walk sums the adjoint-weighted deeper contributions ``A``, a second walk with the
same random numbers back-propagates each vertex's own terms plus ``A_rest f / detach(f)`` for the BSDF value
sampled there; forward mode carries the derivative of the log-throughput. Nothing of a path is kept on a
tape: memory does not grow with the number of samples or the path length (the unrolled code does).

What is differentiated
----------------------
* BSDF values (the hidden object's and the relay wall's reflectance, ...): at the patch point, the hidden
  vertex, the laser spot (its radiant intensity) and in the closed-form wall return. Sampling densities
  and MIS weights are detached (the gradient stays unbiased).
* The laser's ``pulse_energy_j`` (``mi.traverse`` exposes it; captures are linear in it).
* Geometry of a hidden shape (translation, rotation: a rectangle's ``to_world`` and a mesh's
  ``vertex_positions``, tested; a sphere's ``center``/``radius`` goes through the same code, untested): the hidden
  vertex of a hidden-geometry (area) sample follows the shape (its position at a fixed sample,
  ``RayFlags.FollowShape``), so the cosines at ``p``, ``X`` and ``S``, both inverse squares and the
  arrival time are differentiated: the *interior* derivative. Not differentiated: visibility (the shadow
  ray ``X -> S`` and the check that ``X`` is the first hit from ``p``) and the shape's silhouette (the
  boundary terms): the geometric gradient is biased wherever the moving shape changes what is visible
  (occlusion edges, a shape crossing the laser's or a pixel's field of view), unbiased otherwise (a
  hidden patch fully visible from the patches and the spot). Geometry needs ``hidden_geometry_prob = 1``
  (every hidden vertex area-sampled: BSDF-sampled vertices do not follow the shape) and refuses the relay
  wall's geometry. Rigid motions only: a deformation changes the shape's area, and the area density
  ``1/A`` (and the setup's cached hidden area) is not differentiated (biased, not detected).
* Arrival time (geometry only): with a box time bin a contribution's bin does not change with its path
  length ``s`` (zero derivative). With the film's ``kernel_sigma_ps = sigma > 0`` the arrival time is
  differentiated through the continuous kernel: bin ``b`` receives ``w_b(s) = Phi((t_b+1 - s/c)/sigma) -
  Phi((t_b - s/c)/sigma)`` (the Gaussian integrated over the bin), whose derivative
  ``dw_b/ds = (phi((t_b - s/c)/sigma) - phi((t_b+1 - s/c)/sigma)) / (c sigma)`` is closed form. The value
  of a contribution is spread as the primal spreads it (box bin, then the discrete taps,
  :func:`~transient_mi.time_axis.gaussian_kernel_taps`): the primal's expected histogram is the
  continuous-kernel one with an extra box of one bin (variance ``bin_width^2 / 12``), so the arrival-time
  derivative is that of a kernel narrower by that box (a sub-bin mismatch of about
  ``bin_width^2 / (12 sigma^2)`` of the arrival-time part; measured by ``bench/kernel_mismatch.py``: 0.2 %
  of the gradient at sigma = 3 bins, 2.4 % at one bin, see ``docs/differentiable.md``).

Refused in one line: a divergent laser beam or windows on the device legs (the primal's extensions this
kernel does not replay), ``max_depth`` -1 (unlimited) or > 16, ``max_depth`` > 4 with geometry parameters or in an
rgb variant, a sensor medium, spectral/polarized variants, geometry of the relay wall, geometry with
``hidden_geometry_prob < 1`` or without a temporal kernel (``kernel_sigma_ps = 0``).

Forward mode with geometry runs the sample loop evaluated with evaluated virtual calls (Dr.Jit cannot
forward-propagate a shape parameter into symbolic scopes, drjit issue 295): slower than reverse mode.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from transient_mi._upload import upload_tensor
from transient_mi.integrators._lanes import LaneLayout, seed_rng
from transient_mi.integrators._nlos_ad_paths import connect, deeper, first_bounce
from transient_mi.integrators._nlos_ad_terms import (Backward, Forward, TimeKernel, check_sensor_and_variant,
                                                     wall_return_backward,
                                                     wall_return_forward, wall_return_inputs)
from transient_mi.integrators._nlos_kernel import KernelConstants, KernelScene, _sensor_weight
from transient_mi.integrators._nlos_samples import PixelQMC, lane_pixels
from transient_mi.integrators._nlos_render import group_layout
from transient_mi.integrators._replicates import effective_replicates, replicate_seed
from transient_mi.props import PluginParameterError

#: Longest path (segments) with geometry derivatives and rgb variants: three-bounce light.
MAX_AD_DEPTH = 4
#: Longest path (segments) the differentiable NLOS estimator records (BSDF parameters and the laser power,
#: mono variants); the vertices beyond the hidden one are unrolled.
MAX_UNROLLED_DEPTH = 16
from transient_mi.integrators._ad_geometry import GEOMETRY_KEYS, geometry_keys  # noqa: E402,F401


def _geometry_params(params, setup, name: str) -> bool:
    """Whether ``params`` holds a grad-enabled hidden-shape geometry parameter; refuses the relay wall's."""
    keys = geometry_keys(params)
    for key in keys:
        node = params.properties[key][2]
        if node == setup.relay_wall or (hasattr(node, "ptr") and node.ptr == setup.relay_wall.ptr):
            raise PluginParameterError(
                f"{name}: {key} moves the relay wall; differentiable NLOS captures support the geometry of "
                "hidden shapes only")
    return bool(keys)


def check(integrator, scene, sensor, params):
    """Refuse what the differentiable NLOS estimator does not support (one line); returns
    ``(setup, geometry)``."""
    name = integrator.NAME
    check_sensor_and_variant(name, sensor)
    depth = integrator.max_depth_param
    if depth == -1 or depth > MAX_UNROLLED_DEPTH:
        raise PluginParameterError(
            f"{name}: max_depth={depth}; differentiable NLOS captures need a finite max_depth in "
            f"[1, {MAX_UNROLLED_DEPTH}] (the vertices beyond the hidden one are unrolled)")
    deeper = depth > MAX_AD_DEPTH
    if deeper and (mi.is_rgb or mi.is_spectral or mi.is_polarized):
        raise PluginParameterError(
            f"{name}: max_depth={depth}; differentiable NLOS captures beyond three-bounce light need a *_mono "
            f"variant, not {mi.variant()} (or max_depth in [1, {MAX_AD_DEPTH}])")
    if sensor.get_medium() is not None:
        raise PluginParameterError(f"{name}: differentiable NLOS captures through a medium are not supported")
    # (the cached scene analysis is rebuilt by the primal render that mi.render runs first, see
    # _path_options.render_tensor; what the derivatives read of it, the wall's spots and pixels and the hidden
    # shapes' areas, does not change with the supported parameters)
    setup = sensor.nlos_setup(scene)
    # (features of the primal this estimator does not replay; absent from older setups)
    divergence = float(getattr(setup.laser, "divergence_mrad", 0.0))
    if divergence > 0:
        raise PluginParameterError(
            f"{name}: the pulsed_laser's divergence_mrad={divergence:g}; differentiable NLOS captures need a "
            "collimated beam (divergence_mrad=0)")
    if getattr(setup, "windows", False):
        raise PluginParameterError(
            f"{name}: the scene has windows (delta-transmissive shapes on the device legs); differentiable NLOS "
            "captures through windows are not supported")
    geometry = _geometry_params(params, setup, name)
    if geometry and deeper:
        raise PluginParameterError(
            f"{name}: max_depth={depth}; derivatives with respect to hidden geometry record up to three-bounce "
            f"light: max_depth must be in [1, {MAX_AD_DEPTH}]")
    alpha = float(integrator.nlos_options["hidden_geometry_prob"])
    if geometry and alpha != 1.0:
        raise PluginParameterError(
            f"{name}: hidden_geometry_prob={alpha:g}; derivatives with respect to hidden geometry need "
            "hidden_geometry_prob=1 (BSDF-sampled hidden vertices do not follow the shape)")
    if geometry and not sensor.film().kernel_sigma_ps > 0:
        raise PluginParameterError(
            f"{name}: the film's kernel_sigma_ps=0; derivatives with respect to hidden geometry need a temporal "
            "kernel (kernel_sigma_ps > 0): a box time bin has no derivative with respect to arrival time")
    return setup, geometry


@dr.syntax
def _ad_pass(scene, rec, rng, layout, j0, j1, c: KernelConstants, ks: KernelScene, n_att, geometry: bool,
             n_group: int, loop_mode: str):
    """The samples ``[j0, j1)`` of every lane, as :func:`._nlos_kernel.nlos_pass`."""
    group = None if ks.group is None else (n_group, ks.group)
    wall_ptr = ks.wall_ptr
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
            si_c.wi = si_c.to_local(-dr.normalize(si_c.p - c.detector))
        else:
            si_c = scene.ray_intersect(mi.Ray3f(c.detector, dr.normalize(centre - c.detector)),
                                       ray_flags=mi.RayFlags.All, coherent=True)
        to_c = centre - c.detector
        w0_c = _sensor_weight(c, dr.normalize(to_c), dr.squared_norm(to_c))
        opl_c = c.first_last_factor * dr.norm(si_c.p - c.detector)
    j = mi.UInt32(dr.opaque(mi.UInt32, j0))
    j_end = dr.opaque(mi.UInt32, j1)
    spp = dr.opaque(mi.UInt32, layout.spp)
    ctx = mi.BSDFContext()
    while dr.hint((j < j_end) & (k + j * K < spp), mode=loop_mode, max_iterations=-1):
        i_sample = k + j * K
        u = qmc.numbers(c, rng, i_sample)
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
            si = scene.ray_intersect(mi.Ray3f(c.detector, d0), ray_flags=mi.RayFlags.All, coherent=True)
            opl = c.first_last_factor * si.t
        active = si.is_valid()
        beta = mi.Spectrum(1.0)
        connect(scene, rec, lane, si, beta, w0, opl, active, c, spot, group, wall_ptr, ctx, n_att, geometry)
        active &= 5 <= c.max_depth + 1
        si2, weight, eta, active = first_bounce(scene, si, active, u[2:], rng, c, ks, ctx, geometry)
        with dr.resume_grad():
            opl2 = opl + dr.norm(si2.p - si.p)
        vis = mi.Bool(True) if c.spot_is_wall_point else None
        connect(scene, rec, lane, si2, weight, w0, opl2, active, c, spot, group, wall_ptr, ctx, n_att, geometry,
                 visible=vis, depth=2)
        if dr.hint(c.max_depth_static > 4, mode="scalar"):
            deeper(scene, rec, rng, lane, si2, weight, w0, opl2, eta, active, c, spot, group, wall_ptr, ctx, n_att)
        with dr.resume_grad():
            rec.flush()
        j += 1
    return rng


def _passes(integrator, scene, sensor, setup, seed, spp, spots, make_rec, geometry, loop_mode="symbolic"):
    """Run the kernel over every replicate (the primal's seeds and lanes); ``make_rec(layout)`` gives the
    recorder (the same object may be returned for every replicate)."""
    film = sensor.film()
    taps = film.kernel_taps()
    axis = film.time_axis()
    W, H = setup.width, setup.height
    options = dict(integrator.nlos_options)
    options["max_depth"] = integrator.max_depth_param
    options["rr_depth"] = integrator.rr_depth
    confocal = setup.capture == "confocal"
    R = effective_replicates(spp, integrator.replicates_for(True))
    n = spp // R
    K, _ = group_layout(W * H, n, axis.n_bins + 2 * (len(taps) // 2), 1 if confocal else setup.n_spots)
    layout = LaneLayout(W * H, n, K)
    laser = setup.laser
    ks = KernelScene.build(scene, setup, spots)
    rec = None
    for r in range(R):
        s = replicate_seed(seed, r, R)
        rng = seed_rng(s, layout.n_lanes)
        c = KernelConstants.build(setup, options, seed=s, n_group=len(spots))
        rec = make_rec(layout, R)
        for j0, j1 in layout.passes():
            rng = _ad_pass(scene, rec, rng, layout, j0, j1, c, ks, laser.photons_per_pulse_ad, geometry,
                           len(spots), loop_mode)
            if hasattr(rec, "evaluate"):
                rec.evaluate(rng)
            else:
                dr.eval(rng.state)
    return rec, layout, R


def _delta_shape(setup, grad_in, T, spots) -> np.ndarray:
    g = np.asarray(grad_in, dtype=np.float64)
    want = (setup.height, setup.width, T) if len(spots) == 1 else (len(spots), setup.height, setup.width, T)
    if g.size != int(np.prod(want)):
        raise PluginParameterError(f"render_backward: grad_in has shape {g.shape}; expected {want}")
    return g.reshape(len(spots), setup.height * setup.width, T)


def nlos_backward(integrator, scene, params, grad_in, sensor, seed: int, spp: int, spots=None) -> None:
    """Reverse mode: propagate ``grad_in`` (``[height, width, n_bins]``, the adjoint of ``mi.render``'s spot-0
    capture; ``[len(spots), height, width, n_bins]`` for a spot group) to the scene parameters."""
    setup, geometry = check(integrator, scene, sensor, params)
    spots = [0] if spots is None else [int(j) for j in spots]
    film = sensor.film()
    taps, axis = film.kernel_taps(), film.time_axis()
    spp = spp or int(sensor.sampler().sample_count())
    delta = _delta_shape(setup, grad_in, axis.n_bins, spots)
    time = TimeKernel(axis, film.kernel_sigma_ps, taps)
    P = setup.width * setup.height
    rec_holder = {}

    def make_rec(layout, R):
        if "rec" not in rec_holder:
            rec_holder["rec"] = Backward(delta, taps, axis, layout.streams, P, len(spots), time,
                                          1.0 / (layout.spp * R))
        return rec_holder["rec"]

    _passes(integrator, scene, sensor, setup, seed, spp, spots, make_rec, geometry)
    inp = wall_return_inputs(setup, spots)
    if inp is not None:
        wall_return_backward(scene, setup.relay_wall.bsdf(), inp, setup.laser.photons_per_pulse_ad,
                              rec_holder["rec"], P)


def nlos_forward(integrator, scene, params, sensor, seed: int, spp: int, spots=None) -> mi.TensorXf:
    """Forward mode: the derivative of ``mi.render``'s capture (``[height, width, n_bins]``; a spot group:
    ``[len(spots), height, width, n_bins]``) along the parameters' tangents."""
    setup, geometry = check(integrator, scene, sensor, params)
    spots = [0] if spots is None else [int(j) for j in spots]
    film = sensor.film()
    taps, axis = film.kernel_taps(), film.time_axis()
    spp = spp or int(sensor.sampler().sample_count())
    time = TimeKernel(axis, film.kernel_sigma_ps, taps)
    holder = {}

    def make_rec(layout, R):
        if "rec" not in holder:
            holder["rec"] = Forward(layout, axis, taps, len(spots), time)
        return holder["rec"]

    # geometry: the shape's parameters enter the loop body (and the shapes' virtual calls) from outside, which
    # symbolic scopes cannot forward-propagate (drjit issue 295): the sample loop runs evaluated (one kernel
    # per sample index) with evaluated virtual calls (slower; reverse mode has no such restriction)
    evaluated = geometry or integrator.max_depth_param > MAX_AD_DEPTH  # (deeper paths: the same restriction)
    with dr.scoped_set_flag(dr.JitFlag.SymbolicCalls, not evaluated):
        rec, layout, R = _passes(integrator, scene, sensor, setup, seed, spp, spots, make_rec, geometry,
                                 "evaluated" if evaluated else "symbolic")
        inp = wall_return_inputs(setup, spots)
        if inp is not None:
            wall_return_forward(scene, setup.relay_wall.bsdf(), inp, setup.laser.photons_per_pulse_ad, rec.hist,
                                 layout.streams, float(layout.spp * R), "evaluated" if evaluated else "symbolic")
            rec.hist.evaluate()
    G, P, T = len(spots), setup.width * setup.height, axis.n_bins
    out = np.zeros((G, P, T))
    tsum = None
    if rec.tdata is not None:
        t = np.asarray(rec.tdata, dtype=np.float64).reshape(P, layout.streams, G, T)
        tsum = t.sum(axis=1) / (layout.spp * R)  # [P, G, T]
    for g, (h, _, _, _) in enumerate(rec.hist.collect_all(taps, scale=1.0 / R)):
        out[g] = h
        if tsum is not None:
            out[g] += tsum[:, g, :]
    shape = (setup.height, setup.width, T) if G == 1 else (G, setup.height, setup.width, T)
    return upload_tensor(out.reshape(shape))
