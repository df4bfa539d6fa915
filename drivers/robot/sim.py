"""Simulated arm: a 500 Hz joint-space model driven by the Ruckig follower's output.

By default the arm tracks its commanded state perfectly (a kinematic model: no dynamics, no
tracking error), so what the camera simulation sees is exactly the jerk-limited motion of
:class:`drivers.robot.follower.TrajectoryFollower`. With ``servo`` settings it follows the
command as a UR arm follows servoJ (:mod:`drivers.robot.servo_lag`: it trails a moving
command by the lookahead time and settles on a held one), as the UR backend's arm does.
Joints in rad, rad/s; time in s.

Real-time pacing: :meth:`SimRobot.end_period` sleeps to the next multiple of ``dt`` on the
monotonic clock; when the process falls behind (a loaded machine), :meth:`SimRobot.step`
advances the model by every missed period (at most ``MAX_CATCH_UP``) so simulated time keeps
up with wall time.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from drivers.robot.backend import Measured
from drivers.robot.follower import STOP_ACCELERATION, Reference, TrajectoryFollower
from drivers.robot.servo_lag import ServoLag, ServoSettings
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
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
        servo: ServoSettings | None = None,
    ) -> None:
        self.names = tuple(names)
        self.clock, self.sleep = clock, sleep  # injected by tests
        self.rate = float(rate)
        self.dt = 1.0 / self.rate
        self.follower = TrajectoryFollower(q0, limits, self.dt, stop_acceleration)
        self.lag = None if servo is None else ServoLag(q0, servo, self.dt)
        #: s the arm trails its command (the emission supervisor's following check)
        self.following_lag = 0.0 if servo is None else servo.lookahead_time
        self.realtime = realtime
        self._next = clock()
        self.outputs = 0  # the simulated standard digital outputs (bit k = output k)
        self.output_calls: list[tuple[float, int, bool]] = []  # (monotonic s, output, state)
        self.speed = 1.0  # the simulated speed slider (tests set it)

    def begin_period(self) -> None:
        """Nothing to do for the model (the UR backend starts its RTDE period here)."""

    def step(self) -> Measured:
        """Advance the model by the elapsed period(s) and return the new state."""
        n = 1
        if self.realtime:
            behind = self.clock() - self._next
            n = int(min(max(behind // self.dt, 0) + 1, MAX_CATCH_UP))
            self._next += (n - 1) * self.dt  # the missed periods are simulated now, once
        self.follower.dt = self.dt * self.speed  # the slider slows the trajectory clock
        for _ in range(n):
            if self.lag is not None:  # the arm moves for one cycle toward the held command
                self.lag.step(self.follower.q)
            self.follower.step()
        return self.measured()

    def end_period(self) -> None:
        """Sleep until the next period boundary (no-op when not real time)."""
        if not self.realtime:
            return
        self._next += self.dt
        now = self.clock()
        if self._next > now:
            self.sleep(self._next - now)
        elif now - self._next > MAX_CATCH_UP * self.dt:
            self._next = now  # hopelessly late: drop the backlog

    def measured(self) -> Measured:
        """The arm's state: the command itself, or the lagging arm behind it."""
        s = self.follower.state
        q, qd = (s.q, s.qd) if self.lag is None else (self.lag.q.copy(), self.lag.qd.copy())
        return Measured(q, qd, s.mode, speed=self.speed, outputs=self.outputs)

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

    def set_output(self, output: int, on: bool) -> None:
        """A simulated standard digital output (recorded with its time)."""
        self.outputs = self.outputs | (1 << output) if on else self.outputs & ~(1 << output)
        self.output_calls.append((time.monotonic(), output, bool(on)))
        del self.output_calls[:-4096]

    def output(self, output: int) -> bool:
        """Whether output ``output`` is high."""
        return bool(self.outputs >> output & 1)

    @property
    def gate(self) -> bool:
        """Whether any output is high (the sim's outputs are its laser outputs)."""
        return self.outputs != 0

    @property
    def gate_calls(self) -> list[tuple[float, bool]]:
        """(monotonic s, any output high after it) per output command."""
        out, bits = [], 0
        for t, k, on in self.output_calls:
            bits = bits | (1 << k) if on else bits & ~(1 << k)
            out.append((t, bits != 0))
        return out

    def close(self) -> None:
        self.follower.brake()
