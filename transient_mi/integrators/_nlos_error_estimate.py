r"""The discretisation-error estimate of the deterministic NLOS estimator (:mod:`~._nlos_quadrature`).

The quadrature integrates each capture on a *fine* level (elements of edge ``h``, ``m`` cells per patch side) and a
*coarse* one (each fine element's parent, ``2h``, and ``m/2`` cells). Per bin of every pixel the fine level's error
``e = I_h - I`` is estimated from their difference ``d = I_h - I_2h`` by Richardson's rule for a method of order
``p``,

.. math::

    I_{2h} - I_h \approx (2^p - 1)\, e, \qquad |e| \approx \mathrm{rms}_{\pm R}(d) / (2^p - 1),

* **Order** ``p = 2`` (:data:`ESTIMATE_ORDER`): the weights are a midpoint rule with the cell's linear tilt and
  the arrival times exact for a path length linear to second order. On the letter the error falls faster than
  that in aggregate (the cells' part close to fourth order, the elements' part second order: a scratch study, not a
  committed benchmark), yet with the divisor of a third-order method (7) the worst 8-bin windows of its 8 x 8
  capture at 1 cm and 4 cells were no longer covered. Coverage of windows is what the test asks, so the divisor stays 3.
* **Shape.** ``d`` crosses zero where the error need not (a pair's error moves light between neighbouring bins):
  each bin takes the root mean square of ``d`` over ``2 R + 1`` bins centred on it (``R =``
  :data:`ESTIMATE_REACH_BINS`, reflected at the axis ends). A local mean of squares fills the zero crossings and
  keeps every pixel's sum of squares exactly, the quantity ``detect``'s ratio sums. The maximum over the same
  reach, used before, inflated the sum of squares about threefold (on the letter's 8 x 8 accuracy capture the
  stated ratio at 10 ms, at 1 cm and 4 cells, fell from 0.059 to 0.023; its actual error was 0.0034).

An estimate, not a guarantee: ``tests/test_nlos_quadrature.py::test_error_estimate_covers_the_actual_error`` checks
on the letter and the tilted plane that against a much finer level it covers every pixel total, every pixel's summed
squares and every lit 8-bin window's summed squares; a single bin can fall short.
"""

from __future__ import annotations

import numba
import numpy as np

#: Bins on either side over which a bin's estimate takes the root mean square of the two-level difference.
ESTIMATE_REACH_BINS = 2
#: The order of the method assumed by Richardson's rule.
ESTIMATE_ORDER = 2
#: The two-level difference over the fine level's error: ``2^p - 1`` (3 for second order).
ESTIMATE_DIVISOR = 2.0 ** ESTIMATE_ORDER - 1.0


@numba.njit(cache=True, parallel=True, fastmath=False)
def _rms_rows(a, b, reach, scale, out, add, part):
    """``out[k, t] = scale * sqrt(mean_{|j| <= reach} (a - b)[k, t + j]^2)`` (with ``add``: added to ``out[k, t]``;
    ``part`` with rows: each value written there too, in its type), indices reflected at the row's ends (``-1 ->
    0``, ``T -> T - 1``: scipy's ``mode="reflect"``), one row per iteration in parallel; each window summed in order
    from its first bin (same inputs, same bytes, whatever the threads; added, the same bytes as adding the estimate
    afterwards)."""
    n, T = a.shape
    w = 2 * reach + 1
    inv_w = 1.0 / w
    keep = part.shape[0] > 0
    for k in numba.prange(n):
        sq = np.empty(T)
        for t in range(T):
            d = float(a[k, t]) - float(b[k, t])  # (float64 whatever the rows' type)
            sq[t] = d * d
        for t in range(T):
            acc = 0.0
            for j in range(t - reach, t + reach + 1):
                i = j
                while i < 0 or i >= T:  # (reflected; a row shorter than the window reflects more than once)
                    i = -i - 1 if i < 0 else 2 * T - i - 1
                acc += sq[i]
            v = scale * np.sqrt(acc * inv_w)
            out[k, t] = out[k, t] + v if add else v
            if keep:
                part[k, t] = v


def _floats(x) -> np.ndarray:
    """``x`` as a float32 or float64 array as it is (no copy of a capture-sized level), anything else as float64."""
    x = np.asarray(x)
    return x if x.dtype in (np.float32, np.float64) else x.astype(np.float64)


def local_rms(d: np.ndarray, minus: np.ndarray | None = None, scale: float = 1.0,
              add_to: np.ndarray | None = None, part: np.ndarray | None = None) -> np.ndarray:
    """``scale`` times the root mean square of ``d - minus`` (``minus`` default 0) over ``2 ESTIMATE_REACH_BINS +
    1`` bins centred on each bin of the last axis (reflected at its ends, so the sum of squares of every row is
    kept), float64, the shape of ``d``; the difference is formed bin by bin inside the kernel, in float64 from
    float32 or float64 inputs (no temporaries of the capture's size).

    ``add_to`` (float64, C-contiguous, the shape of ``d``), optional: the estimate is added to it in place and it is
    returned (the same bytes as ``add_to + local_rms(...)``, without a new array of the capture's size). ``part``
    (float32 or float64, C-contiguous, the shape of ``d``), optional: the estimate is also written there, each value
    rounded to its type (the error's parts beside their sum, in one pass)."""
    d = _floats(d)
    shape = d.shape
    rows = np.ascontiguousarray(d.reshape(-1, shape[-1]) if d.ndim else d.reshape(1, 1))
    sub = (np.zeros_like(rows) if minus is None else
           np.ascontiguousarray(np.broadcast_to(_floats(minus), shape).reshape(rows.shape)))
    if add_to is None:
        out = np.empty(rows.shape)
    else:
        _check_out("add_to", add_to, shape, (np.float64,))
        out = add_to.reshape(rows.shape)
    if part is None:
        part_rows = np.empty((0, 0))
    else:
        _check_out("part", part, shape, (np.float32, np.float64))
        part_rows = part.reshape(rows.shape)
    _rms_rows(rows, sub, ESTIMATE_REACH_BINS, float(scale), out, add_to is not None, part_rows)
    return out.reshape(shape)


def _check_out(name: str, a: np.ndarray, shape: tuple, dtypes: tuple) -> None:
    """An output array of :func:`local_rms`: C-contiguous, of ``shape`` and one of ``dtypes``."""
    if a.shape != shape or a.dtype not in dtypes or not a.flags.c_contiguous:
        raise ValueError(f"{name}: a C-contiguous array of shape {shape} and type "
                         f"{' or '.join(np.dtype(t).name for t in dtypes)} expected")


def discretisation_error(fine: np.ndarray, coarse: np.ndarray, add_to: np.ndarray | None = None,
                         part: np.ndarray | None = None) -> np.ndarray:
    """The fine level's estimated discretisation error per bin.

    Parameters
    ----------
    fine, coarse : ndarray, float64, shape (..., bins)
        Photons per pulse per bin of the fine (``h``, ``m`` cells) and coarse (``2h``, ``m/2``) levels.
    add_to : ndarray, float64, shape of ``fine``, optional
        Where to add the estimate in place (see :func:`local_rms`).
    part : ndarray, float32 or float64, shape of ``fine``, optional
        Where to write the estimate as well (see :func:`local_rms`).

    Returns
    -------
    ndarray, float64, shape of ``fine``
        ``local_rms(fine - coarse) / ESTIMATE_DIVISOR``, photons per pulse per bin (>= 0), or ``add_to`` with it
        added.
    """
    return local_rms(fine, coarse, 1.0 / ESTIMATE_DIVISOR, add_to, part)
