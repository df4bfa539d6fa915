"""Setpoint intake: the Zenoh callback side of a robot driver's setpoint streams.

Every sample on ``<prefix>/<robot>/setpoint`` goes through :meth:`SetpointIntake.submit`
(the robot node calls it from its control loop for the samples Zenoh queued since the
last period): parsed and checked at once (:mod:`drivers.robot.setpoint_check`,
tens of microseconds; nothing waits for it), then classified into *streams*, in arrival order:

- a stream is identified by its (``session``, ``id``); its setpoints must continue each other
  (:func:`~drivers.robot.setpoint_check.check_next`: ``t``/``seq`` increase, velocity and
  acceleration limits between consecutive setpoints);
- a setpoint that fails a check, any body that does not parse, and a setpoint of another
  stream while one is open are *rejected* and end the open stream (the control loop brakes);
- an open stream whose last setpoint is older than
  :data:`~drivers.robot.setpoint_check.STALE_AFTER` (50 ms, receive clock) is ended;
- once a stream has ended (rejected here, or ended by the control loop with :meth:`end`:
  stale, stop, heartbeat loss, a trajectory), further setpoints of the same (session, id)
  are *ignored* until they pause for 50 ms: a sender that keeps streaming after a stop or a
  rejection does not restart the arm. After such a pause, or with another (session, id),
  the next setpoint starts a new stream (judged by the control loop against the arm's state).

The control loop takes the :class:`StreamEvent` objects with :meth:`take` (a pointer swap
under a lock). Consecutive ``next`` events of one stream are coalesced (only the newest
setpoint matters to the loop; the checks already saw every one), so the list stays short;
at most :data:`MAX_EVENTS` wait: beyond that no stream is started (its setpoints are
ignored) and rejections are dropped, except the one that ends a stream the loop knows of
(so at most ``2 MAX_EVENTS`` events wait).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any, NamedTuple

from drivers.robot.outbox import Outbox
from drivers.robot.setpoint_check import STALE_AFTER, SetpointSample, check_next, parse_setpoint
from planner.errors import InputError
from planner.model.system import Limits

MAX_EVENTS = 64  # events waiting for the control loop
MAX_ENDED = 64  # ended streams remembered (for ignoring their late setpoints)
MAX_REASON = 400  # characters of an unexpected error's text kept in a rejection


class StreamEvent(NamedTuple):
    """What the loop learns: ``kind`` ``start`` (first setpoint of stream number ``stream``),
    ``next`` (its newest checked setpoint) or ``rejected`` (``reason``; ``stream`` is the
    open stream this ends, 0 when none was open); ``received`` monotonic s."""

    kind: str
    stream: int
    sample: SetpointSample | None
    reason: str | None
    received: float


class SetpointIntake:
    """Parses, checks and classifies setpoints for one robot (see the module docstring)."""

    def __init__(
        self,
        robot: str,
        names: tuple[str, ...],
        limits: Limits,
        *,
        clock: Callable[[], float] = time.monotonic,
        stale_after: float = STALE_AFTER,
    ) -> None:
        self.robot, self.names, self.limits = robot, tuple(names), limits
        self.clock, self.stale_after = clock, stale_after
        self._lock = threading.Lock()
        self._events: Outbox[StreamEvent] = Outbox(self._lock)
        self._stream = 0  # number of the latest stream started
        self._open: SetpointSample | None = None  # last setpoint of the open stream
        self._ended: dict[tuple[str, str | None], float] = {}  # key -> last receipt
        self.n_received = 0
        self.n_rejected = 0
        self.n_ignored = 0
        self.n_dropped = 0

    # -- producer side (Zenoh callback thread) ----------------------------------------------
    def submit(self, payload: Any) -> None:
        """One received payload (``zenoh.ZBytes`` or bytes); never raises."""
        received = self.clock()
        self.n_received += 1
        try:
            body = payload if isinstance(payload, bytes) else _bytes(payload)
            sample = parse_setpoint(body, received, self.robot, self.names, self.limits)
        except InputError as exc:
            self._reject(str(exc), received)
            return
        except Exception as exc:  # hostile payloads must never kill the callback
            self._reject(f"body: {type(exc).__name__}: {str(exc)[:MAX_REASON]}", received)
            return
        with self._lock:
            self._classify(sample)

    def _classify(self, s: SetpointSample) -> None:
        """Continue the open stream, ignore a late setpoint of an ended one, or start one."""
        opened = self._open
        if opened is not None and s.received - opened.received > self.stale_after:
            self._close(opened, opened.received)
            opened = None
        if opened is not None:
            if s.key != opened.key:
                self._ended[s.key] = s.received  # both senders must pause
                self._end_open(f"session: setpoint of stream {_name(s.key)} while stream "
                               f"{_name(opened.key)} is followed", s.received)  # fmt: skip
                return
            try:
                s = check_next(opened, s, self.names, self.limits)
            except InputError as exc:
                self._end_open(str(exc), s.received)
                return
            self._open = s
            self._push(StreamEvent("next", self._stream, s, None, s.received))
            return
        last = self._ended.get(s.key)
        if last is not None and s.received - last <= self.stale_after:
            self._ended[s.key] = s.received
            self.n_ignored += 1
            return
        if len(self._events.items) >= MAX_EVENTS:  # the loop is not taking: never open one it
            self.n_dropped += 1  # cannot know of (its setpoints are ignored for 50 ms)
            self._close(s, s.received)
            return
        self._ended.pop(s.key, None)
        self._stream += 1
        self._open = s._replace(qdd=s.qd * 0.0)
        self._push(StreamEvent("start", self._stream, self._open, None, s.received))

    def _reject(self, reason: str, received: float) -> None:
        with self._lock:
            self._end_open(reason, received)

    def _end_open(self, reason: str, received: float) -> None:
        """Reject (lock held): ends the open stream, if one is."""
        self.n_rejected += 1
        stream = 0
        if self._open is not None:
            stream = self._stream
            self._close(self._open, received)
        self._push(StreamEvent("rejected", stream, None, reason, received))

    def _close(self, last: SetpointSample, at: float) -> None:
        self._open = None
        ended = self._ended
        if len(ended) >= MAX_ENDED:
            del ended[min(ended, key=ended.__getitem__)]
        ended[last.key] = at

    def _push(self, ev: StreamEvent) -> None:
        events = self._events.items
        last = events[-1] if events else None
        if ev.kind == "next" and last is not None and last[:2] == ("next", ev.stream):
            events[-1] = ev
            return
        if len(events) >= MAX_EVENTS and not (ev.kind == "rejected" and ev.stream):
            self.n_dropped += 1
            return
        events.append(ev)

    # -- consumer side (control loop) -------------------------------------------------------
    def take(self) -> list[StreamEvent]:
        """The events since the last call, oldest first (:meth:`Outbox.take`)."""
        return self._events.take()

    def end(self, stream: int) -> None:
        """The control loop ended stream number ``stream`` (stale, stop, heartbeat loss,
        replaced by a trajectory, start refused): its later setpoints are ignored."""
        with self._lock:
            if stream == self._stream and self._open is not None:
                self._close(self._open, self._open.received)


def _bytes(payload: Any) -> bytes:
    """A Zenoh payload's bytes, refusing an oversized one before copying it."""
    from drivers.robot.setpoint_check import MAX_SETPOINT_BYTES

    size = len(payload)
    if size > MAX_SETPOINT_BYTES:
        raise InputError(f"payload of {size} bytes exceeds {MAX_SETPOINT_BYTES} bytes", "body")
    data: bytes = payload.to_bytes()
    return data


def _name(key: tuple[str, str | None]) -> str:
    session, id_ = key
    return f"session {session} id {id_}" if id_ is not None else f"session {session}"
