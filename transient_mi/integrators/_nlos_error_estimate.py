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

import numpy as np
from scipy.ndimage import uniform_filter1d

#: Bins on either side over which a bin's estimate takes the root mean square of the two-level difference.
ESTIMATE_REACH_BINS = 2
#: Rows (pixels) filtered at a time: the float64 temporaries of a [spots, pixels, bins] capture stay this many rows
#: (each row is filtered on its own, so the result does not depend on it).
RMS_ROWS = 256
#: The order of the method assumed by Richardson's rule.
ESTIMATE_ORDER = 2
#: The two-level difference over the fine level's error: ``2^p - 1`` (3 for second order).
ESTIMATE_DIVISOR = 2.0 ** ESTIMATE_ORDER - 1.0


def local_rms(d: np.ndarray) -> np.ndarray:
    """Root mean square of ``d [..., T]`` over ``2 ESTIMATE_REACH_BINS + 1`` bins centred on each bin of the last
    axis (reflected at its ends, so the sum of squares of every row is kept)."""
    d = np.asarray(d, dtype=np.float64)
    rows = d.reshape(-1, d.shape[-1]) if d.ndim else d.reshape(1, 1)
    out = np.empty(rows.shape)
    for r0 in range(0, len(rows), RMS_ROWS):  # (a block of rows at a time: the temporaries stay small)
        ms = uniform_filter1d(np.square(rows[r0:r0 + RMS_ROWS]), 2 * ESTIMATE_REACH_BINS + 1, axis=-1, mode="reflect")
        np.sqrt(np.maximum(ms, 0.0), out=out[r0:r0 + RMS_ROWS])
    return out.reshape(d.shape)


def discretisation_error(fine: np.ndarray, coarse: np.ndarray) -> np.ndarray:
    """The fine level's estimated discretisation error per bin.

    Parameters
    ----------
    fine, coarse : ndarray, float64, shape (..., bins)
        Photons per pulse per bin of the fine (``h``, ``m`` cells) and coarse (``2h``, ``m/2``) levels.

    Returns
    -------
    ndarray, float64, shape of ``fine``
        ``local_rms(fine - coarse) / ESTIMATE_DIVISOR``, photons per pulse per bin (>= 0).
    """
    out = local_rms(np.asarray(fine, dtype=np.float64) - coarse)
    out /= ESTIMATE_DIVISOR
    return out
