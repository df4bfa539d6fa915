"""The paper's error metrics and the statistics of the experiments report (pure numpy/scipy).

- point-to-point with correspondences: ``|spot - marker|`` (m), spot and marker as the
  camera measured them;
- closest point (paths): the distance from the spot to the measured polyline;
- mean with a 95 % confidence interval (Student t over independent samples);
- the paper's two-sample t-test between two sets of errors (Fig. 6, chessboard placements),
  kept to show what pooling does, and the tests the report draws conclusions from: paired
  t-tests on per-trial means (targets of one trial share a calibration, so they are not
  independent samples; the trial is) with Holm's step-down correction over the family.
"""

from __future__ import annotations

from collections.abc import Mapping
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


class PairedT(NamedTuple):
    """Paired t-test of per-trial values: statistic, two-sided p, degrees of freedom, the
    number of pairs and the mean difference ``a - b`` with its 95 % confidence interval."""

    t: float
    p: float
    dof: float
    n: int
    diff: MeanCI


def paired_t(a: Mapping[int, float], b: Mapping[int, float]) -> PairedT:
    """Student's paired t-test of ``a[k] - b[k]`` over the keys (trials) where both are
    finite; NaN figures for fewer than two pairs (and NaN t, p when every difference is
    equal, where the test has no variance to work with)."""
    from scipy import stats

    keys = sorted(k for k in set(a) & set(b) if np.isfinite(a[k]) and np.isfinite(b[k]))
    va, vb = np.array([a[k] for k in keys]), np.array([b[k] for k in keys])
    diff = mean_ci(va - vb)
    if len(keys) < 2 or not np.std(va - vb) > 0.0:
        return PairedT(float("nan"), float("nan"), float(len(keys) - 1), len(keys), diff)
    r = stats.ttest_rel(va, vb)
    return PairedT(float(r.statistic), float(r.pvalue), float(len(keys) - 1), len(keys), diff)


def holm(p: Any) -> np.ndarray:
    """Holm's step-down adjusted p values of a family (same order as ``p``): the i-th
    smallest of m times (m - i + 1), made non-decreasing in that order, capped at 1. NaN
    entries are not tests: they stay NaN and do not count in m. Reject at level alpha where
    the adjusted p <= alpha (family-wise error <= alpha under any dependence)."""
    v = np.asarray(p, dtype=float).ravel()
    out = np.full(v.shape, np.nan)
    idx = np.flatnonzero(np.isfinite(v))
    m = len(idx)
    if m == 0:
        return out
    order = idx[np.argsort(v[idx], kind="stable")]
    scaled = v[order] * (m - np.arange(m))
    out[order] = np.minimum(np.maximum.accumulate(scaled), 1.0)
    return out
