"""The rounding residue of the deterministic NLOS estimator's bin masses (:mod:`~._nlos_quadrature`), cleared
before a capture is written, and the float32 copies its results hand out.

A bin mass is a difference of two values of a cumulative distribution; where it is flat (a pair's tails, 1 ps bins)
their rounding can leave a bin a few 1e-14 of the pixel's largest below zero, which the capture writer refuses.
"""

from __future__ import annotations

import numba
import numpy as np

#: A bin below zero by at most this share of its pixel's largest bin is rounding (set to 0); larger ones are kept.
ROUNDING_RESIDUE = 1e-9


def _clear_rounding_residue(h: np.ndarray, light: np.ndarray | None = None, in_place: bool = False) -> np.ndarray:
    """``h [P, T]`` with the rounding residue of the bin masses removed: a mass is a difference of two CDF values,
    and where the CDF is flat (a pair's tails, 1 ps bins) their rounding can leave a bin a few 1e-14 of the pixel's
    largest below zero, which the capture writer refuses. Such bins (down to ``ROUNDING_RESIDUE`` of the pixel's
    largest bin of ``light``, default ``h`` itself) are set to 0; a larger negative value is left for the writer to
    refuse (it is no rounding). The error files take the light as ``light``: their mixed-visibility part is light
    spread by the same masses (the 32 x 32 paper scene at 1 ps bins had bins of it at -1e-20). ``in_place``: ``h``
    (float64, C-contiguous) is cleared and returned, not a copy."""
    h = h if in_place else np.array(h, dtype=np.float64)
    ref = h if light is None else np.ascontiguousarray(light, dtype=np.float64)
    _clear_rows(h.reshape(-1, h.shape[-1]), ref.reshape(-1, ref.shape[-1]), ROUNDING_RESIDUE)
    return h


@numba.njit(cache=True, fastmath=False, inline="always")
def _max_abs(row):
    """The largest ``|x|`` of a row; NaN when the row holds one (its first)."""
    m = 0.0
    for b in range(row.shape[0]):
        a = abs(row[b])
        if a != a:
            return a
        if a > m:
            m = a
    return m


@numba.njit(cache=True, fastmath=False, inline="always")
def _clear(row, lim, out32, copy: bool):
    """In place: ``row[b] = 0`` where ``lim <= row[b] < 0`` (nothing for a NaN ``lim``); with ``copy`` each value is
    written to ``out32`` (float32) too."""
    for b in range(row.shape[0]):
        x = row[b]
        if x < 0.0 and x >= lim:
            x = 0.0
            row[b] = x
        if copy:
            out32[b] = np.float32(x)


@numba.njit(cache=True, parallel=True, fastmath=False)
def _clear_rows(h, ref, share):
    """In place, per row ``k``: ``h[k, b] = 0`` where ``-share * max|ref[k]| <= h[k, b] < 0`` (one pass per row
    instead of numpy's temporaries: on a 64 x 64 capture of 2048 bins they cost more than the pairs of a coarse
    level), the rows in parallel (each row alone: the same bytes whatever the threads). A row whose ``ref`` holds a
    NaN clears nothing (as numpy's comparison with a NaN limit)."""
    none = np.empty(0, dtype=np.float32)
    for k in numba.prange(h.shape[0]):
        _clear(h[k], -share * _max_abs(ref[k]), none, False)


@numba.njit(cache=True, parallel=True, fastmath=False)
def _finish(h, e, share, h32, e32):
    """Per row ``k`` (in parallel; each row alone): ``h[k]`` cleared as :func:`_clear_rows` against itself, then
    ``e[k]`` against the cleared ``h[k]``, both in place and each written to its float32 copy in the same pass."""
    for k in numba.prange(h.shape[0]):
        _clear(h[k], -share * _max_abs(h[k]), h32[k], True)
        _clear(e[k], -share * _max_abs(h[k]), e32[k], True)


def finish_rows(hist: np.ndarray, bound: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The light ``hist`` and its error ``bound`` (float64, C-contiguous, same shape ``[..., T]``) cleared of
    their rounding residue in place, as ``_clear_rounding_residue(hist, in_place=True)`` then
    ``_clear_rounding_residue(bound, hist, in_place=True)``, and their float32 copies ``(hist32, bound32)``, in one
    pass over each row (the same values as those calls and ``astype(np.float32)``, which were two passes and a copy
    each)."""
    h2, e2 = hist.reshape(-1, hist.shape[-1]), bound.reshape(-1, bound.shape[-1])
    h32, e32 = np.empty(hist.shape, dtype=np.float32), np.empty(bound.shape, dtype=np.float32)
    _finish(h2, e2, ROUNDING_RESIDUE, h32.reshape(h2.shape), e32.reshape(e2.shape))
    return h32, e32
