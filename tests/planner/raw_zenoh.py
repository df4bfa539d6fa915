"""An outside client: plain ``zenoh`` calls only, sharing no code with planner.bus.session/client."""

from __future__ import annotations

import json
import threading
import time
from typing import Any

import zenoh


def raw_session(endpoint: str) -> Any:
    """A peer session connected to ``endpoint`` (loopback, no scouting)."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps(["tcp/127.0.0.1:0"]))
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    return zenoh.open(conf)


def ask(session: Any, key: str, body: bytes, timeout: float = 20.0) -> tuple[bool, bytes]:
    """Query ``key`` with ``body``: (ok, reply body); AssertionError if nobody answers."""
    for reply in session.get(key, payload=body, timeout=timeout):
        if reply.ok is not None:
            return True, reply.ok.payload.to_bytes()
        return False, reply.err.payload.to_bytes()
    raise AssertionError(f"no reply on {key} within {timeout} s")


def token_exists(session: Any, key: str) -> bool:
    """Whether a liveliness token ``key`` is declared on the bus right now."""
    replies = list(session.liveliness().get(key, timeout=1.0))
    return any(r.ok is not None for r in replies)


class Inbox:
    """Every sample on one key expression: (receiver monotonic time, parsed JSON or raw)."""

    def __init__(self, session: Any, key: str) -> None:
        self.items: list[tuple[float, Any]] = []
        self._lock = threading.Lock()
        self._sub = session.declare_subscriber(key, self._cb)

    def _cb(self, sample: Any) -> None:
        raw = sample.payload.to_bytes()
        try:
            body: Any = json.loads(raw)
        except ValueError:
            body = raw
        with self._lock:
            self.items.append((time.monotonic(), body))

    def bodies(self) -> list[Any]:
        with self._lock:
            return [b for _, b in self.items]

    def times(self) -> list[float]:
        with self._lock:
            return [t for t, _ in self.items]

    def close(self) -> None:
        self._sub.undeclare()
