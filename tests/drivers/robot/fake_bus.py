"""An in-process stand-in for a Zenoh session, so a robot node runs on a simulated clock.

:class:`FakeBus` records what the node publishes (decoded JSON per key) and delivers samples
to the node's subscribers synchronously, in the caller's thread. :class:`SimClock` is the
monotonic clock the node reads: tests advance it one control period at a time with
:func:`run`, so staleness and heartbeat timeouts are measured in simulated time.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

from tests.fake_clock import FakeClock as SimClock

__all__ = ["FakeBus", "SimClock"]


class _Payload:
    def __init__(self, data: bytes) -> None:
        self.data = data

    def __len__(self) -> int:
        return len(self.data)

    def to_bytes(self) -> bytes:
        return self.data


class _Sample:
    def __init__(self, data: bytes, kind: Any = None) -> None:
        self.payload = _Payload(data)
        self.kind = kind


class _Handle:
    def __init__(self, undeclare: Callable[[], None] = lambda: None) -> None:
        self.undeclare = undeclare


class _Ring:
    """A subscriber declared with a Zenoh channel handler (``RingChannel``): samples wait in
    a queue of the handler's capacity (the oldest dropped) until :meth:`try_recv`."""

    def __init__(self, capacity: int = 256) -> None:
        import collections

        self.queue: collections.deque[_Sample] = collections.deque(maxlen=capacity)

    def try_recv(self) -> _Sample | None:
        return self.queue.popleft() if self.queue else None

    def undeclare(self) -> None:
        pass


class _Publisher:
    def __init__(self, bus: FakeBus, key: str) -> None:
        self.bus, self.key = bus, key

    def put(self, body: bytes, **_: Any) -> None:
        self.bus.published.setdefault(self.key, []).append(json.loads(body))

    def undeclare(self) -> None:
        pass


class _Liveliness:
    def __init__(self, bus: FakeBus) -> None:
        self.bus = bus

    def declare_subscriber(self, key: str, cb: Callable[[Any], None], history: bool = False) -> Any:
        self.bus.watchers[key] = cb
        return _Handle()

    def declare_token(self, key: str) -> Any:
        return _Handle()


class FakeBus:
    """Duck-typed session: ``declare_publisher``, ``declare_subscriber``, ``liveliness()``."""

    def __init__(self) -> None:
        self.published: dict[str, list[Any]] = {}
        self.subscribers: dict[str, Callable[[Any], None]] = {}
        self.watchers: dict[str, Callable[[Any], None]] = {}

    def declare_publisher(self, key: str, **_: Any) -> _Publisher:
        return _Publisher(self, key)

    def declare_subscriber(self, key: str, handler: Any) -> Any:
        """A callback subscriber (delivered in :meth:`put`'s thread) or, for a Zenoh channel
        handler, a ring the node takes samples from."""
        if callable(handler):
            self.subscribers[key] = handler
            return _Handle()
        ring = _Ring()
        self.subscribers[key] = ring.queue.append
        return ring

    def liveliness(self) -> _Liveliness:
        return _Liveliness(self)

    def put(self, key: str, body: bytes | str) -> None:
        """Deliver one sample to the subscriber of ``key`` (now, in this thread)."""
        data = body.encode() if isinstance(body, str) else body
        self.subscribers[key](_Sample(data))

    def token(self, key: str, alive: bool = True) -> None:
        """A liveliness token ``key`` appears (or goes)."""
        import zenoh

        kind = zenoh.SampleKind.PUT if alive else zenoh.SampleKind.DELETE
        self.watchers[key](_Sample(b"", kind))

    def last(self, key: str) -> Any:
        return self.published[key][-1]
