"""One place for the statistics of the tests: false-failure rates, seeds, t- and chi-square quantiles.

Every statistical test states the probability that it fails although the code
is right (its false-failure rate, ``alpha``), for the whole family of checks it
makes. The helpers turn that rate into bounds:

* a mean over ``n`` seeds compared with a closed form: ``(mean - ref) / se``
  with ``se`` estimated from the same seeds follows Student's t with ``n - 1``
  degrees of freedom, not a normal law; with few seeds the normal "3 sigma"
  (p = 0.0027) really fails several percent of the time (12 seeds: 1.2 %,
  and per check, before any family correction). :func:`t_bound` gives the
  right quantile;
* a family of ``k`` checks: Bonferroni, each at ``alpha / k`` (valid whatever
  their dependence);
* a sum of squares of ``k`` independent standardised deviations:
  :func:`t_to_z` maps each t statistic to an exactly normal one (probability
  integral transform), so the sum is chi-square with ``k`` degrees of freedom;
  :func:`chi2_bounds` gives its two-sided acceptance region.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

#: Default family-wise false-failure rate of a statistical test (one failure in a thousand runs of it).
ALPHA = 1e-3


def z_bound(alpha: float = ALPHA, n_tests: int = 1) -> float:
    """Two-sided normal quantile for a family of ``n_tests`` checks at family-wise rate ``alpha`` (Bonferroni)."""
    return float(stats.norm.isf(alpha / (2 * n_tests)))


def t_bound(n_seeds: int | float, alpha: float = ALPHA, n_tests: int = 1, *, df: float | None = None) -> float:
    """Two-sided Student-t quantile for ``|mean - ref| / se`` with ``se`` from ``n_seeds`` seeds (``df = n - 1``
    unless given, e.g. Welch's), for a family of ``n_tests`` checks at family-wise rate ``alpha``."""
    dof = (n_seeds - 1) if df is None else df
    if dof < 1:
        raise ValueError(f"need at least 2 seeds (df >= 1), got df={dof}")
    return float(stats.t.isf(alpha / (2 * n_tests), dof))


def welch_df(var_a: float, n_a: int, var_b: float, n_b: int) -> float:
    """Welch-Satterthwaite degrees of freedom of a difference of two means with unequal variances."""
    qa, qb = var_a / n_a, var_b / n_b
    return (qa + qb) ** 2 / (qa ** 2 / (n_a - 1) + qb ** 2 / (n_b - 1))


def mean_se(values, axis: int = 0) -> tuple[np.ndarray, np.ndarray, int]:
    """``(mean, standard error, number of seeds)`` over ``axis`` (the seeds)."""
    v = np.asarray(values, dtype=np.float64)
    n = v.shape[axis]
    return v.mean(axis=axis), v.std(axis=axis, ddof=1) / math.sqrt(n), n


def t_to_z(t, df: float) -> np.ndarray:
    """Map Student-t statistics to standard-normal ones with the same tail probability."""
    t = np.asarray(t, dtype=np.float64)
    return np.asarray(stats.norm.isf(stats.t.sf(t, df)))


def chi2_bounds(df: int, alpha: float = ALPHA, n_tests: int = 1) -> tuple[float, float]:
    """Two-sided acceptance region of a chi-square statistic with ``df`` degrees of freedom."""
    a = alpha / n_tests
    return float(stats.chi2.ppf(a / 2, df)), float(stats.chi2.isf(a / 2, df))


def assert_mean_matches(values, ref, *, alpha: float = ALPHA, n_tests: int = 1, what: str = "mean") -> float:
    """Assert that the seed mean of ``values`` matches ``ref`` within the t bound; returns the t statistic."""
    m, se, n = mean_se(values)
    assert se > 0, f"{what}: zero spread over {n} seeds"
    t = float((m - ref) / se)
    bound = t_bound(n, alpha, n_tests)
    assert abs(t) <= bound, f"{what}: {m:.6g} vs {ref:.6g}: t = {t:+.2f}, bound {bound:.2f} ({n} seeds)"
    return t
