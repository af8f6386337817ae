r"""Derivatives of the deterministic three-bounce estimator (``estimator="quadrature"``): ``render_backward`` /
``render_forward`` of ``transient_nlos_path`` when its estimator is the quadrature
(:mod:`transient_mi.integrators._nlos_quadrature`).

The capture is linear in every pair's weight
--------------------------------------------
The fine level (the result) deposits each (element, cell) pair ``i`` with the weight
``F_i = N geo_i f_p,i f_x,i I_e / r_SX,e^2`` (``geo`` the detached geometry, ``f_p`` the wall BSDF at the
cell towards the element, ``f_x`` the element's BSDF towards the spot, ``I`` the spot's intensity
``f_S cos`` towards the element, ``N`` photons per pulse) times its visible share ``v_i`` over the bins with
the masses ``m_ib``, which depend on geometry only:

.. math::

    h_{kb} = \sum_{i \in k} v_i F_i m_{ib} \; (+ \text{the wall return}), \qquad
    \frac{\partial L}{\partial F_i} = g_i = v_i \sum_b \bar h_{kb} m_{ib},

with ``\bar h`` the adjoint of the padded histogram: the adjoint of the capture (spot 0, or the confocal
capture), correlated with the film's temporal kernel taps (the adjoint of the primal's convolution). ``g_i``
is computed by :func:`~._nlos_time_spread.adjoint_spot`, which shares the masses, knots and shares with the
primal's :func:`~._nlos_time_spread.spread_spot`. Then, as in PRB (geometry detached, the BSDF terms evaluated
again with gradients attached), the product rule: ``dL = sum_i g_i F_i (dN/N) + sum_i A_i df_p,i +
sum_i B_i df_x,i + sum_{s,e} C_se dI_se`` with the detached coefficients ``A_i = g_i F_i / f_p,i`` (computed
as the product of the other factors, so a zero ``f_p`` still gets its derivative), ``B_i``, ``C_se``; each
Dr.Jit term is back-propagated with ``dr.backward_from``. The wall's closed-form first-bounce return is
differentiated as in the Monte Carlo estimator (:func:`~._nlos_ad_terms.wall_return_backward`). Reverse mode is
exact: the gradient of the quadrature's own primal (float32 rounding aside). Forward mode is the same linear
map: the tangent of every pair's weight spread with the primal's masses.

What is differentiated: every parameter a Mitsuba ``bsdf.eval`` of the hidden shapes or of the relay wall
reads (reflectances, textures) and the laser's ``pulse_energy_j``. Geometry is not: a grad-enabled shape
geometry parameter (``vertex_positions``, ``to_world``, ...: hidden shapes, mannequin joints, the relay wall)
is refused in one line (use ``estimator=monte_carlo``). Any other parameter (the sensor's, the film's) gets
no gradient (zero). The error estimate (coarse level, bounds) is not differentiated.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
from scipy.ndimage import correlate1d

from transient_mi.integrators._ad_geometry import geometry_keys
from transient_mi.integrators._nlos_ad_terms import (Backward, TimeKernel, check_sensor_and_variant,
                                                     wall_return_backward, wall_return_inputs, wall_return_photons)
from transient_mi.integrators._nlos_quadrature import (Chunk, _Geometry, _SpotSide, bsdf_value, check_supported,
                                                       chunk_starts, element_terms, level_elements, patch_cells,
                                                       spot_intensity)
from transient_mi.integrators._nlos_quadrature_geom import (check_geometry, geometry_adjoint,
                                                            mesh_vertex_gradients, vertex_backward)
from transient_mi.integrators._nlos_time_spread import adjoint_spot, spread_spot
from transient_mi.props import PluginParameterError
from transient_mi.time_axis import apply_kernel

#: AD flags: keep the edges (several terms are propagated one after the other through the same parameters,
#: e.g. a reflectance ``x0 + t * d``), clear interior gradients after each; a term that no parameter being
#: differentiated reaches is not an error
_FLAGS = dr.ADFlag.ClearInterior | dr.ADFlag.AllowNoGrad
_FLAGS_FORWARD = dr.ADFlag.Default | dr.ADFlag.AllowNoGrad


def check(integrator, scene, sensor, params, allow_geometry=False):
    """Refuse what the quadrature's derivatives do not support (one line); returns ``(setup, options,
    geometry)``, ``geometry`` whether hidden meshes' vertices are being differentiated (reverse mode only)."""
    name = integrator.NAME
    check_sensor_and_variant(name, sensor)
    if sensor.get_medium() is not None:
        raise PluginParameterError(f"{name}: estimator=quadrature cannot render through a medium (fog); use "
                                   "estimator=monte_carlo")
    setup = sensor.nlos_setup(scene)
    options = dict(integrator.nlos_options)
    options.setdefault("max_depth", integrator.max_depth_param)
    check_supported(setup, options, name)
    keys = geometry_keys(params)
    if keys and not allow_geometry:
        raise PluginParameterError(
            f"{name}: {keys[0]} is being differentiated; estimator=quadrature's forward mode differentiates BSDF "
            "values and the laser's pulse_energy_j, not geometry (use reverse mode, or estimator=monte_carlo)")
    if keys:
        check_geometry(name, setup, params, keys)
    return setup, options, bool(keys)


def kernel_adjoint(grad: np.ndarray, taps) -> np.ndarray:
    """The adjoint of :func:`~transient_mi.time_axis.apply_kernel`: ``[.., T]`` -> ``[.., T + 2 pad]``."""
    pad = len(taps) // 2
    if pad == 0:
        return np.ascontiguousarray(grad, dtype=np.float64)
    ext = np.pad(np.asarray(grad, dtype=np.float64), [(0, 0)] * (grad.ndim - 1) + [(pad, pad)])
    return np.ascontiguousarray(correlate1d(ext, np.asarray(taps, dtype=np.float64), axis=-1, mode="constant",
                                            cval=0.0))


class _FineLevel:
    """The primal's fine level for ``mi.render``'s capture (spot 0, or every spot of a confocal capture):
    the same elements (visibility refinement included), cells, spot side and chunks."""

    def __init__(self, scene, setup, film, options, spots=(0,)):
        self.confocal = setup.capture == "confocal"
        self.spot_ids = list(range(setup.n_spots)) if self.confocal else list(spots)
        self.g = _Geometry(setup, film, patch_cells(setup, options))
        self.P = self.g.W * self.g.H
        self.active = bool(setup.hidden_shapes) and options.get("max_depth", 4) >= 4
        if not self.active:
            return
        self.hidden_ptrs = mi.ShapePtr(setup.hidden_shapes)
        _, _, self.tri, self.idx, _, self.prov = level_elements(scene, setup, self.g, options, self.spot_ids,
                                                                self.hidden_ptrs, with_provenance=True)
        self.side = _SpotSide(scene, setup, self.spot_ids, self.tri, self.idx, self.hidden_ptrs)
        self.pts, self.area, self.nrm = element_terms(self.tri)
        self.X0 = self.pts[:, 0]
        self.spot_weight = self.side.intensity / self.side.r_sx ** 2  # [G, n]
        self.t_origin = self.g.t0_m / self.g.bin_m - self.g.pad

    def intensity_ad(self, scene, spots) -> "mi.Float":
        """The intensities of the spots ``spots`` (indices into ``spot_ids``) towards every element's centroid,
        spot-major ``[len(spots) * n]``, in one launch (attached; call inside ``resume_grad``)."""
        s = self.side
        n = len(self.X0)
        spots = np.asarray(spots, dtype=np.int64)
        return spot_intensity(scene, s.Lo, np.repeat(s.beam[spots], n, axis=0), np.repeat(s.S[spots], n, axis=0),
                              np.tile(self.X0, (len(spots), 1)))

    def chunks(self, scene):
        """``(chunk, spot_of_pair, f_x, [(spot, pair slice, job pixel_start, f_x of the job)])`` per chunk (primal
        values; ``f_x`` the last job's, which is every job's in a confocal or one-spot capture)."""
        for e0, e1 in chunk_starts(self.g, len(self.tri)):
            ch = Chunk(scene, self.g, self.tri, self.idx, self.hidden_ptrs, self.pts, self.area, self.nrm, e0, e1)
            n = len(ch.ee)
            spot_of = np.zeros(n, dtype=np.int64)
            f_x = np.zeros(n)
            jobs = []
            for si_idx, _, sl in ch.jobs(self.confocal, len(self.spot_ids)):
                if sl.stop <= sl.start:
                    continue
                spot_of[sl] = si_idx
                if not self.confocal and jobs:  # (another spot of an array capture: its own BSDF values)
                    f_x = np.zeros(n)
                f_x[sl] = np.asarray(bsdf_value(ch.si_x_of(self.confocal, sl),
                                                ch.to_spot(self.X0, self.side.S[si_idx], sl)), dtype=np.float64)
                jobs.append((si_idx, sl, ch.job_pixel_start(self.confocal, si_idx, sl), f_x))
            yield ch, spot_of, f_x, jobs
            del ch

    def spot_args(self, si_idx: int):
        """The per-spot arguments of :func:`~._nlos_time_spread.adjoint_spot` after ``w2``."""
        s, g = self.side, self.g
        return (np.ascontiguousarray(s.vis[si_idx]), np.ascontiguousarray(s.r_sv[si_idx]), s.r_sx[si_idx],
                g.fl * float(s.laser_leg[si_idx]), g.bin_m, self.t_origin)

    def geometry_job(self, g_elem, grad_ext, ch, f_x, si_idx: int, sl: slice) -> None:
        """Add one job's derivative with respect to the element vertices to ``g_elem`` (``geometry_adjoint``)."""
        g, s = self.g, self.side
        ne = (ch.ee[-1] - ch.ee[0] + 1) if len(ch.ee) else 0
        e0 = int(ch.ee[0])
        c_lo, c_hi = sl.start // ne, sl.stop // ne
        geometry_adjoint(g_elem, grad_ext, e0, ne, c_lo, c_hi, g.cell_pixel.astype(np.int64), g.cell_p,
                         np.asarray(g.cell_ax, dtype=np.float64), np.asarray(g.cell_ay, dtype=np.float64), g.D, g.fl,
                         g.cell_half_diag > 0, g.normal, self.tri, self.X0, self.nrm, self.area, ch.geo * ch.f_p, f_x,
                         *ch.spread_args(), *self.spot_weight_args(si_idx))

    def spot_weight_args(self, si_idx: int):
        """The per-spot arguments of ``geometry_adjoint`` after ``w2``."""
        s, g = self.side, self.g
        return (np.ascontiguousarray(s.vis[si_idx]), np.ascontiguousarray(self.spot_weight[si_idx]), s.S[si_idx],
                np.ascontiguousarray(s.r_sv[si_idx]), s.r_sx[si_idx], g.fl * float(s.laser_leg[si_idx]), g.bin_m,
                self.t_origin)

    def f_x_ad(self, ch, spot_of) -> "mi.Float":
        """The element BSDF of every pair of ``ch`` towards its spot (attached; inside ``resume_grad``)."""
        to_s = self.side.S[spot_of] - self.X0[ch.ee]
        return bsdf_value(ch.si_x, to_s / np.linalg.norm(to_s, axis=1, keepdims=True))


def _grad_shape(setup, grad_in, T, G: int = 1) -> np.ndarray:
    g = np.asarray(grad_in, dtype=np.float64)
    want = (G, setup.height, setup.width, T) if G > 1 else (setup.height, setup.width, T)
    if g.size != int(np.prod(want)):
        raise PluginParameterError(f"render_backward: grad_in has shape {g.shape}; expected {want}")
    return g.reshape(G, setup.height * setup.width, T)


def quadrature_backward(integrator, scene, params, grad_in, sensor, spots=None) -> None:
    """Reverse mode: propagate ``grad_in`` (``[height, width, n_bins]``, the adjoint of ``mi.render``'s capture;
    with ``spots`` of an array capture ``[len(spots), height, width, n_bins]``, the adjoint of those spots'
    captures) to the BSDF parameters, the laser's pulse energy and the hidden meshes' vertices (see the module
    docstring and :mod:`~._nlos_quadrature_geom`)."""
    setup, options, geometry = check(integrator, scene, sensor, params, allow_geometry=True)
    spots = [0] if spots is None or setup.capture == "confocal" else [int(j) for j in spots]
    with dr.suspend_grad():  # (the pairs' geometry detached: its derivative is geometry_adjoint's)
        _backward(scene, setup, options, sensor, grad_in, geometry, spots)


def _backward(scene, setup, options, sensor, grad_in, geometry: bool, spots) -> None:
    film = sensor.film()
    taps, axis = film.kernel_taps(), film.time_axis()
    G = len(spots)
    grad = _grad_shape(setup, grad_in, axis.n_bins, G)
    n_att = setup.laser.photons_per_pulse_ad
    lv = _FineLevel(scene, setup, film, options, spots)
    if lv.active:
        grad_ext = kernel_adjoint(grad, taps)
        C = np.zeros_like(lv.spot_weight)  # coefficients of the spots' intensities [G, n]
        total = 0.0  # sum_i g_i F_i: the coefficient of dN / N
        g_elem = np.zeros(lv.tri.shape) if geometry else None  # d/d(element vertices) [n, 3, 3]
        for ch, spot_of, f_x, jobs in lv.chunks(scene):
            g = np.zeros(len(ch.ee))
            for si_idx, sl, ps, f_x in jobs:
                ge = grad_ext[0 if lv.confocal else si_idx]
                g_job = np.zeros(len(ch.ee)) if G > 1 else g
                adjoint_spot(g_job, ge, ps, ch.pe, *ch.spread_args(), *lv.spot_args(si_idx))  # (g[sl])
                if G > 1:  # (every spot's pairs are all of the chunk's: one g per spot)
                    _spot_terms(lv, ch, f_x, g_job, si_idx, C)
                    total += float(np.sum(g_job * ch.geo * ch.f_p * f_x * lv.spot_weight[si_idx, ch.ee]))
                if geometry:
                    lv.geometry_job(g_elem, ge, ch, f_x, si_idx, sl)
            if G > 1:
                continue
            sw = lv.spot_weight[spot_of, ch.ee]
            gg = g * ch.geo
            total += float(np.sum(gg * ch.f_p * f_x * sw))
            np.add.at(C, (spot_of, ch.ee), gg * ch.f_p * f_x / lv.side.r_sx[spot_of, ch.ee] ** 2)
            with dr.resume_grad():
                obj = (mi.Float((gg * f_x * sw).astype(np.float32)) * bsdf_value(ch.si_p, ch.d_px)
                       + mi.Float((gg * ch.f_p * sw).astype(np.float32)) * lv.f_x_ad(ch, spot_of))
                dr.backward_from(obj, flags=_FLAGS)
        with dr.resume_grad():
            lit = np.flatnonzero(np.any(C != 0.0, axis=1))
            if len(lit):
                dr.backward_from(mi.Float(C[lit].ravel().astype(np.float32)) * lv.intensity_ad(scene, lit),
                                 flags=_FLAGS)
            if total != 0.0:
                dr.backward_from(n_att() * (total / lv.g.N), flags=_FLAGS)
            if geometry:
                vertex_backward(setup.hidden_shapes, mesh_vertex_gradients(setup.hidden_shapes, lv.prov, g_elem),
                                _FLAGS)
    inp = wall_return_inputs(setup, spots)
    if inp is not None:  # (last: it clears the edges it traverses)
        P = setup.width * setup.height
        rec = Backward(grad.reshape(G, P, axis.n_bins), taps, axis, 1, P, G, TimeKernel(axis, 0.0, taps), 1.0)
        wall_return_backward(scene, setup.relay_wall.bsdf(), inp, n_att, rec, P)


def _spot_terms(lv, ch, f_x, g, si_idx: int, C) -> None:
    """One spot's BSDF terms of a chunk (array captures of several spots: ``g`` that spot's pair adjoints),
    back-propagated as in the one-spot pass, and its spot-intensity coefficients added to ``C``."""
    sw = lv.spot_weight[si_idx, ch.ee]
    gg = g * ch.geo
    C[si_idx, :] += np.bincount(ch.ee, weights=gg * ch.f_p * f_x / lv.side.r_sx[si_idx, ch.ee] ** 2,
                                minlength=C.shape[1])
    spot_of = np.full(len(ch.ee), si_idx, dtype=np.int64)
    with dr.resume_grad():
        dr.backward_from(mi.Float((gg * f_x * sw).astype(np.float32)) * bsdf_value(ch.si_p, ch.d_px)
                         + mi.Float((gg * ch.f_p * sw).astype(np.float32)) * lv.f_x_ad(ch, spot_of), flags=_FLAGS)


def quadrature_forward(integrator, scene, params, sensor) -> "mi.TensorXf":
    """Forward mode: the derivative of ``mi.render``'s capture along the parameters' tangents (the tangent of
    every pair's weight spread with the primal's masses, plus the wall return's).

    Every attached value (the pairs' BSDF values, the spots' intensities, the wall return, ``N``) is pushed
    forward by one ``dr.forward_to`` (a second call would not see the parameters' tangents again): forward mode
    holds every chunk's pair data at once (memory grows with the pairs; reverse mode does not)."""
    setup, options, _ = check(integrator, scene, sensor, params)
    film = sensor.film()
    taps, axis = film.kernel_taps(), film.time_axis()
    n_att = setup.laser.photons_per_pulse_ad
    lv = _FineLevel(scene, setup, film, options)
    g = lv.g
    P = g.W * g.H
    hist = np.zeros((P, g.n_ext))
    inp = wall_return_inputs(setup, [0])
    chunks, values = [], []
    with dr.resume_grad():
        values.append(n_att())
        if inp is not None:
            values.append(wall_return_photons(scene, setup.relay_wall.bsdf(), inp, n_att))
        if lv.active:
            values.append(lv.intensity_ad(scene, np.arange(len(lv.spot_ids))))
            for ch, spot_of, f_x, jobs in lv.chunks(scene):
                values += [bsdf_value(ch.si_p, ch.d_px), lv.f_x_ad(ch, spot_of)]
                del ch.si_p, ch.si_x  # (the surface interactions are no longer needed)
                chunks.append((ch, spot_of, f_x, jobs))
        tangents = [np.asarray(t, dtype=np.float64) for t in dr.forward_to(*values, flags=_FLAGS_FORWARD)]
    d_log_n = float(tangents[0][0]) / g.N
    i = 1
    if inp is not None:
        d_ph = tangents[1]
        i = 2
        pix = np.asarray(inp["pixel"], dtype=np.int64)
        opl = np.asarray(inp["opl"], dtype=np.float64)
        for k, o, d in zip(pix, opl, d_ph):  # (binned as the primal's wall return)
            b = int(np.floor((o - g.t0_m) / g.bin_m)) + g.pad
            if 0 <= b < g.n_ext:
                hist[k, b] += d
    if lv.active:
        d_int = tangents[i].reshape(len(lv.spot_ids), len(lv.tri))
        i += 1
        scratch = np.zeros((P, g.n_ext))
        z = np.zeros(P)
        ones_e = np.ones(len(lv.tri))
        for ch, spot_of, f_x, jobs in chunks:
            d_fp, d_fx = tangents[i], tangents[i + 1]
            i += 2
            sw = lv.spot_weight[spot_of, ch.ee]
            d_sw = d_int[spot_of, ch.ee] / lv.side.r_sx[spot_of, ch.ee] ** 2
            t = ch.geo * (d_fp * f_x * sw + ch.f_p * d_fx * sw + ch.f_p * f_x * d_sw + ch.f_p * f_x * sw * d_log_n)
            ones = np.ones(len(ch.ee))
            for si_idx, sl, ps, _ in jobs:
                spread_spot(hist, scratch, z.copy(), z.copy(), z.copy(), ps, ch.pe, t, *ch.spread_args(), ones,
                            np.ascontiguousarray(lv.side.vis[si_idx]), ones_e, *lv.spot_args(si_idx)[1:])
    out = apply_kernel(hist, taps) if g.pad else hist
    return mi.TensorXf(out.astype(np.float32).reshape(setup.height, setup.width, axis.n_bins))
