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
is computed by :func:`~._nlos_pair_kernels.adjoint_group`, which shares the masses, knots and shares with the
primal's :func:`~._nlos_pair_kernels.spread_group`. Then, as in PRB (geometry detached, the BSDF terms evaluated
again with gradients attached), the product rule: ``dL = sum_i g_i F_i (dN/N) + sum_i A_i df_p,i +
sum_i B_i df_x,i + sum_{s,e} C_se dI_se`` with the detached coefficients ``A_i = g_i F_i / f_p,i`` (computed
as the product of the other factors, so a zero ``f_p`` still gets its derivative), ``B_i``, ``C_se``; each
Dr.Jit term is back-propagated with ``dr.backward_from``. Lambertian BSDFs are evaluated per cell (the wall) and
per (element, spot) (the elements; :mod:`~._nlos_surfaces`), so their coefficients are summed over the pairs
first (``A_c = sum_{i in c} A_i |cos_i|``, ``B_se = sum_{i in e, s} B_i`` over the pairs on the spot's side)
and each value is back-propagated once. The wall's closed-form first-bounce return is
differentiated as in the Monte Carlo estimator (:func:`~._nlos_ad_terms.wall_return_backward`). Reverse mode is
exact: the gradient of the quadrature's own primal (float32 rounding aside). Forward mode is the same linear
map: the tangent of every pair's weight spread with the primal's masses.

What is differentiated: every parameter a Mitsuba ``bsdf.eval`` of the hidden shapes or of the relay wall
reads (reflectances, textures), the laser's ``pulse_energy_j`` and, in reverse mode, the hidden meshes' vertex
positions (:mod:`~._nlos_quadrature_geom`; forward mode refuses geometry in one line). Any other parameter (the
sensor's, the film's) gets no gradient (zero). The error estimate (coarse level, bounds) is not differentiated.
"""

from __future__ import annotations

from contextlib import contextmanager

import drjit as dr
import mitsuba as mi
import numpy as np
from scipy.ndimage import correlate1d

from transient_mi._upload import upload, upload_tensor
from transient_mi.integrators._ad_geometry import geometry_keys
from transient_mi.integrators._nlos_ad_terms import (Backward, TimeKernel, check_sensor_and_variant,
                                                     wall_return_backward, wall_return_inputs, wall_return_photons)
from transient_mi.integrators._nlos_pair_kernels import adjoint_group, spread_group
from transient_mi.integrators._nlos_pairs import Chunk, SpotSide, chunk_starts
from transient_mi.integrators._nlos_quadrature import _Geometry, check_supported, level_elements, patch_cells
from transient_mi.integrators._nlos_quadrature_geom import (check_geometry, geometry_adjoint, mesh_vertex_gradients,
                                                            pair_lengths, vertex_backward)
from transient_mi.integrators._nlos_surfaces import WallCells
from transient_mi.props import PluginParameterError
from transient_mi.scene_io import single_threaded
from transient_mi.time_axis import apply_kernel

#: AD flags: keep the edges (several terms are propagated one after the other through the same parameters,
#: e.g. a reflectance ``x0 + t * d``), clear interior gradients after each; a term that no parameter being
#: differentiated reaches is not an error
_FLAGS = dr.ADFlag.ClearInterior | dr.ADFlag.AllowNoGrad
_FLAGS_FORWARD = dr.ADFlag.Default | dr.ADFlag.AllowNoGrad


@contextmanager
def ordered_sums():
    """Run Dr.Jit's reverse-mode propagation inside on one thread (LLVM variants), so that its scatter-adds (the
    adjoint of a gather: a face attribute's gradient summed over the elements on the face, a texel's over the
    pairs that read it) add in a fixed order and the same inputs give the same bits. With the worker threads the
    order follows the threads' scheduling: the sums differed in their last bits from call to call, and an
    optimiser fed these gradients (the mesh fit's carving, L-BFGS-B) drifted apart over iterations. What runs
    inside is small (per-element and per-cell BSDF values; the pairs' heavy sums are numpy's and the kernels',
    in a fixed order already). Dr.Jit queues the scatter-adds and would run them at the next evaluation, so
    everything pending is evaluated before the thread count is restored (the scene loader's
    :func:`~transient_mi.scene_io.single_threaded`, for the same reason). CUDA variants' atomic adds are not
    ordered by this."""
    with single_threaded():
        yield
        dr.eval()


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
    """The primal's fine level for ``mi.render``'s capture (``spots`` of an array capture, spot 0 by default, or
    every spot of a confocal capture): the same elements (visibility refinement included), cells, spot side, wall
    and chunks."""

    def __init__(self, scene, setup, film, options, spots=(0,)):
        self.confocal = setup.capture == "confocal"
        self.spot_ids = list(range(setup.n_spots)) if self.confocal else list(spots)
        self.g = _Geometry(setup, film, patch_cells(setup, options), options.get("element_slope", True))
        self.P = self.g.W * self.g.H
        self.active = bool(setup.hidden_shapes) and options.get("max_depth", 4) >= 4
        if not self.active:
            return
        hidden_ptrs = mi.ShapePtr(setup.hidden_shapes)
        _, self.lv, _, self.prov = level_elements(scene, setup, self.g, options, self.spot_ids, hidden_ptrs,
                                                  with_provenance=True)
        self.side = SpotSide(scene, setup, self.g, self.spot_ids, self.lv)
        self.wall = WallCells(scene, setup, self.g.cell_p, self.g.D)
        self.lambertian = self.lv.surf.lambertian
        self.G = len(self.spot_ids)
        self.t_origin = self.g.t0_m / self.g.bin_m - self.g.pad

    def chunks(self, scene):
        """``(chunk, fx_pair)`` per chunk (:meth:`~._nlos_pairs.Chunk.fx_pairs`: the primal's per-pair ``f_x`` of
        BSDFs that are not Lambertian)."""
        for e0, e1 in chunk_starts(len(self.g.cell_p), self.lv.n):
            ch = Chunk(scene, self.g, self.lv, self.wall, e0, e1, self.side, self.confocal)
            yield ch, ch.fx_pairs(self.g, self.lv, self.side, self.confocal)

    def rows(self):
        """The rows of :func:`~._nlos_pair_kernels.adjoint_group`'s output: one per spot, one for confocal."""
        return range(1 if self.confocal else self.G)

    def terms(self, ch, fx_pair, row: int) -> dict:
        """Per pair of ``ch`` with the spot of ``row`` (an array capture's spot ``row``, or each pair's pixel's):
        element ``e``, spot ``s``, cell ``c``, ``es = e G + s`` (index of the pair's (element, spot)), the primal's
        ``f_x`` and ``sw`` and, for Lambertian elements, ``match`` (the cell on the spot's side)."""
        e = ch.e0 + np.arange(ch.n) % ch.ne
        s = ch.spot_of_pair() if self.confocal else np.full(ch.n, row, dtype=np.int64)
        t = {"e": e, "s": s, "c": np.arange(ch.n) // ch.ne, "es": e * self.G + s, "sw": self.side.sw[e, s]}
        if self.lambertian:
            t["match"] = ch.side_x * self.side.side_s[e, s] > 0
            t["f_x"] = np.where(t["match"], self.side.fx_e[e, s], 0.0)
        else:
            t["f_x"] = fx_pair[row]
        return t

    def f_x_ad(self, ch, row: int) -> "mi.Float":
        """The element BSDF of every pair of ``ch`` towards the spot of ``row``, per pair (elements that are not
        Lambertian; attached inside ``resume_grad``)."""
        spots = [self.side.S[ch.spot_of_pair()]] if self.confocal else [self.side.S[row]]
        return self.lv.surf.pair_values(self.g.cell_p, ch.e0, ch.e1, spots)[0]

    def f_p_ad(self, ch) -> "mi.Float":
        """The wall BSDF of every pair of ``ch`` (walls that are not Lambertian; attached)."""
        return self.wall.pair_values(self.g.cell_p, self.lv.X0, ch.e0, ch.e1)

    def adjoint(self, ch, grad_ext) -> np.ndarray:
        """``g [R, n]`` per row and pair of ``ch`` (:func:`~._nlos_pair_kernels.adjoint_group`; ``grad_ext``
        ``[R, P, n_ext]``)."""
        g = np.zeros((len(self.rows()), ch.n))
        adjoint_group(g, grad_ext, ch.per_pixel, ch.e0, ch.ne, ch.vis_p, ch.A, ch.w1, ch.w2, ch.tilt, self.side.vis,
                      self.side.B, self.confocal, ch.amp, self.side.amp_s)
        return g

    def pair_lengths(self, ch) -> tuple:
        """The chunk's pair lengths (:func:`~._nlos_quadrature_geom.pair_lengths`) and its pairs' visibility as
        ``bool [n, 4]``: what :meth:`geometry` needs for every spot's row of the chunk (computed once a chunk)."""
        g = self.g
        return pair_lengths(g.cell_p, self.lv.X0, self.lv.tri, ch.e0, ch.e1, g.D, g.cell_ax, g.cell_ay, g.fl,
                            g.cell_half_diag > 0) + (((ch.vis_p[:, None] >> np.arange(4)) & 1).astype(np.bool_),)

    def geometry(self, g_elem, grad_ext, ch, t: dict, row: int, lengths: tuple) -> None:
        """Add the derivative with respect to the element vertices of the chunk's pairs with the spot of ``row`` to
        ``g_elem`` (:func:`~._nlos_quadrature_geom.geometry_adjoint`, once per spot: all the chunk's cells for an
        array capture, each pixel's cells with its own spot for a confocal one); ``lengths``: :meth:`pair_lengths`
        of ``ch``."""
        g, side = self.g, self.side
        r_pv, r_px, opl_d, cell_shift, vis_p = lengths
        m2 = g.m * g.m
        jobs = [(k, k * m2, (k + 1) * m2) for k in range(self.P)] if self.confocal else [(row, 0, len(g.cell_p))]
        for s, c_lo, c_hi in jobs:
            vis_s = np.ascontiguousarray(((side.vis[:, s, None] >> np.arange(4)) & 1).astype(np.bool_))
            geometry_adjoint(g_elem, grad_ext[row], ch.e0, ch.ne, c_lo, c_hi, g.cell_pixel.astype(np.int64), g.cell_p,
                             np.asarray(g.cell_ax, dtype=np.float64), np.asarray(g.cell_ay, dtype=np.float64), g.D,
                             g.fl, g.cell_half_diag > 0, g.normal, self.lv.tri, self.lv.X0, self.lv.nrm, self.lv.area,
                             ch.geo * ch.f_p, t["f_x"], vis_p, r_pv, r_px, opl_d, cell_shift, ch.w1, ch.w2, ch.tilt,
                             vis_s, np.ascontiguousarray(side.sw[:, s]), side.S[s],
                             np.ascontiguousarray(side.r_sv[:, s]), np.ascontiguousarray(side.r_sx[:, s]),
                             g.fl * float(side.laser_leg[s]), g.bin_m, self.t_origin, ch.amp,
                             np.ascontiguousarray(side.amp_s[:, s]) if side.amp_s.shape[0] else np.empty((0, 3)))


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
        grad_ext = kernel_adjoint(grad, taps)  # [G, P, n_ext] (one row for a confocal capture)
        n_es = lv.lv.n * lv.G
        C = np.zeros(n_es)  # coefficients of the spots' intensities, element-major [n, G]
        B = np.zeros(n_es)  # of the Lambertian elements' f_x (per element and spot)
        A = np.zeros(len(lv.g.cell_p))  # of a Lambertian wall's per-cell value
        total = 0.0  # sum_i g_i F_i: the coefficient of dN / N
        g_elem = np.zeros(lv.lv.tri.shape) if geometry else None  # d/d(element vertices) [n, 3, 3]
        for ch, fx_pair in lv.chunks(scene):
            g_rows = lv.adjoint(ch, grad_ext)
            lengths = lv.pair_lengths(ch) if geometry else None  # (shared by the spots' rows)
            for row in lv.rows():
                t = lv.terms(ch, fx_pair, row)
                gg = g_rows[row] * ch.geo
                f_x, sw = t["f_x"], t["sw"]
                total += float(np.sum(gg * ch.f_p * f_x * sw))
                C += np.bincount(t["es"], gg * ch.f_p * f_x / lv.side.r_sx[t["e"], t["s"]] ** 2, minlength=n_es)
                if lv.wall.lambertian:
                    A += np.bincount(t["c"], gg * f_x * sw * ch.cos_p, minlength=len(A))
                if lv.lambertian:
                    B += np.bincount(t["es"], np.where(t["match"], gg * ch.f_p * sw, 0.0), minlength=n_es)
                with dr.resume_grad(), ordered_sums():
                    if not lv.wall.lambertian:
                        dr.backward_from(upload(mi.Float, gg * f_x * sw) * lv.f_p_ad(ch), flags=_FLAGS)
                    if not lv.lambertian:
                        dr.backward_from(upload(mi.Float, gg * ch.f_p * sw) * lv.f_x_ad(ch, row),
                                         flags=_FLAGS)
                if geometry:
                    lv.geometry(g_elem, grad_ext, ch, t, row, lengths)
        with dr.resume_grad(), ordered_sums():
            for coef, value in ((C, lambda: lv.side.intensity_ad(scene, lv.lv.X0)),
                                (A, lv.wall.value_ad), (B, lambda: lv.lv.surf.toward_ad(lv.side.S))):
                if np.any(coef != 0.0):
                    dr.backward_from(upload(mi.Float, coef) * value(), flags=_FLAGS)
            if total != 0.0:
                dr.backward_from(n_att() * (total / lv.g.N), flags=_FLAGS)
        if geometry:
            with ordered_sums():
                vertex_backward(setup.hidden_shapes, mesh_vertex_gradients(setup.hidden_shapes, lv.prov, g_elem),
                                _FLAGS)
    inp = wall_return_inputs(setup, spots)
    if inp is not None:  # (last: it clears the edges it traverses)
        P = setup.width * setup.height
        rec = Backward(grad.reshape(G, P, axis.n_bins), taps, axis, 1, P, G, TimeKernel(axis, 0.0, taps), 1.0)
        with ordered_sums():
            wall_return_backward(scene, setup.relay_wall.bsdf(), inp, n_att, rec, P)


def quadrature_forward(integrator, scene, params, sensor) -> "mi.TensorXf":
    """Forward mode: the derivative of ``mi.render``'s capture along the parameters' tangents (the tangent of
    every pair's weight spread with the primal's masses, plus the wall return's).

    Every attached value (the spots' intensities, the Lambertian BSDFs' per-cell and per-(element, spot) values or,
    for other BSDFs, the pairs' values, the wall return, ``N``) is pushed forward by one ``dr.forward_to`` (a
    second call would not see the parameters' tangents again). With BSDFs that are not Lambertian forward mode
    holds every chunk's pair data at once (memory grows with the pairs; reverse mode's does not)."""
    setup, options, _ = check(integrator, scene, sensor, params)
    film = sensor.film()
    taps, axis = film.kernel_taps(), film.time_axis()
    n_att = setup.laser.photons_per_pulse_ad
    lv = _FineLevel(scene, setup, film, options)
    g = lv.g
    P = g.W * g.H
    hist = np.zeros((1, P, g.n_ext))
    inp = wall_return_inputs(setup, [0])
    held, values = [], []
    per_pair = lv.active and not (lv.lambertian and lv.wall.lambertian)
    with dr.resume_grad():
        values.append(n_att())
        if inp is not None:
            values.append(wall_return_photons(scene, setup.relay_wall.bsdf(), inp, n_att))
        if lv.active:
            values += [lv.side.intensity_ad(scene, lv.lv.X0),
                       lv.wall.value_ad() if lv.wall.lambertian else mi.Float(0.0),
                       lv.lv.surf.toward_ad(lv.side.S) if lv.lambertian else mi.Float(0.0)]
            for ch, fx_pair in (lv.chunks(scene) if per_pair else ()):
                values += [lv.f_p_ad(ch) if not lv.wall.lambertian else mi.Float(0.0),
                           lv.f_x_ad(ch, 0) if not lv.lambertian else mi.Float(0.0)]
                held.append((ch, fx_pair))
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
                hist[0, k, b] += d
    if lv.active:
        d_int, d_wall, d_elem = tangents[i], tangents[i + 1], tangents[i + 2]
        i += 3
        scratch = np.zeros((1, P, g.n_ext))
        z = np.zeros((1, P))
        ones_es = np.ones((lv.lv.n, lv.G))
        for ch, fx_pair in (held if per_pair else lv.chunks(scene)):
            if per_pair:
                d_fp_pair, d_fx_pair = tangents[i], tangents[i + 1]
                i += 2
            t = lv.terms(ch, fx_pair, 0)
            e, s = t["e"], t["s"]
            d_fp = d_wall[t["c"]] * ch.cos_p if lv.wall.lambertian else d_fp_pair
            d_fx = np.where(t["match"], d_elem[t["es"]], 0.0) if lv.lambertian else d_fx_pair
            d_sw = d_int[t["es"]] / lv.side.r_sx[e, s] ** 2
            f_x, sw = t["f_x"], t["sw"]
            tan = ch.geo * (d_fp * f_x * sw + ch.f_p * d_fx * sw + ch.f_p * f_x * d_sw + ch.f_p * f_x * sw * d_log_n)
            spread_group(hist, scratch, z.copy(), z.copy(), z.copy(), ch.per_pixel, ch.e0, ch.ne, tan,
                         np.ones(ch.n), ch.vis_p, ch.A, ch.w1, ch.w2, ch.tilt, ch.side_x, np.ones((1, ch.n)),
                         lv.side.vis, lv.side.B, ones_es, ones_es, lv.side.side_s, False, lv.confocal, ch.amp,
                         lv.side.amp_s)
    out = apply_kernel(hist[0], taps) if g.pad else hist[0]
    return upload_tensor(out.reshape(setup.height, setup.width, axis.n_bins))
