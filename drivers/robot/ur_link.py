"""Pieces of the UR backend that deal with the controller link, safety and the operator.

- :class:`AsyncCall`: the RTDE calls that wait for the controller's answer (``servoStop``,
  ``setWatchdog``, ``reuploadScript``, ``disconnect``: ur_rtde's ``sendCommand`` polls the
  script state for up to 300 s, and does so forever on a dead link) run in a helper thread;
  the control loop polls the outcome and never waits more than a given timeout.
- :data:`SAFETY_MODES`: the controller's safety mode (``getSafetyMode()``) by number.
- :class:`RateLimitedLog`: one stderr line per distinct message at most every ``every`` s,
  with the count of repeats suppressed in between.
- The operator's recover request: ``<prefix>/<robot>/recover``, body
  ``{"schema": "beamrelay.recover/1", "robot": <robot>, "t": <UNIX s>, "operator": <text>}``
  (:func:`recover_key`, :func:`recover_body`; read by :func:`schemas.messages.parse_recover`).
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable
from typing import Any, TextIO

from schemas.messages import RecoverRequest

#: UR safety modes (``getSafetyMode()``); 1 and 2 allow motion
SAFETY_MODES = {
    1: "normal",
    2: "reduced",
    3: "protective stop",
    4: "recovery",
    5: "safeguard stop",
    6: "system emergency stop",
    7: "robot emergency stop",
    8: "violation",
    9: "fault",
    10: "validate joint id",
    11: "undefined safety mode",
    12: "automatic mode safeguard stop",
    13: "three-position enabling stop",
}
MOTION_ALLOWED = (1, 2)


def safety_name(mode: int) -> str:
    return SAFETY_MODES.get(int(mode), f"safety mode {int(mode)}")


class AsyncCall:
    """At most one blocking RTDE call at a time, in a daemon thread.

    :meth:`start` begins ``fn()``; :meth:`poll` returns ``None`` while it runs, then
    ``(ok, detail)`` once (``ok`` = the call returned something other than ``False`` without
    raising). A call running longer than ``timeout`` s is reported as failed and abandoned
    (the thread stays blocked in ur_rtde; :attr:`stuck` says so and no new call starts).
    """

    def __init__(self) -> None:
        self.name: str | None = None
        self.stuck = False
        self._thread: threading.Thread | None = None
        self._result: tuple[bool, str] | None = None
        self._deadline = 0.0

    @property
    def busy(self) -> bool:
        return self.name is not None

    def start(self, name: str, fn: Callable[[], Any], timeout: float) -> bool:
        """Begin ``fn`` unless a call is pending or stuck; whether it started."""
        if self.busy or self.stuck:
            return False
        self.name, self._result = name, None
        self._deadline = time.monotonic() + timeout

        def run() -> None:
            try:
                out = fn()
                self._result = (out is not False, "" if out is not False else "returned False")
            except Exception as exc:  # ur_rtde raises RuntimeError on a broken link
                self._result = (False, f"{type(exc).__name__}: {exc}")

        self._thread = threading.Thread(target=run, name=f"rtde-{name}", daemon=True)
        self._thread.start()
        return True

    def poll(self) -> tuple[str, bool, str] | None:
        """``(name, ok, detail)`` once the call ended or timed out, else None."""
        if self.stuck and self._thread is not None and not self._thread.is_alive():
            self.stuck = False  # the abandoned call returned at last (the link came back)
        if self.name is None:
            return None
        name = self.name
        if self._result is not None:
            ok, detail = self._result
            self.name = None
            return name, ok, detail
        if time.monotonic() > self._deadline:
            self.name, self.stuck = None, True
            return name, False, "no answer from the controller (call abandoned)"
        return None

    def wait(self, timeout: float) -> tuple[str, bool, str] | None:
        """Block at most ``timeout`` s for the pending call (shutdown only)."""
        end = time.monotonic() + timeout
        while self.busy and time.monotonic() < end:
            if (out := self.poll()) is not None:
                return out
            time.sleep(0.002)
        return self.poll()


class RateLimitedLog:
    """Print each distinct message at most once every ``every`` s (with the repeat count)."""

    def __init__(self, prefix: str, every: float = 5.0, stream: TextIO | None = None) -> None:
        self.prefix = prefix
        self.every = every
        self.stream = stream
        self._last: dict[str, tuple[float, int]] = {}  # message -> (time printed, suppressed)
        self.printed = 0

    def __call__(self, message: str, key: str | None = None) -> None:
        """Print ``message`` unless one with the same ``key`` (default: the message) was
        printed within ``every`` s."""
        now, key = time.monotonic(), key or message
        t, n = self._last.get(key, (-float("inf"), 0))
        if now - t < self.every:
            self._last[key] = (t, n + 1)
            return
        more = f" (repeated {n} times)" if n else ""
        print(f"{self.prefix}: {message}{more}", file=self.stream or sys.stderr, flush=True)
        self.printed += 1
        self._last[key] = (now, 0)
        if len(self._last) > 256:  # forget the oldest
            del self._last[min(self._last, key=lambda k: self._last[k][0])]


def recover_key(prefix: str, robot: str) -> str:
    return f"{prefix}/{robot}/recover"


def recover_body(robot: str, operator: str = "") -> bytes:
    """The :class:`~schemas.messages.RecoverRequest` body asking ``robot`` to recover."""
    body = RecoverRequest(robot=robot, t=time.time(), operator=operator[:200])
    return body.model_dump_json(by_alias=True).encode()
