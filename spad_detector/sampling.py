"""Exact multinomial draws of histograms, fast for both few and many counts.

:func:`distribute` puts ``K`` avalanches of each pixel into time bins with
probabilities ``q`` (the rest, ``1 - sum(q)``, is lost: time stamps outside the
window). Pixels with few avalanches (``K <= n_bins / 4``) draw each
avalanche's bin by inverting the cumulative ``q`` (cost ~ ``K log n_bins``);
pixels with many use numpy's sequential-binomial multinomial (cost ~
``n_bins``). Both are exact draws from ``Multinomial(K, q)``.
"""

from __future__ import annotations

import numpy as np


def distribute(rng: np.random.Generator, K: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Draw ``counts[i] ~ Multinomial(K[i], q[i])`` (only the first ``n_bins`` categories kept).

    Parameters
    ----------
    K : ndarray of int, shape (n_pix,)
    q : ndarray, shape (n_pix, n_bins)
        Per-avalanche bin probabilities, row sums <= 1.

    Returns
    -------
    ndarray of int64, shape (n_pix, n_bins)
    """
    K = np.asarray(K, dtype=np.int64)
    q = np.clip(np.asarray(q, dtype=np.float64), 0.0, None)
    n_pix, T = q.shape
    s = q.sum(1)
    over = s > 1.0
    if np.any(over):  # rounding only
        q[over] /= s[over, None]
        s[over] = 1.0
    out = np.zeros((n_pix, T), dtype=np.int64)
    small = np.nonzero((K > 0) & (K <= max(1, T // 4)))[0]
    large = np.nonzero(K > max(1, T // 4))[0]
    if small.size:
        cum = np.cumsum(q[small], axis=1)
        cum += 2.0 * np.arange(small.size)[:, None]
        k = K[small]
        row = np.repeat(np.arange(small.size), k)
        u = rng.random(row.size)
        idx = np.searchsorted(cum.ravel(), u + 2.0 * row, side="right")
        b = idx - row * T
        keep = b < T
        flat = np.bincount(row[keep] * T + b[keep], minlength=small.size * T)
        out[small] = flat.reshape(small.size, T)
    if large.size:
        pv = np.concatenate([q[large], np.clip(1.0 - s[large], 0.0, None)[:, None]], axis=1)
        out[large] = rng.multinomial(K[large], pv)[:, :T]
    return out
