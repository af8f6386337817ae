"""The rounding residue of the deterministic NLOS estimator's bin masses (:mod:`~._nlos_quadrature`), cleared
before a capture is written, and the float32 copies its results hand out.

A bin mass is a difference of two values of a cumulative distribution; where it is flat (a pair's tails, 1 ps bins)
their rounding can leave a bin a few 1e-14 of the pixel's largest below zero, which the capture writer refuses.
Such bins (down to ``ROUNDING_RESIDUE`` of the pixel's largest bin of light) are set to 0; a larger negative value
is left for the writer to refuse (it is no rounding). The error files are measured against the light, not against
their own largest bin: their mixed-visibility part is light spread by the same masses (the 32 x 32 paper scene at
1 ps bins had error bins at -1e-20 where the error's largest was 1e-12 and the light's 1e-8).
"""

from __future__ import annotations

import numba
import numpy as np

#: A bin below zero by at most this share of its pixel's largest bin is rounding (set to 0); larger ones are kept.
ROUNDING_RESIDUE = 1e-9


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
def _clear(row, lim, out32):
    """In place: ``row[b] = 0`` where ``lim <= row[b] < 0`` (nothing for a NaN ``lim``, as numpy's comparison with
    a NaN limit); each value is written to ``out32`` (float32) too."""
    for b in range(row.shape[0]):
        x = row[b]
        if x < 0.0 and x >= lim:
            x = 0.0
            row[b] = x
        out32[b] = np.float32(x)


@numba.njit(cache=True, parallel=True, fastmath=False)
def _finish(h, e, share, h32, e32):
    """Per row ``k`` (in parallel; each row alone: the same bytes whatever the threads): ``h[k]`` cleared against
    ``share`` of its own largest ``|h|``, then ``e[k]`` against the cleared ``h[k]``'s, both in place and each written
    to its float32 copy in the same pass. Clearing leaves the row's largest ``|h|`` as it was (a cleared bin is at most
    ``share < 1`` of it; a NaN stays), so the one limit serves both."""
    for k in numba.prange(h.shape[0]):
        lim = -share * _max_abs(h[k])
        _clear(h[k], lim, h32[k])
        _clear(e[k], lim, e32[k])


def finish_rows(hist: np.ndarray, bound: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The light ``hist`` and its error ``bound`` (float64, C-contiguous, same shape ``[..., T]``) cleared of their
    rounding residue in place (module docstring: each row of ``hist`` against its own largest bin, each row of
    ``bound`` against the cleared light's), and their float32 copies ``(hist32, bound32)``, in one pass over each
    row (they were two passes and a copy each)."""
    h2, e2 = hist.reshape(-1, hist.shape[-1]), bound.reshape(-1, bound.shape[-1])
    h32, e32 = np.empty(hist.shape, dtype=np.float32), np.empty(bound.shape, dtype=np.float32)
    _finish(h2, e2, ROUNDING_RESIDUE, h32.reshape(h2.shape), e32.reshape(e2.shape))
    return h32, e32
