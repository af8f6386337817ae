"""The per-contribution terms of the differentiable NLOS estimator (:mod:`._nlos_ad`): the recorders that
back-propagate (:class:`Backward`) or push forward (:class:`Forward`) each contribution, the continuous temporal
kernel's derivative (:class:`TimeKernel`), and the closed-form wall return's derivative. Distances in metres,
times in picoseconds; histograms ``[slot, bin]`` with the slots of :mod:`._lanes`.
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from transient_core.units import C_M_PER_PS
from transient_mi._upload import upload
from transient_mi.integrators._lanes import LaneHistogram, LaneLayout, to_mono
from transient_mi.integrators._nlos_render import GroupHistogram

#: AD flags: a term that no parameter being differentiated reaches is not an error
_FLAGS = dr.ADFlag.Default | dr.ADFlag.AllowNoGrad


class TimeKernel:
    """The continuous temporal kernel's bin weights' derivative ``dw_b/ds`` (1/m) near a path length."""

    def __init__(self, axis, sigma_ps: float, taps):
        self.on = sigma_ps > 0
        self.T = axis.n_bins
        self.M = len(taps) // 2 + 1  # bins each side of the contribution's own
        self._t0 = dr.opaque(mi.Float, axis.t0_ps)
        self._bw = dr.opaque(mi.Float, axis.bin_width_ps)
        self._inv_sigma = dr.opaque(mi.Float, 1.0 / sigma_ps if sigma_ps > 0 else 0.0)
        self._k = dr.opaque(mi.Float, 1.0 / (C_M_PER_PS * sigma_ps * math.sqrt(2 * math.pi)) if sigma_ps > 0
                            else 0.0)

    def weights(self, opl):
        """``[(bin b (Int32), dw_b/ds)]`` for the ``2 M + 1`` bins around the bin of ``opl`` (detached)."""
        tau = mi.Float(dr.detach(opl)) / C_M_PER_PS
        x = (tau - self._t0) / self._bw
        b0 = mi.Int32(dr.floor(dr.select(dr.isfinite(x), dr.clip(x, -1e9, 1e9), -1e9)))
        out = []
        prev = None
        for m in range(-self.M, self.M + 2):  # edges t_b, b = b0 - M .. b0 + M + 1
            e = self._t0 + mi.Float(b0 + m) * self._bw
            z = (e - tau) * self._inv_sigma
            g = dr.exp(-0.5 * z * z)
            if prev is not None:
                out.append((b0 + (m - 1), self._k * (prev - g)))
            prev = g
        return out


class Backward:
    """Reverse mode: back-propagates ``delta . c`` of each contribution (and its arrival-time term)."""

    def __init__(self, delta, taps, axis, layout_K, P, G, time: TimeKernel, scale: float):
        pad = len(taps) // 2
        self.T = axis.n_bins
        d = np.asarray(delta, dtype=np.float64).reshape(G * P, self.T)
        d_ext = np.pad(d, ((0, 0), (pad, pad)))
        if pad:
            from scipy.ndimage import convolve1d  # adjoint of the primal's convolution (symmetric taps)
            d_ext = convolve1d(d_ext, taps, axis=1, mode="constant", cval=0.0)
        self.T_ext = self.T + 2 * pad
        self.delta_ext = upload(mi.Float, d_ext)
        self.delta = upload(mi.Float, d)
        self.binner = LaneHistogram(LaneLayout(1, 1, 1), axis, pad)
        self.K, self.P = layout_K, P
        self.time = time
        self.scale = scale
        self._pending = []

    def record(self, lane, sub, opl, val, ok, geometry: bool, score=None):
        valid, _, b_ext, invalid = self.binner.bin_index(dr.detach(opl))
        slot = mi.UInt32(sub) * self.P + mi.UInt32(lane) // self.K
        ok_v = mi.Bool(ok) & valid & ~invalid
        d = dr.gather(mi.Float, self.delta_ext, slot * self.T_ext + mi.UInt32(dr.maximum(b_ext, 0)), ok_v)
        obj = d * dr.select(ok_v, val, 0.0)
        if geometry and self.time.on:
            ok_t = mi.Bool(ok) & ~invalid
            g = mi.Float(0.0)
            for b, w in self.time.weights(opl):
                inb = ok_t & (b >= 0) & (b < self.T)
                g += dr.gather(mi.Float, self.delta, slot * self.T + mi.UInt32(dr.maximum(b, 0)), inb) * w
            obj += dr.detach(dr.select(ok_t, val * g, 0.0)) * opl
        self._pending.append(obj)

    def take(self):
        """The sum of the terms recorded since the last call (attached), and forget them."""
        obj = mi.Float(0.0)
        for o in self._pending:
            obj = obj + o
        self._pending = []
        return obj

    def flush(self):
        """Back-propagate the sample's recorded terms at once (one reduction into the parameters' gradients
        per sample rather than one per contribution)."""
        if self._pending:
            dr.backward_from(self.scale * self.take(), flags=_FLAGS)


class Forward:
    """Forward mode: records the tangent of each contribution (and its arrival-time term) in histograms."""

    def __init__(self, layout, axis, taps, G, time: TimeKernel):
        self.hist = GroupHistogram(layout, axis, len(taps) // 2, G)
        self.time = time
        self.G = G
        self.T = axis.n_bins
        self.tdata = dr.zeros(mi.Float, layout.n_lanes * G * self.T) if time.on else None

    def record(self, lane, sub, opl, val, ok, geometry: bool, score=None):
        """``score``: the derivative of the log-throughput accumulated before this vertex (deeper paths), whose
        share ``val * score`` is added to the tangent."""
        dv, ds = dr.forward_to(val, opl, flags=_FLAGS)
        dv, ds = dr.detach(dv), dr.detach(ds)
        if score is not None:
            dv = dv + dr.detach(val) * score
        self.hist.record(lane, dr.detach(opl), dr.select(ok, dv, 0.0), ok, sub=sub)
        if geometry and self.time.on:
            slot = mi.UInt32(lane) * self.G + mi.UInt32(sub)
            c_ds = dr.detach(val) * ds
            for b, w in self.time.weights(opl):
                inb = mi.Bool(ok) & (b >= 0) & (b < self.T) & dr.isfinite(c_ds)
                dr.scatter_reduce(dr.ReduceOp.Add, self.tdata, c_ds * w, slot * self.T + mi.UInt32(dr.maximum(b, 0)),
                                  inb, mode=dr.ReduceMode.NoConflicts)

    def flush(self):
        pass

    def evaluate(self, rng):
        if self.tdata is not None:
            dr.eval(self.hist.data, self.hist.counts, self.tdata, rng.state)
        else:
            self.hist.evaluate(rng.state)


def wall_return_inputs(setup, spots):
    """What the closed-form wall return of ``spots`` needs (as :meth:`NLOSSetup._wall_return`): ``None`` if no
    spot returns light to a pixel, else ``dict(lane_pixel, sub, opl, ray, to_detector, geometric)`` (Dr.Jit
    arrays; ``geometric = A_ap cos(theta_ap) / |S - D|^2``)."""
    wr = setup.wall_return
    confocal = setup.capture == "confocal"
    all_spots = np.arange(setup.n_spots) if confocal else np.array(spots)
    sub = np.zeros(len(all_spots), dtype=np.uint32) if confocal else np.arange(len(spots), dtype=np.uint32)
    pix = wr["pixel"][all_spots]
    Lo, D = setup.laser_origin, setup.detector
    toD = D - setup.spots[all_spots]
    dist = np.linalg.norm(toD, axis=1)
    w = toD / dist[:, None]
    cos_ap = np.clip(-(w @ setup.aperture_normal), 0.0, None)
    sel = (pix >= 0) & (cos_ap > 0) & setup.include_wall_return
    if not sel.any():
        return None
    S, w, cos_ap, dist = setup.spots[all_spots][sel], w[sel], cos_ap[sel], dist[sel]
    d = S - Lo
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    n = len(S)
    return {"pixel": upload(mi.UInt32, pix[sel]), "sub": upload(mi.UInt32, sub[sel]),
            "opl": upload(mi.Float, wr["opl_m"][all_spots][sel]), "n": n,
            "ray": mi.Ray3f(mi.Point3f(*[upload(mi.Float, np.full(n, Lo[i])) for i in range(3)]),
                            mi.Vector3f(*[upload(mi.Float, d[:, i]) for i in range(3)])),
            "detector": mi.Point3f(*[upload(mi.Float, np.full(n, D[i])) for i in range(3)]),
            "w": mi.Vector3f(*[upload(mi.Float, c) for c in w.T]),
            "geometric": upload(mi.Float, setup.aperture_area_m2 * cos_ap / dist ** 2)}


def wall_return_photons(scene, wall_bsdf, inp, n_att):
    """Photons per pulse of each spot's wall return (``mi.Float``, attached to the wall's BSDF and the laser's
    pulse energy). Every spot is on the relay wall: its BSDF is called directly."""
    si = scene.ray_intersect(inp["ray"])
    visible = ~scene.ray_test(si.spawn_ray_to(inp["detector"]))
    f = to_mono(wall_bsdf.eval(mi.BSDFContext(), si, si.to_local(inp["w"])), si.wavelengths)
    return dr.select(visible, f * inp["geometric"] * n_att(), 0.0)


@dr.syntax
def wall_return_backward(scene, wall_bsdf, inp, n_att, rec, P):
    """Back-propagate the wall return's adjoint (inside a one-iteration symbolic loop: a kernel compiled once;
    outside a loop the BSDF's backward pass would be compiled anew at every call)."""
    i = dr.zeros(mi.UInt32, inp["n"])
    while dr.hint(i < 1, mode="symbolic", exclude=[inp], max_iterations=-1):
        with dr.resume_grad():
            photons = wall_return_photons(scene, wall_bsdf, inp, n_att)
            valid, _, b_ext, _ = rec.binner.bin_index(inp["opl"])
            slot = inp["sub"] * P + inp["pixel"]
            d = dr.gather(mi.Float, rec.delta_ext, slot * rec.T_ext + mi.UInt32(dr.maximum(b_ext, 0)), valid)
            dr.backward_from(d * photons, flags=_FLAGS)
        i += 1


@dr.syntax
def wall_return_forward(scene, wall_bsdf, inp, n_att, hist, K: int, weight: float, loop_mode: str):
    """Record the wall return's tangent (times ``weight``) in ``hist`` at lane ``pixel * K`` (one-iteration
    loop, as :func:`wall_return_backward`)."""
    i = dr.zeros(mi.UInt32, inp["n"])
    while dr.hint(i < 1, mode=loop_mode, exclude=[inp], max_iterations=-1):
        with dr.resume_grad():
            photons = wall_return_photons(scene, wall_bsdf, inp, n_att)
            d_ph = dr.detach(dr.forward_to(photons, flags=_FLAGS))
        hist.record(inp["pixel"] * K, inp["opl"], d_ph * weight, mi.Bool(True), sub=inp["sub"])
        i += 1


def check_sensor_and_variant(name: str, sensor) -> None:
    """Refuse, in one line, a differentiable NLOS render of a sensor that is not a ``spad_array`` or in a
    spectral or polarized variant (shared by both estimators' derivatives)."""
    from transient_mi.integrators._sensor_checks import is_nlos_sensor
    from transient_mi.props import PluginParameterError

    if not is_nlos_sensor(sensor):
        raise PluginParameterError(f"{name}: differentiable rendering needs a spad_array sensor, not "
                                   f"{type(sensor).__name__}")
    if mi.is_spectral or mi.is_polarized:
        raise PluginParameterError(f"{name}: differentiable NLOS captures support *_mono and *_rgb variants, "
                                   f"not {mi.variant()}")
