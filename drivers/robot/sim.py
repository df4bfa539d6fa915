"""Simulated arm: a 500 Hz joint-space model whose state is the Ruckig follower's output.

The arm tracks its commanded state perfectly (a kinematic model: no dynamics, no tracking
error), so what the camera simulation sees is exactly the jerk-limited motion of
:class:`drivers.robot.follower.TrajectoryFollower`. Joints in rad, rad/s; time in s.

Real-time pacing: :meth:`SimRobot.end_period` sleeps to the next multiple of ``dt`` on the
monotonic clock; when the process falls behind (a loaded machine), :meth:`SimRobot.step`
advances the model by every missed period (at most ``MAX_CATCH_UP``) so simulated time keeps
up with wall time.
"""

from __future__ import annotations

import time

from drivers.robot.backend import Measured
from drivers.robot.follower import STOP_ACCELERATION, FollowerState, Reference, TrajectoryFollower
from planner.model.system import Limits
from planner.model.transforms import Array
from schemas import defaults

MAX_CATCH_UP = 10  # periods simulated at most per step when the loop fell behind


class SimRobot:
    """A simulated arm for :class:`drivers.robot.node.RobotNode` (backend ``sim``)."""

    kind = "sim"

    def __init__(
        self,
        names: tuple[str, ...],
        q0: Array,
        limits: Limits,
        rate: float = defaults.SERVO_RATE_HZ,
        stop_acceleration: float = STOP_ACCELERATION,
        realtime: bool = True,
    ) -> None:
        self.names = tuple(names)
        self.rate = float(rate)
        self.dt = 1.0 / self.rate
        self.follower = TrajectoryFollower(q0, limits, self.dt, stop_acceleration)
        self.realtime = realtime
        self._next = time.monotonic()
        self.gate = False  # the simulated laser gate output
        self.gate_calls: list[tuple[float, bool]] = []  # (monotonic s, state) per command

    def begin_period(self) -> None:
        """Nothing to do for the model (the UR backend starts its RTDE period here)."""

    def step(self) -> Measured:
        """Advance the model by the elapsed period(s) and return the new state."""
        n = 1
        if self.realtime:
            behind = time.monotonic() - self._next
            n = int(min(max(behind // self.dt, 0) + 1, MAX_CATCH_UP))
        state: FollowerState = self.follower.state
        for _ in range(n):
            state = self.follower.step()
        return Measured(state.q, state.qd, state.mode)

    def end_period(self) -> None:
        """Sleep until the next period boundary (no-op when not real time)."""
        if not self.realtime:
            return
        self._next += self.dt
        now = time.monotonic()
        if self._next > now:
            time.sleep(self._next - now)
        elif now - self._next > MAX_CATCH_UP * self.dt:
            self._next = now  # hopelessly late: drop the backlog

    def measured(self) -> Measured:
        s = self.follower.state
        return Measured(s.q, s.qd, s.mode)

    def command(self, reference: Reference) -> None:
        self.follower.follow(reference)

    def queue(self, reference: Reference) -> None:
        self.follower.enqueue(reference)

    def start_stream(self) -> None:
        """A stream starts (the model can always follow one)."""

    def stream(self, q: Array, qd: Array, qdd: Array) -> None:
        self.follower.stream(q, qd, qdd)

    def brake(self, reason: str) -> None:
        self.follower.brake()

    def set_gate(self, on: bool) -> None:
        """The simulated digital output that switches the laser (recorded with its time)."""
        self.gate = bool(on)
        self.gate_calls.append((time.monotonic(), self.gate))
        del self.gate_calls[:-4096]

    def close(self) -> None:
        self.follower.brake()
