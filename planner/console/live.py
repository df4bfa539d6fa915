"""What the console sees on the bus: the latest of every stream, thread safe.

:class:`LiveState` subscribes, on one Zenoh session, to the public topics of docs/conventions.md section 6:
``camera/points`` (kept raw; decoded by the drawing loop), ``camera/spot``, every robot's
``joint_states`` and ``status``, the laser gate ``<prefix>/laser``, the planner's
``heartbeat`` and the liveliness tokens ``alive/**``. Callbacks only store; bodies that do
not validate are counted and dropped (the console keeps showing the last good state). Times
are the receiver's monotonic clock (s).
"""

from __future__ import annotations

import bisect
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from planner.bus.session import Keys, decode, update_alive
from planner.errors import InputError
from planner.model.transforms import Array
from schemas.messages import Heartbeat, JointState, LaserState, RobotStatus, SpotMessage

#: a stream silent for longer than this (s) is shown as stale
STALE_AFTER = 0.5
#: s over which a stream's rate is counted: a window of time, not of samples, so a burst of
#: queued messages arriving together (30 heartbeats in 23 ms once read 1275 Hz) does not
#: read as a rate
RATE_WINDOW = 1.0
#: arrivals kept per stream (a 500 Hz joint-state stream fills RATE_WINDOW with 500)
RATE_SAMPLES = 2000


@dataclass
class Stamped:
    """A value and when it arrived (monotonic s)."""

    value: Any
    at: float


@dataclass
class LiveState:
    """Latest bus state (see the module docstring). Use :meth:`subscribe` once."""

    keys: Keys
    points: Stamped | None = None  # (payload, attachment)
    spot: Stamped | None = None  # SpotMessage
    joints: dict[str, Stamped] = field(default_factory=dict)  # robot -> JointState
    status: dict[str, Stamped] = field(default_factory=dict)  # robot -> RobotStatus
    laser: Stamped | None = None  # LaserState
    heartbeat: Stamped | None = None  # Heartbeat
    alive: set[str] = field(default_factory=set)
    last_fault: Stamped | None = None  # (robot, fault): the newest fault any driver reported
    rejected: int = 0
    points_seq: int = 0
    clock: Callable[[], float] = time.monotonic
    _arrivals: dict[str, deque[float]] = field(default_factory=dict)
    _first: dict[str, float] = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock)
    _subs: list[Any] = field(default_factory=list)

    def subscribe(self, session: Any) -> None:
        """Declare the subscribers on ``session``."""
        k = self.keys
        self._subs = [
            session.declare_subscriber(k.camera_points, self._on_points),
            session.declare_subscriber(k.camera_spot, self._on_spot),
            session.declare_subscriber(k.joint_states("*"), self._on_joints),
            session.declare_subscriber(k.status("*"), self._on_status),
            session.declare_subscriber(k.laser, self._on_laser),
            session.declare_subscriber(k.heartbeat, self._on_heartbeat),
            session.liveliness().declare_subscriber(k.alive_all, self._on_alive, history=True),
        ]

    def close(self) -> None:
        for s in self._subs:
            s.undeclare()
        self._subs.clear()

    # callbacks ------------------------------------------------------------------------------
    def _tick(self, name: str) -> float:
        now = self.clock()
        q = self._arrivals.setdefault(name, deque(maxlen=RATE_SAMPLES))
        self._first.setdefault(name, now)
        q.append(now)
        return now

    def _on_points(self, sample: Any) -> None:
        att = sample.attachment
        if att is None:
            self.rejected += 1
            return
        body = (sample.payload.to_bytes(), att.to_bytes())
        with self._lock:
            self.points = Stamped(body, self._tick("points"))
            self.points_seq += 1

    def _decode(self, sample: Any, cls: Any) -> Any:
        try:
            return decode(sample.payload.to_bytes(), cls)
        except InputError:
            self.rejected += 1
            return None

    def _on_spot(self, sample: Any) -> None:
        if (m := self._decode(sample, SpotMessage)) is not None:
            with self._lock:
                self.spot = Stamped(m, self._tick("spot"))

    def _on_joints(self, sample: Any) -> None:
        robot = str(sample.key_expr).split("/")[-2]
        if (m := self._decode(sample, JointState)) is not None:
            with self._lock:
                self.joints[robot] = Stamped(m, self._tick(f"joints/{robot}"))

    def _on_status(self, sample: Any) -> None:
        robot = str(sample.key_expr).split("/")[-2]
        if (m := self._decode(sample, RobotStatus)) is not None:
            fault = "protective stop" if m.protective_stop else m.fault
            with self._lock:
                now = self.clock()
                self.status[robot] = Stamped(m, now)
                last = self.last_fault
                if fault and (last is None or last.value != (robot, fault)):
                    self.last_fault = Stamped((robot, fault), now)

    def _on_laser(self, sample: Any) -> None:
        if (m := self._decode(sample, LaserState)) is not None:
            with self._lock:
                self.laser = Stamped(m, self.clock())

    def _on_heartbeat(self, sample: Any) -> None:
        if (m := self._decode(sample, Heartbeat)) is not None:
            with self._lock:
                self.heartbeat = Stamped(m, self._tick("heartbeat"))

    def _on_alive(self, sample: Any) -> None:
        update_alive(self.alive, self._lock, sample)

    # readers ----------------------------------------------------------------------------
    def rate(self, name: str) -> float:
        """Arrivals per second of stream ``name`` (``points``, ``spot``, ``heartbeat``,
        ``joints/<robot>``): those of the last :data:`RATE_WINDOW` s over the window (over
        the time since the first arrival while the stream is younger); 0 when stale."""
        with self._lock:
            q = self._arrivals.get(name)
            now = self.clock()
            if not q or len(q) < 2 or now - q[-1] > STALE_AFTER:
                return 0.0
            age = now - self._first[name]
            if age < RATE_WINDOW:
                return (len(q) - 1) / max(q[-1] - q[0], 1e-9)
            return (len(q) - bisect.bisect_right(q, now - RATE_WINDOW)) / RATE_WINDOW

    def joint_vector(self, robots: tuple[str, ...]) -> dict[str, Array] | None:
        """Latest q (rad) of every robot in ``robots``, or None until all have reported."""
        with self._lock:
            if not all(r in self.joints for r in robots):
                return None
            return {r: np.asarray(self.joints[r].value.q, dtype=float) for r in robots}

    def joint_states(self) -> dict[str, Stamped]:
        """The latest JointState of every robot that reported (a copy of the mapping)."""
        with self._lock:
            return dict(self.joints)

    def snapshot(self) -> dict[str, Any]:
        """A consistent copy of the scalar state for the health panel."""
        with self._lock:
            return {
                "alive": sorted(self.alive),
                "spot": self.spot,
                "status": dict(self.status),
                "laser": self.laser,
                "heartbeat": self.heartbeat,
                "last_fault": self.last_fault,
                "rejected": self.rejected,
            }

    def take_points(self, since_seq: int) -> tuple[int, tuple[bytes, bytes] | None]:
        """The newest raw cloud if newer than ``since_seq``: (seq, (payload, attachment))."""
        with self._lock:
            if self.points is None or self.points_seq == since_seq:
                return self.points_seq, None
            return self.points_seq, self.points.value
