"""The laser gate of a robot driver: one digital output of the arm switches the laser.

:class:`LaserGate` is driven from the control loop of :class:`drivers.robot.node.RobotNode`
once per period: on while the followed trajectory plays one of its ``laser_on`` intervals
(:meth:`drivers.robot.follower.TrajectoryFollower.laser_edge`) or while a followed setpoint
stream's newest setpoint has ``laser_on``, off otherwise, off on a
backend fault, and forced off (commanded again even if already off) at start-up, in every
safety stop and at exit. Each switch is recorded as a :class:`GateSwitch` and published as
a :class:`schemas.messages.LaserState`. Times in s.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any, NamedTuple

from schemas.messages import LaserState

MAX_SWITCHES = 4096  # switches remembered
EDGE_SLACK = 1e-6  # s


class GateSwitch(NamedTuple):
    """One switch: ``on``; the interval edge it plays (s, reference time; None for a forced
    or fault switch), the reference time it was switched at, ``lag`` = their difference (s);
    ``latency`` (s) from the control period's start to the output command; ``reason``."""

    on: bool
    edge: float | None
    tau: float
    lag: float
    latency: float
    reason: str


class LaserGate:
    """The gate output ``output`` of ``robot``, commanded through ``backend.set_gate`` and
    published with ``put`` (bytes)."""

    def __init__(self, robot: str, output: int, backend: Any, put: Callable[[bytes], Any]) -> None:
        self.robot, self.output, self.backend, self._put = robot, output, backend, put
        self.on = False
        self.switches: list[GateSwitch] = []
        self.period_start = time.monotonic()  # monotonic s, set by the loop every period

    def update(self, fault: str | None, streamed: bool = False) -> None:
        """This period's state: on inside a laser interval of the followed trajectory, or
        while the follower streams and ``streamed`` (the followed stream's newest setpoint
        asks for it); off on a fault."""
        follower = self.backend.follower
        edge = follower.laser_edge() if fault is None else None
        stream = fault is None and streamed and follower.mode == "streaming"
        if (edge is not None or stream) == self.on:
            return
        if edge is not None:
            self._switch(True, edge, "laser_on interval")
        elif stream:
            self._switch(True, None, "setpoint laser_on")
        elif follower.mode == "streaming" and fault is None:
            self._switch(False, None, "setpoint laser off")
        else:
            self._switch(False, self._off_edge(follower), fault or "interval ended")

    def force_off(self, reason: str) -> None:
        """Command the output off now, whatever its state."""
        self._switch(False, None, reason, force=True)

    def _switch(self, on: bool, edge: float | None, reason: str, force: bool = False) -> None:
        tau = self.backend.follower.tau
        self.backend.set_gate(on)
        latency = time.monotonic() - self.period_start
        changed = on != self.on
        self.on = on
        if changed:
            lag = tau - edge if edge is not None else 0.0
            self.switches.append(GateSwitch(on, edge, tau, lag, latency, reason))
            del self.switches[:-MAX_SWITCHES]
        if changed or force:
            self.publish(reason)

    @staticmethod
    def _off_edge(follower: Any) -> float | None:
        """The end (s, reference time) of the interval just left, if one was."""
        ref = follower.reference
        if follower.mode != "following" or ref is None or ref.laser_on is None:
            return None
        ends = ref.laser_on[:, 1] - ref.t[0]
        before = ends[ends <= follower.tau + EDGE_SLACK]
        return float(before[-1]) if len(before) else None

    def publish(self, reason: str | None = None) -> None:
        """The current state on ``<prefix>/laser`` (with the last switch's figures)."""
        last = self.switches[-1] if self.switches else None
        msg = LaserState(robot=self.robot, t=time.time(), on=self.on, output=self.output,
                         reason=reason, lag=None if last is None else last.lag,
                         latency=None if last is None else last.latency)  # fmt: skip
        from planner.service.bus import encode

        self._put(encode(msg))
