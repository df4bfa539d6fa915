"""Iterative learning control along a path: one pass's measured deviations -> the next pass.

A pass sweeps joint samples ``Q`` (K x nq, rad) meant to put the spot on ``targets`` (K x 3,
world, m) at arc lengths ``arc`` (K, m). The camera measures the spot at some arc lengths
(``measured_arc``, M) with errors ``measured_error`` (M x 3, measured spot - the target at
that arc length, world, m). :func:`ilc_update` interpolates the errors at the K samples
(held at the measured range's ends), maps each one through the model's spot Jacobian into
a damped minimum-norm joint correction in the sample's surface plane (as one servo step,
:class:`~planner.servo.step.Corrector`), low-pass filters the corrections along the arc
(Gaussian, ``smoothing`` m standard deviation: camera noise is not learned) and adds them to
``Q``: the corrected samples for the next pass. Samples whose corrected configuration breaks a
rule (:meth:`~planner.servo.step.Corrector.check`) are listed; the caller decides.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.ndimage import gaussian_filter1d

from planner.model.status import Failure
from planner.model.transforms import Array
from planner.servo.step import Corrector
from schemas.defaults import SERVO_MAX_STEP_RAD


@dataclass(frozen=True)
class IlcSettings:
    """``gain`` of the learned correction (1 = full); ``smoothing`` (m of arc): standard
    deviation of the Gaussian low-pass along the path; ``max_step`` (rad): largest change of
    any joint at one sample; ``damping`` (m/rad) of the least squares."""

    gain: float = 1.0
    smoothing: float = 0.002
    max_step: float = SERVO_MAX_STEP_RAD
    damping: float = 1e-3

    def __post_init__(self) -> None:
        for name in ("gain", "smoothing", "max_step"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"ILC {name} must be finite and > 0, got {v}")


class IlcUpdate(NamedTuple):
    """The next pass: ``q`` (K x nq, rad) = the pass's samples + ``dq`` (filtered, bounded);
    ``error`` (K x 3, m) the measured deviation at each sample; ``failures`` the samples
    whose corrected configuration breaks a rule, as (index, failure)."""

    q: Array
    dq: Array
    error: Array
    failures: list[tuple[int, Failure]]


def lowpass_along_arc(arc: Array, values: Array, sigma: float) -> Array:
    """Gaussian low-pass (standard deviation ``sigma``, m of arc) of ``values`` (K x d)
    sampled at increasing ``arc`` (K, m), through a uniform resampling of the arc."""
    arc = np.asarray(arc, dtype=float)
    values = np.asarray(values, dtype=float)
    length = float(arc[-1] - arc[0])
    if len(arc) < 3 or length <= 0.0:
        return values.copy()
    h = min(sigma / 4.0, length / (len(arc) - 1))
    grid = np.linspace(arc[0], arc[-1], int(np.ceil(length / h)) + 1)
    h = float(grid[1] - grid[0])
    out = np.empty_like(values)
    for j in range(values.shape[1]):
        u = gaussian_filter1d(np.interp(grid, arc, values[:, j]), sigma / h, mode="nearest")
        out[:, j] = np.interp(arc, grid, u)
    return out


def _check_inputs(Q: Array, P: Array, arc: Array, marc: Array, merr: Array) -> None:
    K = len(Q)
    if P.shape != (K, 3) or arc.shape != (K,):
        raise ValueError(f"ILC needs targets K x 3 and arc (K,) for K = {K} samples, got "
                         f"{P.shape} and {arc.shape}")  # fmt: skip
    if np.any(np.diff(arc) < 0) or not np.all(np.isfinite(arc)):
        raise ValueError("ILC arc lengths must be finite and non-decreasing (m)")
    if merr.shape != (len(marc), 3):
        raise ValueError(f"ILC measured errors must be M x 3 for M = {len(marc)}, got {merr.shape}")


def ilc_update(
    corrector: Corrector,
    Q: Array,
    targets: Array,
    normals: Array | None,
    arc: Array,
    measured_arc: Array,
    measured_error: Array,
    settings: IlcSettings | None = None,
) -> IlcUpdate:
    """The corrected joint samples of the next pass (see the module docstring). ``normals``
    (K x 3 unit, or None): the targets' surface normals. Measurements with a non-finite error
    are ignored; ValueError when none is left or shapes disagree."""
    s = settings or IlcSettings()
    Q, P = np.asarray(Q, dtype=float), np.asarray(targets, dtype=float)
    arc, marc = np.asarray(arc, dtype=float), np.asarray(measured_arc, dtype=float).ravel()
    merr = np.asarray(measured_error, dtype=float).reshape(-1, 3)
    _check_inputs(Q, P, arc, marc, merr)
    ok = np.isfinite(marc) & np.all(np.isfinite(merr), axis=1)
    if not ok.any():
        raise ValueError("ILC needs at least one finite measured deviation")
    order = np.argsort(marc[ok], kind="stable")
    marc, merr = marc[ok][order], merr[ok][order]
    E = np.column_stack([np.interp(arc, marc, merr[:, j]) for j in range(3)])
    dq = np.empty_like(Q)
    J = []
    for k in range(len(Q)):
        n = None if normals is None else normals[k]
        plane_normal = corrector.model.plane_normal(Q[k], P[k], n)
        sj = corrector.model.evaluate(Q[k], P[k], plane_normal)
        Jp = sj.plane_jacobian
        J.append(sj.jacobian)
        A = Jp @ Jp.T + s.damping**2 * np.eye(2)
        dq[k] = -s.gain * Jp.T @ np.linalg.solve(A, sj.axes.T @ E[k])
    dq = lowpass_along_arc(arc, dq, s.smoothing)
    big = np.max(np.abs(dq), axis=1, keepdims=True)
    dq *= np.minimum(1.0, s.max_step / np.maximum(big, 1e-300))
    Qn = Q + dq
    failures = []
    for k in range(len(Q)):
        expected = P[k] + E[k] + J[k] @ dq[k]  # the measured spot + J dq, not the model's
        bad = corrector.check(Qn[k], P[k], None if normals is None else normals[k], expected)
        if bad is not None:
            failures.append((k, bad))
    return IlcUpdate(Qn, dq, E, failures)


def polyline_deviation(points: Array, polyline: Array) -> Array:
    """Distance (m) of each point (M x 3) from a polyline (L x 3, world, m)."""
    X = np.asarray(points, dtype=float).reshape(-1, 3)
    V = np.asarray(polyline, dtype=float).reshape(-1, 3)
    if len(V) == 1:
        return np.linalg.norm(X - V[0], axis=1)
    A, B = V[:-1], V[1:]
    AB = B - A
    t = np.einsum("msk,sk->ms", X[:, None, :] - A[None], AB) / np.maximum(
        np.einsum("sk,sk->s", AB, AB), 1e-300
    )
    C = A[None] + np.clip(t, 0.0, 1.0)[..., None] * AB[None]
    return np.min(np.linalg.norm(X[:, None, :] - C, axis=2), axis=1)
