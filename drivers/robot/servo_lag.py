"""How a UR arm follows ``servoJ`` targets: the controller's lag behind the command.

URScript's ``servoj(q, a, v, t, lookahead_time, gain)`` (URScript Manual, e-Series, entry
``servoj``; the same arguments in ur_rtde's ``RTDEControlInterface.servoJ``): "the gain
parameter works the same way as the P-term of a PID controller, where it adjusts the current
position towards the desired (q)"; "lookahead_time is used to project the current position
forward in time with the current velocity. A low value gives fast reaction, a high value
prevents overshoot" (lookahead 0.03-0.2 s, gain 100-2000). Per joint, that is

    qdd = gain * (q_target - (q + lookahead_time * qd))

a proportional controller on the position projected ``lookahead_time`` ahead: a damped
second-order follower (natural frequency ``sqrt(gain)`` rad/s, damping ratio
``lookahead_time * sqrt(gain) / 2``: 0.87 at the driver's 0.1 s / 300), which settles on a
held target exactly and trails a target moving at constant velocity v by exactly
``lookahead_time * v``: the arm lags the command by the lookahead time, as the UR driver
assumes (``URRobot.following_lag``). Integrated per 2 ms controller cycle (semi-implicit
Euler). The gain's unit (1/s^2) is this model's reading of the manual's "P-term"; UR
publishes no transfer function. Joints in rad, rad/s; time in s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from planner.model.transforms import Array
from schemas import defaults

CYCLE = 1.0 / defaults.SERVO_RATE_HZ  # s, the e-Series controller cycle


@dataclass(frozen=True)
class ServoSettings:
    """servoJ's ``lookahead_time`` (s) and ``gain`` (default: the UR driver's settings)."""

    lookahead_time: float = defaults.SERVOJ_LOOKAHEAD_S
    gain: float = defaults.SERVOJ_GAIN

    @property
    def damping(self) -> float:
        """Damping ratio of the follower."""
        return self.lookahead_time * float(np.sqrt(self.gain)) / 2.0


class ServoLag:
    """The arm behind a stream of servoJ targets (see the module docstring)."""

    def __init__(self, q0: Array, settings: ServoSettings | None = None, dt: float = CYCLE):
        self.settings = ServoSettings() if settings is None else settings
        self.dt = float(dt)
        self.q = np.asarray(q0, dtype=float).copy()
        self.qd = np.zeros_like(self.q)

    def step(self, target: Array) -> tuple[Array, Array]:
        """One controller cycle toward ``target``: the arm's new (q, qd)."""
        s = self.settings
        qdd = s.gain * (np.asarray(target, dtype=float) - self.q - s.lookahead_time * self.qd)
        self.qd = self.qd + self.dt * qdd
        self.q = self.q + self.dt * self.qd
        return self.q.copy(), self.qd.copy()


def follow(t: Array, q: Array, settings: ServoSettings | None = None, dt: float = CYCLE) -> Array:
    """Where the arm is at the times ``t`` (s, increasing, from the arm at rest on ``q[0]``)
    when its command runs through the joints ``q`` (K x n) at ``t``, linearly between them,
    one servoJ target per controller cycle ``dt`` (held for the cycle): (K x n) rad."""
    t, q = np.asarray(t, dtype=float), np.asarray(q, dtype=float)
    grid = t[0] + dt * np.arange(int(np.ceil((t[-1] - t[0]) / dt)) + 1)
    command = np.column_stack([np.interp(grid, t, q[:, j]) for j in range(q.shape[1])])
    lag = ServoLag(q[0], settings, dt)  # the arm at grid[k + 1]: one cycle toward command[k]
    arm = np.array([q[0], *(lag.step(c)[0] for c in command[:-1])])
    return np.column_stack([np.interp(t, grid, arm[:, j]) for j in range(q.shape[1])])
