"""The camera's spot messages as the planner node sees them (no Zenoh here).

:class:`SpotBuffer` keeps the last ``<prefix>/camera/spot`` messages (capture time ``t``,
UNIX s; ``p_camera`` in the camera optical frame, m, or None; ``confidence``) and hands out
the frames captured in a time window, waiting for them: what a closed-loop measurement
averages (:func:`planner.servo.measure.average_frames`). :class:`LaserLog` keeps the laser
gate's on-intervals from ``<prefix>/laser``. Their ``callback`` methods are the node's
subscriber callbacks.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

from planner.bus.session import decode_sample
from planner.servo.measure import SpotFrame
from schemas.messages import LaserState, SpotMessage

log = logging.getLogger("beamrelay.node")

#: frames kept (about 10 s at 30 Hz)
BUFFER_FRAMES = 300
#: how long (s) after a window closes its last frames may still arrive
LATENCY = 0.1


class SpotBuffer:
    """The latest camera spot messages, thread safe."""

    def __init__(self, size: int = BUFFER_FRAMES) -> None:
        self._frames: deque[tuple[float, SpotFrame]] = deque(maxlen=size)
        self._cond = threading.Condition()

    def offer(self, t: float, p_camera: list[float] | None, confidence: float) -> None:
        """One spot message: capture time ``t`` (UNIX s), the spot (camera frame, m) or None."""
        p = None if p_camera is None else np.asarray(p_camera, dtype=float)
        with self._cond:
            self._frames.append((float(t), SpotFrame(p, float(confidence))))
            self._cond.notify_all()

    def callback(self, sample: Any) -> None:
        """Subscriber callback of ``<prefix>/camera/spot``: any body (bad ones are logged)."""

        msg = decode_sample(sample, SpotMessage, log, "spot message")
        if msg is not None:
            self.offer(msg.t, msg.p_camera, msg.confidence)

    def window(self, t0: float, t1: float) -> list[SpotFrame]:
        """Frames captured in ``[t0, t1]`` (UNIX s), oldest first."""
        with self._cond:
            return [f for t, f in self._frames if t0 <= t <= t1]

    def collect(
        self, t0: float, t1: float, n: int, stop: Callable[[], bool],
        latency: float = LATENCY, poll: float = 0.01, *,
        clock: Callable[[], float] = time.time, wait: Callable[[float], object] | None = None,
    ) -> list[SpotFrame]:  # fmt: skip
        """Wait until ``n`` frames captured in ``[t0, t1]`` (UNIX s) are in, ``clock`` (UNIX
        s) passes ``t1`` plus ``latency`` (s, for the last frames' delivery), or ``stop()``;
        the frames of the window (at most ``n``, oldest first). ``wait(s)`` waits between
        looks (None: until the next frame, at most ``poll`` s)."""
        while True:
            got = self.window(t0, t1)
            if len(got) >= n or stop() or clock() > t1 + latency:
                return got[:n]
            _pause(self._cond, poll, wait)


class LaserLog:
    """The laser's lit intervals (treatment gate or aiming beam on) from ``<prefix>/laser``
    (UNIX s, the gate driver's clock), thread safe: a measurement's frames are the ones
    captured while it was lit."""

    def __init__(self, size: int = 64) -> None:
        self._spans: deque[list[float]] = deque(maxlen=size)
        self._on = False
        self._cond = threading.Condition()

    def offer(self, t: float, on: bool) -> None:
        """One gate state message (sent at every switch and with every status)."""
        with self._cond:
            if on and not self._on:
                self._spans.append([float(t), float("inf")])
            elif not on and self._on and self._spans:
                self._spans[-1][1] = float(t)
            self._on = bool(on)
            self._cond.notify_all()

    def callback(self, sample: Any) -> None:
        """Subscriber callback of ``<prefix>/laser``: any body (bad ones are logged)."""

        msg = decode_sample(sample, LaserState, log, "laser state")
        if msg is not None:  # lit: the camera sees a spot (treatment or aiming beam)
            self.offer(msg.t, msg.on or bool(msg.aim))

    def span_after(self, t0: float) -> tuple[float, float] | None:
        """The first on-interval (t_on, t_off; t_off = inf while on) that began at or after
        ``t0`` (UNIX s), or None."""
        with self._cond:
            for a, b in self._spans:
                if a >= t0:
                    return a, b
        return None

    def wait_span(
        self, t0: float, timeout: float, stop: Callable[[], bool], poll: float = 0.01, *,
        clock: Callable[[], float] = time.monotonic,
        wait: Callable[[float], object] | None = None,
    ) -> tuple[float, float] | None:  # fmt: skip
        """Wait (at most ``timeout`` s on ``clock``, or until ``stop()``) for the first
        on-interval that began at or after ``t0`` to end; it, or None when none began or it
        did not end. ``wait(s)`` waits between looks (None: until the next switch, at most
        ``poll`` s)."""
        deadline = clock() + timeout
        while True:
            span = self.span_after(t0)
            if span is not None and np.isfinite(span[1]):
                return span
            if stop() or clock() > deadline:
                return None
            _pause(self._cond, poll, wait)


def _pause(cond: threading.Condition, poll: float, wait: Callable[[float], object] | None) -> None:
    """``wait(poll)``, or (None) until ``cond`` is notified, at most ``poll`` s."""
    if wait is not None:
        wait(poll)
        return
    with cond:
        cond.wait(poll)
