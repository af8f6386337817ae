"""numba helpers of the exact engine (:mod:`.exact`): each event's slot and the events' time order, the two numpy
calls that took most of a chunk's time outside the event loop.

Both give the bytes of the numpy expressions they replace (tested against them):

* :func:`event_slots` is ``np.searchsorted(cdf_flat, u + 2 pix, side="right") - pix n_slots``: each pixel's row of
  the flattened CDF is offset by ``2 pix``, so a pixel's value ``u + 2 pix`` in ``[2 pix, 2 pix + 1]`` can only land
  in its own row; the search runs over that row (``n_slots`` values, not ``n_pix n_slots``), over the few slots
  its guide table gives (:func:`guide_table`), and compares the same rounded sums. Every search that finds the
  first value above ``v`` gives the same index: whether a row's value exceeds ``v`` changes once along the row
  (the rows are non-decreasing cumulative sums; their last value, set to exactly 1, is not below ``v``'s
  largest).
* :func:`time_order` is ``np.argsort(t, kind="stable")`` for non-negative finite times: a least-significant-digit
  radix sort of the times' bit patterns (monotone in the value for non-negative IEEE doubles), stable, so equal
  times keep their input order as in numpy's stable sort; digits that every time shares are skipped.

Together they took the exact engine's case of ``bench/bench_detector.py`` from about 0.5 s to 0.28 s
(``bench/results/detector.json``, whose note has the runs before).
"""

from __future__ import annotations

import numba
import numpy as np

#: Bits of the radix sort's digit (256 buckets: the counts stay in the first-level cache).
DIGIT_BITS = 8
#: Entries of each row's guide table (:func:`guide_table`): a power of two, so ``u * GUIDE`` and ``k / GUIDE`` are
#: exact.
GUIDE = 256


@numba.njit(cache=True)
def guide_table(cdf_flat, n_slots):
    """Each row's guide (Chen and Asau's table for sampling by inversion): ``G[p, k]``, int32 ``[n_rows, GUIDE +
    1]``, the first slot of row ``p`` of ``cdf_flat`` (rows of ``n_slots`` values, row ``p`` offset by ``2 p``)
    whose value exceeds ``k / GUIDE + 2 p`` (``n_slots`` when none does). One pass over each row."""
    n_rows = cdf_flat.shape[0] // n_slots
    out = np.empty((n_rows, GUIDE + 1), dtype=np.int32)
    for p in range(n_rows):
        start = p * n_slots
        i = 0
        for k in range(GUIDE + 1):
            w = k / GUIDE + 2.0 * p
            while i < n_slots and cdf_flat[start + i] <= w:
                i += 1
            out[p, k] = i
    return out


@numba.njit(cache=True)
def event_slots(cdf_flat, n_slots, pix, u, guide):
    """Slot of every event: per event ``i`` the first index of pixel ``pix[i]``'s row of ``cdf_flat`` (rows of
    ``n_slots`` values, row ``p`` offset by ``2 p``) whose value exceeds ``v = u[i] + 2 pix[i]``, relative to the
    row's start (``n_slots`` when none does); ``guide``: :func:`guide_table` of ``cdf_flat``. With ``k = floor(u
    GUIDE)``, ``v`` lies between the guide's thresholds ``k`` and ``k + 1`` (rounding is monotone), so the slot lies
    in ``[G[p, k], G[p, k + 1]]``: a binary search over those few slots. int64, shape of ``pix``."""
    out = np.empty(pix.shape[0], dtype=np.int64)
    for i in range(pix.shape[0]):
        p = pix[i]
        v = u[i] + 2.0 * p
        k = int(u[i] * GUIDE)
        start = p * n_slots
        lo = start + guide[p, k]
        hi = start + guide[p, k + 1]
        while lo < hi:
            mid = (lo + hi) >> 1
            if cdf_flat[mid] <= v:
                lo = mid + 1
            else:
                hi = mid
        out[i] = lo - start
    return out


@numba.njit(cache=True)
def _radix_order(keys):
    """Stable ascending order of the unsigned 64-bit ``keys`` (LSD radix, :data:`DIGIT_BITS` a pass)."""
    n = keys.shape[0]
    n_digits = 64 // DIGIT_BITS
    n_buckets = 1 << DIGIT_BITS
    mask = np.uint64(n_buckets - 1)
    counts = np.zeros((n_digits, n_buckets), dtype=np.int64)
    for i in range(n):
        k = keys[i]
        for d in range(n_digits):
            counts[d, np.int64((k >> np.uint64(d * DIGIT_BITS)) & mask)] += 1
    order = np.arange(n)
    key = keys.copy()
    order_b = np.empty(n, dtype=np.int64)
    key_b = np.empty(n, dtype=np.uint64)
    pos = np.empty(n_buckets, dtype=np.int64)
    for d in range(n_digits):
        shared = False
        for b in range(n_buckets):
            if counts[d, b] == n:
                shared = True
                break
        if shared:  # (every key has this digit: the pass would change nothing)
            continue
        s = 0
        for b in range(n_buckets):
            pos[b] = s
            s += counts[d, b]
        shift = np.uint64(d * DIGIT_BITS)
        for i in range(n):
            k = key[i]
            b = np.int64((k >> shift) & mask)
            j = pos[b]
            pos[b] = j + 1
            key_b[j] = k
            order_b[j] = order[i]
        order, order_b = order_b, order
        key, key_b = key_b, key
    return order


def time_order(t: np.ndarray) -> np.ndarray:
    """``np.argsort(t, kind="stable")`` (int64) of float64 times; by radix on the bit patterns when every time is
    finite and non-negative (``-0.0`` excluded: its pattern sorts last), else by numpy itself."""
    t = np.ascontiguousarray(t, dtype=np.float64)
    if t.size == 0:
        return np.zeros(0, dtype=np.int64)
    if not (np.isfinite(t).all() and t.min() >= 0.0 and not np.signbit(t).any()):
        return np.argsort(t, kind="stable")
    return _radix_order(t.view(np.uint64))
