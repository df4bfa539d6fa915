"""The paper's error metrics and the statistics of the experiments report (pure numpy/scipy).

- point-to-point with correspondences: ``|spot - marker|`` (m), spot and marker as the
  camera measured them;
- closest point (paths): the distance from the spot to the measured polyline;
- mean with a 95 % confidence interval (Student t over independent samples);
- the paper's two-sample t-test between two sets of errors (Fig. 6, chessboard placements).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from numpy.typing import ArrayLike


def point_error(spot: ArrayLike, marker: ArrayLike) -> float:
    """Point-to-point error (m) of a spot and its corresponding marker (3,)."""
    return float(np.linalg.norm(np.asarray(spot, dtype=float) - np.asarray(marker, dtype=float)))


def closest_point_error(spot: ArrayLike, polyline: ArrayLike) -> float:
    """Distance (m) from ``spot`` (3,) to the polyline through ``polyline`` (K x 3, K >= 1,
    NaN rows skipped); NaN when no vertex is finite."""
    P = np.asarray(polyline, dtype=float).reshape(-1, 3)
    P = P[np.all(np.isfinite(P), axis=1)]
    s = np.asarray(spot, dtype=float)
    if len(P) == 0:
        return float("nan")
    if len(P) == 1:
        return float(np.linalg.norm(s - P[0]))
    a, d = P[:-1], np.diff(P, axis=0)
    L2 = np.maximum(np.einsum("ij,ij->i", d, d), 1e-30)
    t = np.clip(np.einsum("ij,ij->i", s - a, d) / L2, 0.0, 1.0)
    return float(np.min(np.linalg.norm(a + t[:, None] * d - s, axis=1)))


class MeanCI(NamedTuple):
    """Mean, standard deviation (ddof 1) and the half-width of its confidence interval."""

    mean: float
    std: float
    half_width: float
    n: int


def mean_ci(x: Any, level: float = 0.95) -> MeanCI:
    """Mean of the finite values of ``x`` with the Student-t confidence interval half-width
    ``t_{(1+level)/2, n-1} s / sqrt(n)`` (NaN for fewer than two values)."""
    from scipy import stats

    v = np.asarray(x, dtype=float).ravel()
    v = v[np.isfinite(v)]
    n = len(v)
    if n == 0:
        return MeanCI(float("nan"), float("nan"), float("nan"), 0)
    if n == 1:
        return MeanCI(float(v[0]), float("nan"), float("nan"), 1)
    s = float(np.std(v, ddof=1))
    h = float(stats.t.ppf(0.5 + level / 2, n - 1) * s / np.sqrt(n))
    return MeanCI(float(np.mean(v)), s, h, n)


class TTest(NamedTuple):
    """Two-sample t-test: statistic, two-sided p value, degrees of freedom, sample sizes."""

    t: float
    p: float
    dof: float
    n_a: int
    n_b: int


def two_sample_t(a: Any, b: Any) -> TTest:
    """Student's two-sample t-test (equal variances, as in the paper) of the finite values
    of ``a`` and ``b``; NaN figures when either has fewer than two values."""
    from scipy import stats

    va, vb = (np.asarray(x, dtype=float).ravel() for x in (a, b))
    va, vb = va[np.isfinite(va)], vb[np.isfinite(vb)]
    if len(va) < 2 or len(vb) < 2:
        return TTest(float("nan"), float("nan"), float("nan"), len(va), len(vb))
    r = stats.ttest_ind(va, vb, equal_var=True)
    return TTest(
        float(r.statistic), float(r.pvalue), float(len(va) + len(vb) - 2), len(va), len(vb)
    )
