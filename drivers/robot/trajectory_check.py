"""Checks a robot driver applies to a received joint trajectory before it moves the arm.

Joints in rad, rad/s, rad/s^2; times in s from the trajectory's first sample. Every failed
check raises :class:`planner.errors.InputError` whose ``where`` names the sample
(``q[12]``, ``qd[3]``) and whose reason gives the joint and the figure against its limit,
e.g. ``q[12]: wrist_3 moves 0.5000 rad in 0.0020 s = 250.0 rad/s > 3.1416 rad/s``.

Two groups, so that the costly part can run away from the control loop:

- :func:`check_samples` / :func:`parse_trajectory` need nothing but the message and the
  arm's limits (run in the parse worker of :mod:`drivers.robot.intake`):

  1. robot name and joint names (same order);
  2. every sample inside the position limits, declared ``qd`` / ``qdd`` inside the
     velocity / acceleration limits;
  3. the *positions themselves*, as the follower plays them (linear interpolation, one
     sample per control ``period``): first differences ``(q[k] - q[k-1]) / dt`` against
     the velocity limit, second differences against the acceleration limit, the velocity
     change taken over ``min(sample spacing, period)`` (samples sparser than the control
     period are played as velocity steps within one period);
  4. declared ``qd`` consistent with the positions: the mean of ``qd[k-1]`` and ``qd[k]``
     within ``a_max * period`` of the finite-difference velocity (the velocity step one
     control period at the acceleration limit can absorb when the follower hands over
     from the samples to Ruckig); declared ``qdd`` likewise within
     ``j_max * max(dt, period)`` of the finite differences of ``qd``. A correct
     jerk-limited trajectory is off by at most ``j_max dt^2 / 12`` and ``j_max dt / 4``
     (trapezoid rule): 1.7e-5 rad/s and 0.025 rad/s^2 at 500 Hz and 50 rad/s^3, far
     inside. Zeroed velocities on a moving trajectory are off by the whole speed.

- :func:`check_start` compares the first sample with a state only the control loop knows
  (the measured joints, or the last sample of the running trajectory).

Slack: the limits are checked with a relative slack :data:`LIMIT_SLACK` (floating-point
noise) plus what a position rounding of :data:`POSITION_NOISE` rad adds to the finite
differences (2 noise / dt on a velocity, 4 noise / h^2 on an acceleration). A correct
500 Hz trajectory from Ruckig samples its continuous motion, whose first differences are
interval means of the velocity and second differences weighted means of the acceleration,
so it needs no more: the planner's trajectories reach the acceleration limit to 2e-11
(relative) and pass.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from drivers.robot.follower import Reference
from planner.errors import InputError
from planner.model.system import Limits
from planner.model.transforms import Array
from schemas import defaults
from schemas.messages import JointTrajectory

START_TOLERANCE = 0.01  # rad: largest |q_traj[0] - q_now| accepted (any joint)
LIMIT_SLACK = 1e-6  # relative slack on velocity/acceleration limits (numerical noise)
POSITION_NOISE = 1e-9  # rad: position rounding the finite-difference checks tolerate
DEFAULT_PERIOD = 1.0 / defaults.SERVO_RATE_HZ  # s: control period of the 500 Hz backends


class Parsed(NamedTuple):
    """A trajectory that passed every state-free check."""

    id: str | None
    session: str | None
    reference: Reference


def _first(bad: np.ndarray) -> tuple[int, int] | None:
    """(sample, joint) of the first True in a K x n mask, or None."""
    if not np.any(bad):
        return None
    k, j = (int(i) for i in np.argwhere(bad)[0])
    return k, j


def _check_bounds(q: Array, qd: Array, qdd: Array, names: tuple[str, ...], lim: Limits) -> None:
    vmax = lim.velocity * (1 + LIMIT_SLACK)
    amax = lim.acceleration * (1 + LIMIT_SLACK)
    rules = [
        ("q", q, q < lim.lower, lim.lower, "below lower limit", "rad"),
        ("q", q, q > lim.upper, lim.upper, "above upper limit", "rad"),
        ("qd", qd, np.abs(qd) > vmax, lim.velocity, "exceeds", "rad/s"),
        ("qdd", qdd, np.abs(qdd) > amax, lim.acceleration, "exceeds", "rad/s^2"),
    ]
    for key, x, bad, bound, what, unit in rules:
        hit = _first(bad)
        if hit is not None:
            k, j = hit
            raise InputError(
                f"{x[k, j]:.4f} {unit} on joint {names[j]} {what} {bound[j]:.4f} {unit}",
                f"{key}[{k}]",
            )


def _check_differences(
    t: Array, q: Array, names: tuple[str, ...], lim: Limits, period: float
) -> Array:
    """Velocity and acceleration of the played positions; returns the velocities (K-1 x n)."""
    dt = np.diff(t)[:, None]
    dq = np.diff(q, axis=0)
    v = dq / dt
    hit = _first(np.abs(v) > lim.velocity * (1 + LIMIT_SLACK) + 2 * POSITION_NOISE / dt)
    if hit is not None:
        k, j = hit
        raise InputError(
            f"{names[j]} moves {abs(dq[k, j]):.4f} rad in {dt[k, 0]:.4f} s = "
            f"{abs(v[k, j]):.1f} rad/s > {lim.velocity[j]:.4f} rad/s",
            f"q[{k + 1}]",
        )
    h = np.minimum((dt[1:] + dt[:-1]) / 2, period)
    dv = np.diff(v, axis=0)
    a = dv / h
    hit = _first(np.abs(a) > lim.acceleration * (1 + LIMIT_SLACK) + 4 * POSITION_NOISE / h**2)
    if hit is not None:
        k, j = hit
        raise InputError(
            f"{names[j]} velocity changes {abs(dv[k, j]):.4f} rad/s in {h[k, 0]:.4f} s = "
            f"{abs(a[k, j]):.1f} rad/s^2 > {lim.acceleration[j]:.4f} rad/s^2",
            f"q[{k + 1}]",
        )
    return v


def _check_consistency(
    t: Array, v: Array, qd: Array, qdd: Array, names: tuple[str, ...], lim: Limits, period: float
) -> None:
    dt = np.diff(t)[:, None]
    v_decl = (qd[1:] + qd[:-1]) / 2
    tol_v = lim.acceleration * period + 2 * POSITION_NOISE / dt
    hit = _first(np.abs(v - v_decl) > tol_v)
    if hit is not None:
        k, j = hit
        raise InputError(
            f"declared velocity of {names[j]} averages {v_decl[k, j]:.4f} rad/s up to sample "
            f"{k + 1} but q moves at {v[k, j]:.4f} rad/s (tolerance {tol_v[k, j]:.4f} rad/s)",
            f"qd[{k}]",
        )
    a_fd = np.diff(qd, axis=0) / dt
    a_decl = (qdd[1:] + qdd[:-1]) / 2
    tol_a = lim.jerk * np.maximum(dt, period) + lim.acceleration * LIMIT_SLACK
    hit = _first(np.abs(a_fd - a_decl) > tol_a)
    if hit is not None:
        k, j = hit
        raise InputError(
            f"declared acceleration of {names[j]} averages {a_decl[k, j]:.4f} rad/s^2 up to "
            f"sample {k + 1} but qd changes at {a_fd[k, j]:.4f} rad/s^2 "
            f"(tolerance {tol_a[k, j]:.4f} rad/s^2)",
            f"qdd[{k}]",
        )


def check_samples(
    t: Array,
    q: Array,
    qd: Array,
    qdd: Array,
    names: tuple[str, ...],
    limits: Limits,
    period: float = DEFAULT_PERIOD,
) -> None:
    """State-free numeric checks 2-4 of the module docstring (arrays K and K x n)."""
    _check_bounds(q, qd, qdd, names, limits)
    if len(t) < 2:
        return
    v = _check_differences(t, q, names, limits, period)
    _check_consistency(t, v, qd, qdd, names, limits, period)


def check_message(
    msg: JointTrajectory,
    robot: str,
    names: tuple[str, ...],
    limits: Limits,
    period: float = DEFAULT_PERIOD,
) -> Parsed:
    """Every state-free check of a decoded message; the ready :class:`Parsed` arrays."""
    if msg.robot != robot:
        raise InputError(
            f"trajectory is for robot {msg.robot!r}, this driver is {robot!r}", "robot"
        )
    if tuple(msg.names) != tuple(names):
        raise InputError(f"joint names {msg.names} differ from {list(names)}", "names")
    t, q, qd, qdd = (np.asarray(a, dtype=float) for a in (msg.t, msg.q, msg.qd, msg.qdd))
    check_samples(t, q, qd, qdd, names, limits, period)
    laser, aim = (None if v is None else np.asarray(v, dtype=float).reshape(-1, 2)
                  for v in (msg.laser_on, msg.aim_on))  # fmt: skip
    return Parsed(msg.id, msg.session, Reference(t, q, qd, qdd, laser, aim))


def check_start(
    q_first: Array, q_ref: Array, names: tuple[str, ...], tolerance: float, against: str
) -> None:
    """The first sample within ``tolerance`` rad of ``q_ref`` (``against`` says what that is)."""
    gap = np.abs(np.asarray(q_first, dtype=float) - np.asarray(q_ref, dtype=float))
    if np.max(gap) > tolerance:
        j = int(np.argmax(gap))
        raise InputError(
            f"starts {gap[j]:.4f} rad from {against} on joint {names[j]} "
            f"(tolerance {tolerance:g} rad)",
            "q[0]",
        )


def check_trajectory(
    msg: JointTrajectory,
    robot: str,
    names: tuple[str, ...],
    limits: Limits,
    q_now: Array,
    start_tolerance: float = START_TOLERANCE,
    period: float = DEFAULT_PERIOD,
) -> Reference:
    """All checks for an idle arm at ``q_now``: the reference to follow, or InputError."""
    parsed = check_message(msg, robot, names, limits, period)
    check_start(parsed.reference.q[0], q_now, names, start_tolerance, "the current state")
    return parsed.reference
