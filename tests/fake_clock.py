"""A fake monotonic clock for the timing logic that takes a ``clock`` (and a ``sleep``).

The code under test reads ``clock()`` (s) and waits with ``sleep(s)``; a test passes a
:class:`FakeClock` for both, steps it with :meth:`FakeClock.advance` (or sets ``t``), and
asserts exact times: nothing here waits on the wall clock.
"""

from __future__ import annotations


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
