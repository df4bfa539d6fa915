"""Predicting a moving target from noisy, late measurements (world frame, m, s).

Two predictors, one interface: :meth:`update` with a measurement ``z`` (m) taken at ``t``
(s, the camera frame's capture time) and its covariance ``R`` (m^2, :mod:`planner.track.noise`),
then :meth:`predict` at any later time - the time the command takes effect - gives the
position, velocity and the position covariance (:class:`Prediction`).

- :class:`ConstantVelocity`: the line through the last two measurements.
- :class:`KalmanCV`: a constant-velocity Kalman filter, state ``x = [p, v]`` (6), transition
  ``p += v dt``, process noise a white acceleration of RMS ``accel_sigma`` (m/s^2) per axis
  held over each step (``Q = s_a^2 [[dt^4/4, dt^3/2], [dt^3/2, dt^2]]`` per axis). A
  measurement whose normalised innovation ``nis = y' S^-1 y`` exceeds :data:`NIS_GATE` (the
  chi-square 99.9 % point, 3 dof) is a manoeuvre (a linear motion turning back): the filter
  restarts from it, velocity unknown again (``speed_sigma``), so its reported uncertainty
  grows until it has re-learnt the velocity.

The process noise comes from the motion scale (:func:`accel_sigma_for`): the acceleration of
a sine with the given peak speed and period.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from planner.model.transforms import Array

#: chi-square 99.9 % point with 3 degrees of freedom: a larger NIS is a manoeuvre
NIS_GATE = 16.27
#: m/s, default RMS of the target's speed before it is measured (the fastest motion tracked)
SPEED_SCALE = 0.05
#: m/s, default peak speed of the target's smooth motion (breathing: 7.9 mm/s at 5 mm, 0.25 Hz)
MOTION_SPEED = 0.01
#: s, default period of the target's motion (breathing)
PERIOD_SCALE = 4.0


def accel_sigma_for(speed: float = MOTION_SPEED, period: float = PERIOD_SCALE) -> float:
    """RMS acceleration (m/s^2) of a sine motion of peak ``speed`` (m/s) and ``period`` (s):
    peak acceleration ``2 pi speed / period`` over sqrt(2)."""
    return 2 * np.pi * speed / period / np.sqrt(2)


class Prediction(NamedTuple):
    """The target at time ``t`` (s): position ``p`` (m), velocity ``v`` (m/s), position
    covariance ``cov`` (3x3, m^2), all world frame."""

    t: float
    p: Array
    v: Array
    cov: Array

    @property
    def sigma(self) -> float:
        """RMS of the position error along its worst direction (m)."""
        return float(np.sqrt(max(float(np.linalg.eigvalsh(self.cov)[-1]), 0.0)))


class ConstantVelocity:
    """Extrapolates the line through the last two measurements."""

    def __init__(self) -> None:
        self._last: list[tuple[float, Array, Array]] = []

    @property
    def ready(self) -> bool:
        return bool(self._last)

    def update(self, t: float, z: Array, R: Array) -> float:
        """Take measurement ``z`` (m) at ``t`` (s) with covariance ``R``; returns 0 (no test)."""
        self._last = [*self._last[-1:], (float(t), np.asarray(z, float), np.asarray(R, float))]
        return 0.0

    def predict(self, t: float) -> Prediction:
        """Position at ``t`` on the line (the last measurement while only one is known)."""
        t2, z2, R2 = self._last[-1]
        if len(self._last) < 2:
            return Prediction(t, z2.copy(), np.zeros(3), R2.copy())
        t1, z1, R1 = self._last[0]
        dt = t2 - t1
        v = (z2 - z1) / dt
        k = (t - t2) / dt  # p = z2 + k (z2 - z1)
        cov = (1 + k) ** 2 * R2 + k**2 * R1
        return Prediction(t, z2 + v * (t - t2), v, cov)


class KalmanCV:
    """Constant-velocity Kalman filter (see the module docstring)."""

    def __init__(self, accel_sigma: float | None = None, speed_sigma: float = SPEED_SCALE) -> None:
        self.accel_sigma = accel_sigma_for() if accel_sigma is None else float(accel_sigma)
        self.speed_sigma = float(speed_sigma)
        self.x = np.zeros(6)
        self.P = np.zeros((6, 6))
        self.t: float | None = None
        self.manoeuvres = 0  # restarts after a NIS above the gate

    @property
    def ready(self) -> bool:
        return self.t is not None

    def _restart(self, t: float, z: Array, R: Array, v: Array) -> None:
        self.x = np.concatenate([z, v])
        self.P = np.zeros((6, 6))
        self.P[:3, :3] = R
        self.P[3:, 3:] = self.speed_sigma**2 * np.eye(3)
        self.t = t

    def _propagate(self, dt: float) -> tuple[Array, Array]:
        F = np.eye(6)
        F[:3, 3:] = dt * np.eye(3)
        s2 = self.accel_sigma**2
        Q = np.zeros((6, 6))
        Q[:3, :3] = s2 * dt**4 / 4 * np.eye(3)
        Q[:3, 3:] = Q[3:, :3] = s2 * dt**3 / 2 * np.eye(3)
        Q[3:, 3:] = s2 * dt**2 * np.eye(3)
        return F @ self.x, F @ self.P @ F.T + Q

    def update(self, t: float, z: Array, R: Array) -> float:
        """Fuse measurement ``z`` (m) taken at ``t`` (s) with covariance ``R`` (m^2); returns
        its normalised innovation (0 for the first). An out-of-order one is ignored (nan)."""
        z, R = np.asarray(z, dtype=float), np.asarray(R, dtype=float)
        if self.t is None:
            self._restart(float(t), z, R, np.zeros(3))
            return 0.0
        dt = float(t) - self.t
        if dt <= 0:
            return float("nan")
        x, P = self._propagate(dt)
        y = z - x[:3]
        S = P[:3, :3] + R
        nis = float(y @ np.linalg.solve(S, y))
        if nis > NIS_GATE:
            self.manoeuvres += 1
            self._restart(float(t), z, R, x[3:])
            return nis
        K = np.linalg.solve(S, P[:3, :]).T  # P H' S^-1 (S symmetric)
        self.x = x + K @ y
        I_KH = np.eye(6)
        I_KH[:, :3] -= K
        self.P = I_KH @ P @ I_KH.T + K @ R @ K.T  # Joseph form: stays symmetric, PSD
        self.t = float(t)
        return nis

    def predict(self, t: float) -> Prediction:
        """The target at ``t`` (s), from the last update (no change of state)."""
        assert self.t is not None, "predict before the first update"
        x, P = self._propagate(max(float(t) - self.t, 0.0))
        return Prediction(float(t), x[:3], x[3:], P[:3, :3])
