"""A fake monotonic clock for the timing logic that takes a ``clock`` (and a ``sleep``).

The code under test reads ``clock()`` (s) and waits with ``sleep(s)``; a test passes a
:class:`FakeClock` for both, steps it with :meth:`FakeClock.advance` (or sets ``t``), and
asserts exact times: nothing here waits on the wall clock.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable


class FakeClock:
    """A settable monotonic clock (s): ``clock()`` reads it, ``clock.sleep(s)`` advances it
    (and records the request in ``slept``)."""

    def __init__(self, t: float = 1000.0) -> None:
        self.t = t
        self.slept: list[float] = []

    def __call__(self) -> float:
        return self.t

    def advance(self, seconds: float) -> float:
        """Move the clock on by ``seconds``; the new time."""
        self.t += seconds
        return self.t

    def sleep(self, seconds: float) -> None:
        """A ``time.sleep`` that takes no wall time: the clock moves on by ``seconds``."""
        self.slept.append(seconds)
        self.t += max(0.0, seconds)


class Timeline(FakeClock):
    """A :class:`FakeClock` with events: ``at(t, fn)`` runs ``fn()`` when the clock passes
    ``t``. :meth:`wait` (a ``wait(s) -> stopped`` for the code under test) moves the clock
    on, running the events due in time order, and returns early, True, at the event after
    which ``stopped()`` holds."""

    def __init__(self, t: float = 1000.0, stopped: Callable[[], bool] = lambda: False) -> None:
        super().__init__(t)
        self.stopped = stopped
        self._events: list[tuple[float, int, Callable[[], None]]] = []
        self._n = 0

    def at(self, t: float, fn: Callable[[], None]) -> None:
        heapq.heappush(self._events, (t, self._n, fn))
        self._n += 1

    def wait(self, seconds: float) -> bool:
        end = self.t + max(0.0, seconds)
        while self._events and self._events[0][0] <= end:
            t, _, fn = heapq.heappop(self._events)
            self.t = max(self.t, t)
            fn()
            if self.stopped():
                return True
        self.t = end
        return self.stopped()

    def run_all(self) -> None:
        """Run every pending event (the clock ends at the last one)."""
        while self._events:
            t, _, fn = heapq.heappop(self._events)
            self.t = max(self.t, t)
            fn()
