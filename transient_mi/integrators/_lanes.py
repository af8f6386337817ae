"""Deterministic time-binned accumulation shared by the transient integrators.

Why lanes own their histograms
------------------------------
Adding floats with atomics from several threads makes the result depend on
thread scheduling (float addition is not associative), so the same seed
would not give the same bytes. Instead every SIMD lane owns one histogram
slot: lane ``l = pixel * K + k`` (``K`` sample streams per pixel) traces the
samples ``k, k + K, k + 2K, ... < spp`` of its pixel one after another and
adds them into its own slot, so each slot sees one writer in a fixed order.
At the end the ``K`` slots of a pixel are summed in a fixed order (one
output element per lane of a gather kernel).
``K`` depends only on the film size, ``spp`` and the backend (never on the
number of threads), so results are byte-identical across runs and machines
with the same backend.

One lane-layout policy (:func:`streams_for`) serves both integrators; only
the lane target differs (:data:`CAMERA_TARGET_LANES_LLVM`,
:data:`CAMERA_TARGET_LANES_CUDA` for cameras, :data:`NLOS_GROUP_TARGET_LANES`
for NLOS spot groups) and the memory bound: a camera's lane histograms hold
``lanes * n_bins_ext`` float32 values (``n_bins_ext`` = bins plus kernel
padding), kept under :data:`MAX_SLOT_FLOATS` by reducing ``K``; an NLOS spot
group's memory is bounded by the number of spots rendered together instead
(see :func:`transient_mi.integrators._nlos_render.group_layout`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from transient_core.stack import band_edges_nm
from transient_core.units import C_M_PER_PS
from transient_mi.time_axis import TimeAxis, apply_kernel

#: Lanes per launch for cameras (:func:`choose_streams`): many lanes, enough to fill every CPU thread's
#: SIMD units (LLVM) or the GPU (CUDA); each lane traces few samples, and the lane histograms are summed
#: once per render.
CAMERA_TARGET_LANES_LLVM = 1 << 15
CAMERA_TARGET_LANES_CUDA = 1 << 19
#: Lanes per launch for NLOS spot groups (:func:`~transient_mi.integrators._nlos_render.group_layout`): few
#: lanes, since every lane holds one histogram per spot of its group and these are zeroed and summed for
#: every launch; fewer lanes leave room for more spots per group (which share the detector-side
#: sub-paths), and each lane loops over many samples.
NLOS_GROUP_TARGET_LANES = 1 << 10
#: Upper bound on the float32 values held in a camera's lane histograms (1 GiB).
MAX_SLOT_FLOATS = 1 << 28
#: Paths per kernel launch (one progress-bar step).
PATHS_PER_PASS = 1 << 21


def is_cuda() -> bool:
    return mi.variant().startswith("cuda_")


def streams_for(n_pixels: int, spp: int, n_bins_ext: int, target_lanes: int, max_floats: int | None) -> int:
    """Sample streams ``K`` per pixel: the layout policy of every transient integrator.

    ``K`` is the largest power of two with ``K <= spp``, ``n_pixels * K <= target_lanes`` and (unless
    ``max_floats`` is None) ``n_pixels * K * n_bins_ext <= max_floats`` float32 histogram values; at least 1.
    It depends only on these numbers (never on the number of threads): same seed, same bytes.

    Raises
    ------
    MemoryError
        ``max_floats`` is given and even ``K = 1`` needs more than ``max_floats`` values.
    """
    k = 1
    while (k * 2 <= spp and n_pixels * k * 2 <= target_lanes
           and (max_floats is None or n_pixels * k * 2 * n_bins_ext <= max_floats)):
        k *= 2
    if max_floats is not None and n_pixels * n_bins_ext > max_floats:
        raise MemoryError(
            f"film of {n_pixels} pixels x {n_bins_ext} bins needs {n_pixels * n_bins_ext * 4 / 2**30:.1f} GiB "
            "of histogram memory; use fewer pixels or bins"
        )
    return k


def choose_streams(n_pixels: int, spp: int, n_bins_ext: int) -> int:
    """Sample streams ``K`` per pixel of a camera render (a power of two, 1 <= K <= spp; see :func:`streams_for`)."""
    target = CAMERA_TARGET_LANES_CUDA if is_cuda() else CAMERA_TARGET_LANES_LLVM
    return streams_for(n_pixels, spp, n_bins_ext, target, MAX_SLOT_FLOATS)


def seed_rng(seed: int, n_lanes: int):
    """One PCG32 stream per lane, decorrelated with the TEA hash (as Mitsuba's samplers)."""
    idx = dr.arange(mi.UInt32, n_lanes)
    v0, v1 = mi.sample_tea_32(dr.opaque(mi.UInt32, seed & 0xFFFFFFFF), idx)
    rng = mi.PCG32()
    rng.seed(v0, v1)
    return rng


def to_mono(value, wavelengths=None):
    """A spectrum as one float: itself (mono), luminance Y (RGB, spectral)."""
    if mi.is_polarized:
        value = mi.unpolarized_spectrum(value)
    if mi.is_monochromatic:
        return value[0]
    if mi.is_spectral:
        return mi.luminance(value, wavelengths)
    return mi.luminance(value)


@dataclass
class LaneLayout:
    """How pixels and samples map onto SIMD lanes."""

    n_pixels: int
    spp: int
    streams: int  # K

    @property
    def n_lanes(self) -> int:
        return self.n_pixels * self.streams

    def passes(self) -> list[tuple[int, int]]:
        """Per-lane sample ranges ``[j0, j1)`` (j-th sample of a lane is ``k + j K``)."""
        per_lane = math.ceil(self.spp / self.streams)
        step = max(1, PATHS_PER_PASS // self.n_lanes)
        return [(j, min(per_lane, j + step)) for j in range(0, per_lane, step)]


#: A dropped fraction below minus this is more than float32 rounding of the binned sum: recorded as an anomaly.
NEGATIVE_FRACTION_TOL = 1e-5


def dropped_fraction(hist, total: float, in_hist: float) -> float:
    """``(total - in_hist) / total`` clipped at 0; a value below ``-NEGATIVE_FRACTION_TOL`` (more light in the
    histogram than was recorded) is kept, most negative first, in ``hist.negative_fraction`` for the manifest."""
    if total <= 0:
        return 0.0
    raw = (total - in_hist) / total
    if raw < -NEGATIVE_FRACTION_TOL:
        hist.negative_fraction = min(hist.negative_fraction, raw)
    return max(0.0, raw)


@dr.syntax
def sum_strided(data, base, stride: int, count: int, size: int):
    """``out[i] = sum_k data[base[i] + k stride]`` for ``k = 0 .. count - 1``, added in that order.

    A symbolic loop (one compiled kernel whatever ``count``; an unrolled sum compiled in time growing
    faster than ``count``: 6 s at 8192 streams), with the same additions in the same order as the
    unrolled ``out += gather(...)`` it replaced, so the same bytes.
    """
    out = dr.zeros(mi.Float, size)
    k = mi.UInt32(0)
    n = dr.opaque(mi.UInt32, count)
    step = dr.opaque(mi.UInt32, stride)
    while k < n:
        out += dr.gather(mi.Float, data, base + k * step)
        k += 1
    return out


class LaneHistogram:
    """Per-lane time histograms, lost energy and dropped-contribution counters.

    ``record`` is called from traced (symbolic-loop) code; its scatters are
    side effects that each lane applies to its own slot only.

    Layout: slot ``s`` (one per lane; subclasses hold several per lane) owns
    ``stride = n_bins_ext + 1`` floats of :attr:`data`: the padded time bins,
    then one *overflow* value holding the energy that fell outside them (the
    lost energy: steady = sum of the bins + overflow). :attr:`counts` holds two
    counters per counting slot: contributions outside the film's range
    (dropped) and contributions with a NaN/-inf path length or a NaN value
    (invalid). So recording a contribution is two scatters, one float and one
    integer.
    """

    def __init__(self, layout: LaneLayout, axis: TimeAxis, pad: int, n_slots: int | None = None,
                 n_count_slots: int | None = None):
        self.layout = layout
        self.axis = axis
        self.pad = pad
        self.n_bins_ext = axis.n_bins + 2 * pad
        self.stride = self.n_bins_ext + 1
        self.n_slots = layout.n_lanes if n_slots is None else n_slots
        self.n_count_slots = layout.n_lanes if n_count_slots is None else n_count_slots
        self.data = dr.zeros(mi.Float, self.n_slots * self.stride)
        # [dropped, invalid] per counting slot; invalid: a bug somewhere, never silently binned or dropped
        self.counts = dr.zeros(mi.UInt32, 2 * self.n_count_slots)
        #: (total - in_hist) / total below -NEGATIVE_FRACTION_TOL at collect(): more light binned than recorded
        self.negative_fraction = 0.0
        F64 = dr.float64_array_t(mi.Float)
        # Opaque: true IEEE divisions below, and one compiled kernel for any time axis.
        self._c = dr.opaque(F64, C_M_PER_PS)
        self._t0 = dr.opaque(F64, axis.t0_ps)
        self._bw = dr.opaque(F64, axis.bin_width_ps)
        self._n_ext = dr.opaque(mi.Int32, self.n_bins_ext)
        self._stride = dr.opaque(mi.UInt32, self.stride)
        self._n = dr.opaque(mi.Int32, axis.n_bins)
        self._pad = dr.opaque(mi.Int32, pad)

    def bin_index(self, opl_m):
        """(valid, in_range, bin_ext, invalid) for arrivals with optical path ``opl_m``.

        ``+inf`` (light from an infinitely distant emitter: no time of flight)
        is out of range; NaN and ``-inf`` are *invalid* (a bug upstream).
        """
        F64 = dr.float64_array_t(mi.Float)
        pos = (F64(opl_m) / self._c - self._t0) / self._bw
        finite = dr.isfinite(pos)
        invalid = dr.isnan(pos) | (pos == -dr.inf)
        pos = dr.select(finite, pos, -1e9)
        pos = dr.clip(pos, -1e9, 1e9)
        b = mi.Int32(dr.floor(pos))
        in_range = finite & (b >= 0) & (b < self._n)
        b_ext = b + self._pad
        valid = finite & (b_ext >= 0) & (b_ext < self._n_ext)
        return valid, in_range, b_ext, invalid

    def _count(self, count_slot, active, invalid, in_range):
        """Count a contribution that is invalid, or dropped (outside the film's range)."""
        idx = mi.UInt32(count_slot) * 2 + dr.select(invalid, mi.UInt32(1), mi.UInt32(0))
        dr.scatter_reduce(dr.ReduceOp.Add, self.counts, mi.UInt32(1), idx, active & (invalid | ~in_range),
                          mode=dr.ReduceMode.NoConflicts)

    def _add(self, slot, value, valid, b_ext, active):
        """Add ``value`` to bin ``b_ext`` of ``slot``, or to its overflow value when not ``valid``."""
        b = dr.select(valid, mi.UInt32(dr.maximum(b_ext, 0)), mi.UInt32(self._n_ext))
        dr.scatter_reduce(dr.ReduceOp.Add, self.data, value, mi.UInt32(slot) * self._stride + b, active,
                          mode=dr.ReduceMode.NoConflicts)

    def record(self, lane, opl_m, value, active):
        """Add ``value`` (mi.Float) arriving after ``opl_m`` metres to ``lane``'s slot.

        Contributions with a NaN or ``-inf`` path length (or a NaN value) are
        counted as invalid and kept out of the histogram, the steady total and
        the dropped counts.
        """
        nan_value = dr.isnan(value)
        active = mi.Bool(active) & ((value != 0) | nan_value)  # (NaN != 0 is an ordered compare: false)
        valid, in_range, b_ext, invalid = self.bin_index(opl_m)
        invalid |= nan_value
        self._count(lane, active, invalid, in_range)
        self._add(lane, value, valid, b_ext, active & ~invalid)

    def evaluate(self, *loop_outputs):
        """Run the pending pass. Pass the loop's other outputs (the RNG state)
        here too: evaluating them separately would execute the loop twice."""
        dr.eval(self.data, self.counts, *loop_outputs)

    def _counters(self) -> np.ndarray:
        """``[n_count_slots, 2]`` uint32: (dropped, invalid) per counting slot."""
        return np.asarray(self.counts).reshape(self.n_count_slots, 2)

    def invalid_count(self) -> int:
        """Contributions recorded with a NaN/-inf path length or a NaN value (bugs; see :meth:`record`)."""
        return int(self._counters()[:, 1].sum(dtype=np.uint64))

    def _overflow(self) -> np.ndarray:
        """``[n_slots]`` float64: each slot's energy outside the padded bins."""
        return np.asarray(self.data).reshape(self.n_slots, self.stride)[:, -1].astype(np.float64)

    def _per_pixel(self):
        """Sum the K stream slots of each pixel in a fixed order (one drjit kernel).

        Returns a flat ``mi.Float`` of ``n_pixels * n_bins_ext`` values.
        """
        L, T = self.layout, self.n_bins_ext
        idx = dr.arange(mi.UInt32, L.n_pixels * T)
        pixel = idx // T
        b = idx - pixel * T
        base = pixel * (L.streams * self.stride) + b
        out = sum_strided(self.data, base, self.stride, L.streams, L.n_pixels * T)
        dr.eval(out)
        return out

    def collect(self, taps: np.ndarray) -> tuple[np.ndarray, np.ndarray, int, float]:
        """Sum streams per pixel, average over spp, apply the temporal kernel.

        Returns ``(hist[n_pixels, n_bins] float32, steady[n_pixels] float32,
        dropped_contributions, dropped_fraction)``.
        """
        L = self.layout
        T = self.n_bins_ext
        lost = self._overflow().reshape(L.n_pixels, L.streams).sum(axis=1)
        if L.streams == 1:
            # one slot per pixel: its bins are a strided view of the slots (no gather pass over the film)
            hist = np.asarray(self.data).reshape(L.n_pixels, self.stride)[:, :T]
        else:
            # np.asarray is a writeable zero-copy view of drjit's memory (it keeps the drjit array alive)
            hist = np.asarray(self._per_pixel()).reshape(L.n_pixels, T)
        self.data = None  # (the view keeps the buffer it needs alive)
        hist *= np.float32(1.0 / L.spp)  # in place: no second full-size buffer
        rows = hist.sum(axis=1, dtype=np.float64)
        steady = rows + lost / L.spp
        if len(taps) > 1:
            hist = apply_kernel(hist, taps).astype(np.float32)
            in_hist = float(hist.sum(dtype=np.float64))
        else:
            in_hist = float(rows.sum())
        dropped = int(self._counters()[:, 0].sum(dtype=np.uint64))
        total = float(steady.sum())
        frac = dropped_fraction(self, total, in_hist)
        return hist, steady.astype(np.float32), dropped, frac


# ------------------------------------------------------------------ channels

#: Channels a camera render records per time bin (see :func:`film_channels`).
RGB_CHANNELS = ("R", "G", "B")
STOKES_CHANNELS = ("S0", "S1", "S2", "S3")


def variant_channels() -> tuple[str, ...] | None:
    """The channels the active variant records per bin: ``R, G, B`` (``*_rgb`` and ``*_spectral``: linear
    sRGB, as Mitsuba's films develop spectral renders), ``S0..S3`` (``*_polarized``: the Stokes vector in
    the sensor's frame, as Mitsuba's ``stokes`` integrator), None for ``*_mono`` (one value)."""
    if mi.is_polarized:
        return STOKES_CHANNELS
    if mi.is_rgb or mi.is_spectral:
        return RGB_CHANNELS
    return None


def stokes_rotation(sensor, d):
    """Mueller rotation taking a path's Stokes frame (``stokes_basis(-d)``, Mitsuba's implicit frame for a
    ray of direction ``d`` arriving at the sensor) to the sensor's frame (its x axis: ``d x up``), as
    Mitsuba's ``stokes`` integrator does, so S1 > 0 is light polarized along the image's x axis."""
    up = sensor.world_transform() @ mi.Vector3f(0, 1, 0)  # a vector (a Scalar one would transform as a point)
    return mi.mueller.rotate_stokes_basis(-d, mi.mueller.stokes_basis(-d), dr.cross(d, up))


def as_list(values) -> list:
    """:func:`channel_values`' result as a list (one element in mono)."""
    return list(values) if isinstance(values, (list, tuple)) else [values]


def channel_values(value, wavelengths, channels, rotation=None):
    """A path contribution (``mi.Spectrum``) as the recorded values: one ``mi.Float`` (mono, see
    :func:`to_mono`) or a list of them, one per channel.

    ``rotation`` (polarized variants): from :func:`stokes_rotation` for the path's camera ray. Stokes
    components of spectral-polarized renders are reduced to their luminance Y, as :func:`to_mono` does.
    """
    if channels is None:
        return to_mono(value, wavelengths)
    if channels == STOKES_CHANNELS:
        m = rotation @ value if rotation is not None else value
        out = []
        for i in range(4):
            e = m[i][0]  # column 0: the Stokes vector of unpolarized emission after the path's Mueller matrix
            out.append(e[0] if mi.is_monochromatic else mi.luminance(e, wavelengths))
        return out
    bands = band_edges_nm(channels)
    if bands is not None:  # spectral bands: each wavelength's weight (1 / pdf) goes to its band
        s = mi.unpolarized_spectrum(value)
        n = len(wavelengths)
        out = []
        for lo, hi in bands:
            acc = mi.Float(0.0)
            for i in range(n):
                acc += dr.select((wavelengths[i] >= lo) & (wavelengths[i] < hi), s[i], 0.0)
            out.append(acc * (1.0 / n))
        return out
    if mi.is_spectral:
        rgb = mi.spectrum_to_srgb(mi.unpolarized_spectrum(value), wavelengths)
    else:
        rgb = mi.unpolarized_spectrum(value)
    return [rgb[0], rgb[1], rgb[2]]


class ChannelHistogram(LaneHistogram):
    """Lane histograms with one sub-slot per channel (slot = ``lane * C + channel``).

    The dropped and invalid counters count contributions (one per lane, whatever their channels); the
    lost energy is kept per channel.
    """

    def __init__(self, layout: LaneLayout, axis: TimeAxis, pad: int, n_channels: int):
        super().__init__(layout, axis, pad, n_slots=layout.n_lanes * n_channels)
        self.n_channels = n_channels
        self._nch = dr.opaque(mi.UInt32, n_channels)

    def record(self, lane, opl_m, values, active):
        """Add the per-channel ``values`` arriving after ``opl_m`` metres to ``lane``'s slots."""
        nan_value = mi.Bool(False)
        nonzero = mi.Bool(False)
        for v in values:
            nan_value |= dr.isnan(v)
            nonzero |= v != 0
        active = mi.Bool(active) & (nonzero | nan_value)
        valid, in_range, b_ext, invalid = self.bin_index(opl_m)
        invalid |= nan_value
        self._count(lane, active, invalid, in_range)
        active &= ~invalid
        for ch, v in enumerate(values):
            self._add(mi.UInt32(lane) * self._nch + ch, v, valid, b_ext, active)

    def collect(self, taps: np.ndarray) -> tuple[np.ndarray, np.ndarray, int, float]:
        """As :meth:`LaneHistogram.collect`, per channel: ``(hist[n_pixels, n_bins, C] float32,
        steady[n_pixels, C] float32, dropped_contributions, dropped_fraction)`` (the fraction over all
        channels together)."""
        L, T, C = self.layout, self.n_bins_ext, self.n_channels
        idx = dr.arange(mi.UInt32, L.n_pixels * C * T)
        pc = idx // T  # (pixel, channel)
        pixel = pc // C
        base = (pixel * (L.streams * C) + (pc - pixel * C)) * self.stride + (idx - pc * T)
        summed = sum_strided(self.data, base, C * self.stride, L.streams, L.n_pixels * C * T)
        dr.eval(summed)
        lost = self._overflow().reshape(L.n_pixels, L.streams, C).sum(axis=1)
        self.data = None
        hist = np.asarray(summed).reshape(L.n_pixels * C, T)
        del summed
        hist *= np.float32(1.0 / L.spp)
        steady = hist.sum(axis=1, dtype=np.float64).reshape(L.n_pixels, C) + lost / L.spp
        if len(taps) > 1:
            hist = apply_kernel(hist, taps).astype(np.float32)
        dropped = int(self._counters()[:, 0].sum(dtype=np.uint64))
        total = float(steady.sum())
        in_hist = float(hist.sum(dtype=np.float64))
        frac = dropped_fraction(self, total, in_hist)
        hist = np.ascontiguousarray(hist.reshape(L.n_pixels, C, -1).transpose(0, 2, 1))
        return hist, steady.astype(np.float32), dropped, frac
