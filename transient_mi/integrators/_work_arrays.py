"""Capture-sized work arrays of the deterministic NLOS estimator, kept between the render calls of one capture.

A capture is rendered group of spots by group of spots (one ``render_transient`` call each), and every call of the
quadrature (:mod:`~._nlos_quadrature`) needs the same few arrays of the group's size: each level's bins and the
error bound, ``[spots, pixels, bins]`` float64 or float32, hundreds of MB. Freshly allocated, each is a new mapping
of the operating system's, and every one of its pages is faulted in on first use: on the 32 x 32 array capture
against mitransient (1024 spots in 16 groups of 64, 400 bins) that was about a third of the render
(``python bench/bench_work_arrays.py``: the capture with the arrays kept and allocated afresh, alternating;
``bench/results/work_arrays.json``, quoted in docs/quadrature.md).

Inside :func:`reuse_work_arrays` (what ``transient-mi render``'s loop over the groups enters, the noise target's
rounds included) the arrays are kept on the calling thread and handed out again, zeroed, to the next
call that asks for one of the same name (its size at most the kept one's: the last group may be smaller); the
block's end frees them. Outside such a block every call allocates afresh, as before. Zeroed memory is zeroed
memory: the results are the same bytes either way (tested).

An array handed out is the caller's until its next request of the same name: the quadrature takes its results'
float32 copies from them before it returns, so no result refers to one.
"""

from __future__ import annotations

import threading
from contextlib import contextmanager
from math import prod

import numpy as np

_LOCAL = threading.local()


@contextmanager
def reuse_work_arrays():
    """Keep the quadrature's work arrays between render calls on this thread for the block (module docstring).
    Nested blocks share the outermost one's arrays, which its end frees."""
    if getattr(_LOCAL, "arrays", None) is not None:
        yield
        return
    _LOCAL.arrays = {}
    try:
        yield
    finally:
        _LOCAL.arrays = None


def work_zeros(name: str, shape: tuple, dtype=np.float64) -> np.ndarray:
    """A C-contiguous array of zeros of ``shape`` and ``dtype``: inside :func:`reuse_work_arrays`, the array last
    handed out under ``name`` (zeroed; a view of its first elements when ``shape`` is smaller) unless it is too small
    or of another type (then a new one replaces it); outside, ``np.zeros``."""
    arrays = getattr(_LOCAL, "arrays", None)
    if arrays is None:
        return np.zeros(shape, dtype=dtype)
    n = prod(shape)
    kept = arrays.get(name)
    if kept is None or kept.dtype != np.dtype(dtype) or kept.size < n:
        arrays.pop(name, None)  # (the old one freed first: at most one array per name at any time)
        kept = arrays[name] = np.zeros(n, dtype=dtype)
        return kept.reshape(shape)
    view = kept[:n].reshape(shape)
    view.fill(0)
    return view
