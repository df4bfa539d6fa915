"""The spot's path parameter s(t) along a joint spline of arc length.

A 1-DOF online Ruckig whose velocity limit is the spot speed, lowered ahead of time where a
joint velocity, acceleration or jerk limit would bind at the spline's derivatives
(:func:`path_speed_limit`); the spot acceleration and jerk are nominal multiples of the
speed (:func:`spot_ramp`), capped by the joints. Arc length in m, time in s, joints rad.
"""

from __future__ import annotations

from bisect import bisect_left
from typing import NamedTuple

import numpy as np

from planner.errors import PlanError
from planner.model.system import Limits
from planner.model.transforms import Array

_SHARE_V, _SHARE_A, _SHARE_J = 0.9, 0.5, 0.3  # share of each limit given to each term
SPOT_ACCEL_PER_SPEED = 20.0  # 1/s: nominal spot acceleration (m/s^2) per m/s of spot speed
SPOT_JERK_PER_ACCEL = 20.0  # 1/s: nominal spot jerk (m/s^3) per m/s^2 of spot acceleration


def path_speed_limit(
    spline: object, arc: Array, lim: Limits, spot_speed: float, a_s: float
) -> tuple[Array, Array, Array]:
    """Largest spot speed (m/s) at each sample keeping q' sd, q'' sd^2 and the jerk terms
    within their shares of the limits; returns (speed, limit code 0..3, joint index)."""
    d1, d2, d3 = (np.abs(spline(arc, nu)) + 1e-12 for nu in (1, 2, 3))  # type: ignore[operator]
    caps = np.stack(
        [
            np.full(len(arc), spot_speed),
            (_SHARE_V * lim.velocity / d1).min(axis=1),
            np.sqrt(_SHARE_A * lim.acceleration / d2).min(axis=1),
            np.minimum(np.cbrt(_SHARE_J * lim.jerk / d3), _SHARE_J * lim.jerk / (3 * d2 * a_s))
            .min(axis=1),
        ]
    )  # fmt: skip
    code = caps.argmin(axis=0)
    joints = np.stack(
        [np.zeros(len(arc), dtype=int), (lim.velocity / d1).argmin(axis=1),
         (lim.acceleration / d2).argmin(axis=1), (lim.jerk / d3).argmin(axis=1)]
    )  # fmt: skip
    return caps.min(axis=0), code, joints[code, np.arange(len(arc))]


class Profile(NamedTuple):
    """The path parameter s(t) (m, m/s, m/s^2) sampled at ``rate`` along a joint spline of
    arc length, with the speed caps the joint limits impose at each path sample (``speed``
    m/s, binding ``code`` 0 spot speed .. 3 jerk, stacked ``joint``) and the spot
    acceleration and jerk used (m/s^2, m/s^3; ``accel_joint`` / ``jerk_joint``: the joint
    that capped the acceleration / the jerk below its nominal value, -1 if none)."""

    s: Array
    sd: Array
    sdd: Array
    spline: object
    speed: Array
    code: Array
    joint: Array
    a_s: float
    j_s: float
    accel_joint: int
    jerk_joint: int = -1


def spot_ramp(spot_speed: float) -> tuple[float, float]:
    """Nominal spot acceleration (m/s^2) and jerk (m/s^3) for a spot speed (m/s)."""
    a_s = spot_speed * SPOT_ACCEL_PER_SPEED
    return a_s, a_s * SPOT_JERK_PER_ACCEL


def ramp_length(spot_speed: float, a_s: float | None = None, j_s: float | None = None) -> float:
    """Distance (m) a jerk-limited ramp from rest to ``spot_speed`` (m/s) takes with spot
    acceleration ``a_s`` and jerk ``j_s`` (default :func:`spot_ramp`)."""
    a0, j0 = spot_ramp(spot_speed)
    a, j = a0 if a_s is None else a_s, j0 if j_s is None else j_s
    v = spot_speed
    t_acc = v / a + a / j if v * j >= a * a else 2 * np.sqrt(v / j)
    return float(v * t_acc / 2)


def lookahead(speed: float, a_s: float, j_s: float, rate: float) -> float:
    """Distance (m) ahead of the spot over which :func:`profile` applies the speed caps: a
    conservative jerk-limited stopping distance from ``speed`` (m/s) plus two periods."""
    return speed * speed / (2 * a_s) + speed * a_s / j_s + 2 * speed / rate


def profile(q_path: Array, arc: Array, lim: Limits, spot_speed: float, rate: float) -> Profile:
    """Sample s(t) from rest to rest along the path at ``rate`` (1-DOF online Ruckig whose
    velocity limit is the spot speed, lowered ahead of time where a joint limit binds)."""
    from ruckig import InputParameter, OutputParameter, Result, Ruckig
    from scipy.interpolate import make_interp_spline

    spline = make_interp_spline(arc, q_path, k=5 if len(arc) > 5 else min(3, len(arc) - 1))
    d1max = np.abs(spline(arc, 1)).max(axis=0) + 1e-12
    a_nom, _ = spot_ramp(spot_speed)
    a_caps = _SHARE_A * lim.acceleration / d1max
    a_s = float(min(a_nom, a_caps.min()))
    j_caps = _SHARE_J * lim.jerk / d1max
    j_s = float(min(a_s * SPOT_JERK_PER_ACCEL, j_caps.min()))
    accel_joint = int(np.argmin(a_caps)) if a_caps.min() < a_nom else -1
    jerk_joint = int(np.argmin(j_caps)) if j_caps.min() < a_s * SPOT_JERK_PER_ACCEL else -1
    speed, code, joint = path_speed_limit(spline, arc, lim, spot_speed, a_s)
    L = float(arc[-1])
    otg, inp, out = Ruckig(1, 1.0 / rate), InputParameter(1), OutputParameter(1)
    inp.current_position, inp.current_velocity, inp.current_acceleration = [0.0], [0.0], [0.0]
    inp.target_position, inp.target_velocity, inp.target_acceleration = [L], [0.0], [0.0]
    inp.max_acceleration, inp.max_jerk = [a_s], [j_s]
    S = [(0.0, 0.0, 0.0)]
    arc_list, speed_list = [float(x) for x in arc], [float(x) for x in speed]  # bisect, min
    for _ in range(int(50 * (L / max(speed.min(), 1e-9) + 1) * rate)):
        s, v = inp.current_position[0], inp.current_velocity[0]
        brake = lookahead(v, a_s, j_s, rate)
        i0, i1 = bisect_left(arc_list, s), bisect_left(arc_list, s + brake)
        inp.max_velocity = [max(min(speed_list[max(i0 - 1, 0) : i1 + 1]), 1e-6)]
        result = otg.update(inp, out)
        if result not in (Result.Working, Result.Finished):
            raise PlanError(f"Ruckig failed ({result}) timing the path at s = {s:.4f} m")
        S.append((out.new_position[0], out.new_velocity[0], out.new_acceleration[0]))
        out.pass_to_input(inp)
        if result == Result.Finished:
            break
    else:
        raise PlanError(f"path timing did not finish (length {L:.4f} m)")
    s, sd, sdd = np.clip(np.array(S), [0.0, 0.0, -np.inf], [L, np.inf, np.inf]).T
    return Profile(s, sd, sdd, spline, speed, code, joint, a_s, j_s, accel_joint, jerk_joint)


def aligned(prof: Profile, s_mark: float, rate: float) -> Profile:
    """``prof`` with its motion delayed by a fraction of a period so that a sample lands
    exactly on arc length ``s_mark`` (m; where a mark starts): the spot rests for that
    fraction at the start, then follows the same s(t) (quintic Hermite through the samples'
    s, sd, sdd), one sample longer. Unchanged when ``s_mark`` is outside the profile or
    already on a sample."""
    from scipy.optimize import brentq

    s, sd, sdd = prof.s, prof.sd, prof.sdd
    k = int(np.searchsorted(s, s_mark, side="left"))
    if k == 0 or k >= len(s) or s[k] - s_mark < 1e-12 or s[k] <= s[k - 1]:
        return prof
    t = np.arange(len(s)) / rate
    curve = QuinticHermite(t, s, sd, sdd)
    tau = float(brentq(lambda x: float(curve(np.array([x]))[0]) - s_mark, t[k - 1], t[k],
                       xtol=1e-15))  # fmt: skip
    delay = k / rate - tau  # in (0, 1 / rate): the crossing moves onto sample k
    tn = np.clip(np.arange(len(s) + 1) / rate - delay, 0.0, t[-1])
    s_new = np.clip(curve(tn), 0.0, float(s[-1]))
    sd_new, sdd_new = curve(tn, 1), curve(tn, 2)
    s_new[-1], sd_new[[0, -1]], sdd_new[[0, -1]] = s[-1], 0.0, 0.0
    return prof._replace(s=s_new, sd=sd_new, sdd=sdd_new)


class QuinticHermite:
    """The piecewise quintic through samples ``(t, y, yd, ydd)`` matching value, first and
    second derivative at every sample (what ``scipy.interpolate.BPoly.from_derivatives``
    builds from three derivatives a side, but vectorised: that one loops in Python per
    interval, 130 ms for a 2300-sample profile, half of a path preview's timing).
    ``curve(tq, nu)``: the ``nu``-th derivative (0-2) at ``tq`` (clipped to
    ``[t[0], t[-1]]``)."""

    def __init__(self, t: Array, y: Array, yd: Array, ydd: Array) -> None:
        self.t = np.asarray(t, dtype=float)
        h = np.diff(self.t)
        y0, y1 = y[:-1], y[1:]
        v0, v1 = h * yd[:-1], h * yd[1:]  # per unit of u = (t - t_i) / h
        a0, a1 = h**2 * ydd[:-1], h**2 * ydd[1:]
        c0, c1, c2 = y0, v0, a0 / 2
        P, V, A = y1 - (c0 + c1 + c2), v1 - (c1 + 2 * c2), a1 - 2 * c2
        c3, c4, c5 = 10 * P - 4 * V + A / 2, -15 * P + 7 * V - A, 6 * P - 3 * V + A / 2
        self.h = h
        self.c = np.stack([c0, c1, c2, c3, c4, c5])  # 6 x (n - 1), ascending powers of u

    def __call__(self, tq: Array, nu: int = 0) -> Array:
        tq = np.clip(np.asarray(tq, dtype=float), self.t[0], self.t[-1])
        i = np.clip(np.searchsorted(self.t, tq, side="right") - 1, 0, len(self.h) - 1)
        h, u = self.h[i], (tq - self.t[i]) / self.h[i]
        c = self.c[:, i]
        if nu == 0:
            return c[0] + u * (c[1] + u * (c[2] + u * (c[3] + u * (c[4] + u * c[5]))))
        if nu == 1:
            d = c[1] + u * (2 * c[2] + u * (3 * c[3] + u * (4 * c[4] + u * 5 * c[5])))
            return d / h
        if nu == 2:
            d = 2 * c[2] + u * (6 * c[3] + u * (12 * c[4] + u * 20 * c[5]))
            return d / h**2
        raise ValueError(f"derivative order {nu} not in 0-2")
