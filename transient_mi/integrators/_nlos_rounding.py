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


@numba.njit(cache=True, parallel=True, fastmath=False)
def _clear_rows(h, ref, share):
    """In place, per row ``k``: ``h[k, b] = 0`` where ``-share * max|ref[k]| <= h[k, b] < 0`` (one pass per row
    instead of numpy's temporaries: on a 64 x 64 capture of 2048 bins they cost more than the pairs of a coarse
    level), the rows in parallel (each row alone: the same bytes whatever the threads). A row whose ``ref`` holds a
    NaN clears nothing (as numpy's comparison with a NaN limit)."""
    for k in numba.prange(h.shape[0]):
        m = 0.0
        for b in range(ref.shape[1]):
            a = abs(ref[k, b])
            if a != a:
                m = a
                break
            if a > m:
                m = a
        lim = -share * m
        for b in range(h.shape[1]):
            x = h[k, b]
            if x < 0.0 and x >= lim:
                h[k, b] = 0.0


@numba.njit(cache=True, parallel=True, fastmath=False)
def _finish(h, e, share, h32, e32):
    """Per row ``k`` (in parallel; each row alone): ``h[k]`` cleared as :func:`_clear_rows` against itself, then
    ``e[k]`` against the cleared ``h[k]``, both in place and each written to its float32 copy in the same pass."""
    for k in numba.prange(h.shape[0]):
        m = 0.0
        for b in range(h.shape[1]):
            a = abs(h[k, b])
            if a != a:
                m = a
                break
            if a > m:
                m = a
        lim = -share * m
        for b in range(h.shape[1]):
            x = h[k, b]
            if x < 0.0 and x >= lim:
                x = 0.0
                h[k, b] = x
            h32[k, b] = np.float32(x)
        m = 0.0
        for b in range(h.shape[1]):
            a = abs(h[k, b])
            if a != a:
                m = a
                break
            if a > m:
                m = a
        lim = -share * m
        for b in range(e.shape[1]):
            x = e[k, b]
            if x < 0.0 and x >= lim:
                x = 0.0
                e[k, b] = x
            e32[k, b] = np.float32(x)


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
