"""Discovery's statistics: the signed-rank test of per-block gains, the jackknife over folds and
the spread of per-flight values."""

from __future__ import annotations

import numpy as np

# scipy.stats is imported where it is used: it costs 0.7 s, and every predictor imports this
# package (for the augmented model), also where no test is run

__all__ = ["pvalue", "jackknife", "half_width", "spread"]


def pvalue(g: np.ndarray) -> tuple[float, float]:
    """One-sided Wilcoxon signed-rank test that the per-block gains ``g`` lean positive: the
    equivalent normal ``z`` and p."""
    from scipy.stats import norm, wilcoxon

    g = g[g != 0]
    if len(g) < 2:
        return 0.0, 1.0
    p = float(wilcoxon(g, alternative="greater").pvalue)
    return float(norm.isf(p)), p


def hodges_lehmann(g: np.ndarray) -> float:
    """The Hodges-Lehmann location of the per-block gains ``g``: the median of the pairwise
    means ``(g_i + g_j) / 2``, ``i <= j``, the estimate that goes with the signed-rank test of
    :func:`pvalue` (one block's wild held-out loss moves it by one rank, not by its size)."""
    g = np.asarray(g, dtype=float)
    if len(g) == 0:
        return 0.0
    i, j = np.triu_indices(len(g))
    return float(np.median(0.5 * (g[i] + g[j])))


def jackknife(thetas: np.ndarray) -> np.ndarray:
    """Delete-a-group jackknife standard error from the estimates ``(n, k)`` each fitted without
    one of ``n`` groups."""
    n = len(thetas)
    return np.sqrt((n - 1) / n * ((thetas - thetas.mean(axis=0)) ** 2).sum(axis=0))


def half_width(stderr: float, groups: int, level: float = 0.95) -> float:
    """Half-width of the ``level`` interval from a jackknife over ``groups`` groups: the standard
    error has ``groups - 1`` degrees of freedom, so the quantile is Student's t (with 10 folds,
    2.26 standard errors rather than the normal 1.96, which would cover 92 %)."""
    from scipy.stats import t as student_t

    return float(student_t.ppf(0.5 + level / 2, max(groups - 1, 1)) * stderr)


def spread(values: np.ndarray, level: float = 0.95) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Standard deviation over the rows of ``values (n, k)`` (one row per flight; n - 1 in the
    denominator) and its ``level`` interval, ``(s, low, high)`` each ``(k,)``: for values drawn
    independently from one normal law, ``(n - 1) s² / σ²`` is chi-squared with n - 1 degrees of
    freedom."""
    from scipy.stats import chi2

    values = np.asarray(values, dtype=float)
    dof = len(values) - 1
    s = values.std(axis=0, ddof=1)
    return (s, s * np.sqrt(dof / chi2.ppf(0.5 + level / 2, dof)), s * np.sqrt(dof / chi2.ppf(0.5 - level / 2, dof)))
