"""What the planner node knows about the robots it moves (no Zenoh here).

- :class:`JointCache`: the latest ``joint_states`` per robot (receiver clock; its
  :meth:`~JointCache.callback` feeds it from the bus).
- :class:`MotionTracks`: per robot, the last trajectory its driver accepted: final joints
  (rad) and when it ends (monotonic clock, s). A driver queues a trajectory that arrives
  while another one runs if it starts where the running one ends, so the node plans from
  that final state while the trajectory still runs, and from ``joint_states`` afterwards.
- :class:`AckBoard`: the drivers' verdicts (:class:`~schemas.messages.TrajectoryAck`, carried
  by their ``status``) on the trajectories of one request id.

plan.json ``trajectory`` -> one JointTrajectory per robot, and its chunks for execution, are
:mod:`planner.service.stream`'s.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from planner.bus.ids import base_id
from planner.bus.session import decode_sample
from planner.errors import BeamrelayError
from planner.io.plan import Verdict
from planner.model.transforms import Array
from schemas.messages import JointState

log = logging.getLogger("beamrelay.node")

#: a joint state older than this (s, receiver clock) does not count as "current"
STATE_MAX_AGE = 0.5
#: how long (s) the node waits for every driver's verdict on an executed trajectory
ACK_TIMEOUT = 2.0
#: time (s) added to a trajectory's duration for the driver's approach and settle phases
TRACK_MARGIN = 1.0
#: a robot within AT_Q rad (every joint) of a commanded configuration, slower than REST_QD
#: rad/s, rests there (the closed loop's measurements wait for it)
AT_Q = 1e-4
REST_QD = 1e-3
#: status modes after which a robot is no longer where its last trajectory ends
HALTED_MODES = frozenset({"braking", "stopped", "fault"})


class ExecuteError(BeamrelayError):
    """``execute`` refused: a driver is down or its joint state is missing/stale.

    ``robots`` names the robots concerned.
    """

    def __init__(self, reason: str, robots: list[str]) -> None:
        self.reason = reason
        self.robots = robots
        super().__init__(reason)


@dataclass
class JointCache:
    """Latest joint state per robot (receiver clock), thread safe."""

    names: tuple[str, ...]
    _q: dict[str, tuple[float, Array, Array]] = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def update(self, robot: str, q: Array, qd: Array) -> None:
        with self._lock:
            self._q[robot] = (time.monotonic(), q, qd)

    def get(self, robot: str) -> tuple[float, Array, Array] | None:
        with self._lock:
            return self._q.get(robot)

    def callback(self, robot: str, nq: int) -> Callable[[Any], None]:
        """Subscriber callback of ``robot``'s ``joint_states``: a state with ``nq`` joints is
        kept, any other body dropped (one that does not decode is logged)."""

        def cb(sample: Any) -> None:
            msg = decode_sample(sample, JointState, log, f"joint state from {robot}")
            if msg is None:
                return
            q, qd = np.asarray(msg.q), np.asarray(msg.qd)
            if q.shape == (nq,):
                self.update(robot, q, qd)

        return cb

    def current(
        self, max_age: float = STATE_MAX_AGE, robots: tuple[str, ...] | None = None
    ) -> dict[str, Array]:
        """``{robot: q}`` (rad) for ``robots`` (default all), or ExecuteError naming the
        missing/stale ones."""
        now = time.monotonic()
        out, missing = {}, []
        for name in self.names if robots is None else robots:
            entry = self.get(name)
            if entry is None or now - entry[0] > max_age:
                missing.append(name)
            else:
                out[name] = entry[1]
        if missing:
            raise ExecuteError(
                f"no current joint state from {', '.join(missing)} "
                f"(none received in the last {max_age:g} s)",
                missing,
            )
        return out

    def rests_at(self, q: dict[str, Array], at_q: float = AT_Q, rest_qd: float = REST_QD,
                 max_age: float = STATE_MAX_AGE) -> bool:  # fmt: skip
        """Whether every robot of ``q`` (rad) has a joint state younger than ``max_age`` s
        within ``at_q`` rad of it (every joint) and slower than ``rest_qd`` rad/s."""
        now = time.monotonic()
        for robot, q_r in q.items():
            entry = self.get(robot)
            if entry is None or now - entry[0] > max_age:
                return False
            _, q_now, qd_now = entry
            if np.max(np.abs(q_now - q_r)) >= at_q or np.max(np.abs(qd_now)) >= rest_qd:
                return False
        return True


@dataclass(frozen=True)
class Track:
    """A trajectory a driver accepted: request ``id``, final joints ``q_end`` (rad), and
    ``end`` (monotonic s) when it finishes playing, not counting the driver's margin."""

    id: str
    q_end: Array
    end: float


@dataclass
class MotionTracks:
    """The last accepted trajectory per robot; thread safe. ``margin`` (s) covers the
    driver's approach and settle around the nominal duration."""

    margin: float = TRACK_MARGIN
    _tracks: dict[str, Track] = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def accepted(self, robot: str, request_id: str, q_end: Array, duration: float) -> float:
        """Record an accepted trajectory of ``duration`` s: it starts now, or when the one
        still running ends (the driver queues it). Returns that start (monotonic s)."""
        now = time.monotonic()
        with self._lock:
            prev = self._tracks.get(robot)
            begin = now if prev is None or prev.end + self.margin <= now else max(now, prev.end)
            self._tracks[robot] = Track(request_id, np.asarray(q_end, float), begin + duration)
        return begin

    def running_end(self, robot: str) -> Array | None:
        """Final joints (rad) of the robot's trajectory while it may still run, else None."""
        with self._lock:
            track = self._tracks.get(robot)
        if track is None or track.end + self.margin <= time.monotonic():
            return None
        return track.q_end

    def halted(self, robot: str, trajectory_id: str | None) -> bool:
        """The robot stopped (braking, protective stop, fault) while its status names the
        trajectory ``trajectory_id`` (None: no trajectory; a chunk id counts for its
        request): forget where it was going. True if that trajectory may still have been
        running (the robots move only together: the caller stops them all)."""
        with self._lock:
            track = self._tracks.get(robot)
            if track is None or base_id(trajectory_id) not in (None, track.id):
                return False
            del self._tracks[robot]
            return track.end + self.margin > time.monotonic()

    def clear(self) -> None:
        """Forget every trajectory (a stop was sent on the bus)."""
        with self._lock:
            self._tracks.clear()


@dataclass
class AckBoard:
    """Drivers' verdicts on the trajectories of the request being executed; thread safe."""

    _want: dict[str, str | None] = field(default_factory=dict)
    _got: dict[str, Any] = field(default_factory=dict)
    _cond: threading.Condition = field(default_factory=threading.Condition)

    def expect(self, robots: list[str], request_id: str | None) -> None:
        """Start collecting verdicts on ``request_id`` (call before publishing)."""
        with self._cond:
            self._want = dict.fromkeys(robots, request_id)
            self._got = {}

    def offer(self, robot: str, ack: Any) -> None:
        """A :class:`~schemas.messages.TrajectoryAck` seen in ``robot``'s status."""
        with self._cond:
            if self._want.get(robot) == ack.id and robot not in self._got:
                self._got[robot] = ack
                self._cond.notify_all()

    def wait(self, timeout: float) -> dict[str, Any]:
        """``{robot: TrajectoryAck | None}`` (None: no verdict within ``timeout`` s)."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while len(self._got) < len(self._want):
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self._cond.wait(left)
            out = {robot: self._got.get(robot) for robot in self._want}
            self._want, self._got = {}, {}
        return out


def start_state(
    robots: tuple[str, ...], tracks: MotionTracks, joints: JointCache
) -> dict[str, Array]:
    """Where each of ``robots`` will be when a trajectory sent now starts (rad): the end of
    the trajectory it still plays (``tracks``), else its latest joint state (ExecuteError if
    stale)."""
    start = {}
    for robot in robots:
        q_end = tracks.running_end(robot)
        if q_end is not None:
            start[robot] = q_end
    rest = tuple(r for r in robots if r not in start)
    return start | (joints.current(robots=rest) if rest else {})


def execution_verdict(acks: dict[str, Any], timeout: float) -> tuple[Verdict, str | None]:
    """(accepted | rejected, reason naming each robot that did not accept)."""
    reasons = []
    for robot, ack in acks.items():
        if ack is None:
            reasons.append(f"no answer from {robot} within {timeout:g} s")
        elif not ack.accepted:
            reasons.append(f"{robot}: {ack.reason or 'rejected without a reason'}")
    return (Verdict.REJECTED, "; ".join(reasons)) if reasons else (Verdict.ACCEPTED, None)
