"""The robot node's handling of setpoint streams, once per control period.

:class:`StreamingMixin` is the part of :class:`drivers.robot.node.RobotNode` that starts,
follows and ends setpoint streams (the rules are in the node's module docstring): it takes
the events of :class:`drivers.robot.setpoint_intake.SetpointIntake`, admits a new stream with
the node's own rules for trajectories (stop, braking, planner alive, fresh heartbeat of its
session) plus the stream's start check, hands the target of
:class:`drivers.robot.streaming.StreamControl` to the backend every period, and ends the
stream on staleness or a rejected setpoint. Times are monotonic s.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from drivers.robot.backend import Measured, RobotBackend
from drivers.robot.follower import REST_VELOCITY
from drivers.robot.setpoint_check import check_stream_start
from drivers.robot.setpoint_intake import SetpointIntake, StreamEvent
from drivers.robot.streaming import StreamControl
from planner.errors import InputError

EXECUTING = ("approach", "following", "settle")  # follower modes that play a trajectory


class StreamingMixin:
    """Setpoint streams for the robot node (needs the attributes and methods below)."""

    backend: RobotBackend
    gate: Any
    gate_output: int | None
    setpoints: SetpointIntake
    streams: StreamControl
    rejection: str | None
    stopped_by: str | None

    def _admissible(self, received: float, session: str | None) -> None:
        raise NotImplementedError

    def _check_emission(self, laser_on: bool, aim_on: bool) -> None:
        raise NotImplementedError

    def _safe_stop(self, reason: str, rejected: str | None = None) -> None:
        raise NotImplementedError

    def _publish_status(self, m: Measured) -> None:
        raise NotImplementedError

    def _follow_streams(self, now: float) -> None:
        """Setpoint streams, once per period: start, follow or end one (module docstring)."""
        sc = self.streams
        for ev in self.setpoints.take():
            if ev.kind == "start":
                self._start_stream(ev)
            elif ev.kind == "next" and ev.sample is not None:
                sc.advance(ev.stream, ev.sample)
            elif ev.kind == "rejected" and sc.follows(ev.stream):
                self._safe_stop(f"setpoint rejected: {ev.reason}", rejected=ev.reason)
            elif ev.kind == "rejected" and not ev.stream:
                sc.refuse(None, ev.reason or "rejected")
                self._publish_status(self.backend.measured())
        if sc.active is None:
            return
        if sc.stale(now):
            reason = f"setpoint stream stale: no setpoint for {1e3 * sc.silent(now):.0f} ms"
            if np.any(np.abs(self.backend.follower.qd) > REST_VELOCITY):
                self._safe_stop(reason)
            else:  # at rest on its last setpoint: the normal end of a stream
                self._end_stream(reason)
            return
        self.backend.stream(*sc.target(now))

    def _start_stream(self, ev: StreamEvent) -> None:
        """Admit (rule 1 of streams) and follow a new stream, or refuse it."""
        s = ev.sample
        assert s is not None
        try:
            self._check_emission(s.laser_on, s.aim)
            self._admissible(ev.received, s.session)
            mode = self.backend.follower.mode
            if mode in EXECUTING:
                raise InputError(f"a trajectory is executing (mode {mode}): stream once the "
                                 "arm rests, or stop it first", "body")  # fmt: skip
            m = self.backend.measured()
            check_stream_start(s, m.q, m.qd, self.backend.names)
            self.backend.start_stream()
        except InputError as exc:
            self.setpoints.end(ev.stream)
            self.streams.refuse(s, str(exc))
        else:
            self.streams.begin(ev.stream, s)
            self.rejection = self.stopped_by = None
        self._publish_status(self.backend.measured())

    def _end_stream(self, reason: str, braked: bool = False, rejected: bool = False) -> None:
        """Stop following the stream (laser off); the arm stays where the caller left it."""
        if self.gate is not None and (self.gate.on or self.gate.aim):
            self.gate.force_off(reason)
        stream = self.streams.end(reason, braked, rejected)
        if stream is None:
            return
        self.setpoints.end(stream)
        self.backend.follower.finish_stream()
        self._publish_status(self.backend.measured())
