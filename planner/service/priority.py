"""Best-effort CPU priority for the processes whose timing keeps the arm safe.

A robot driver brakes when the planner's heartbeat is silent for 100 ms, and its control
loop must run every period. On a loaded machine (a browser rendering in software, a
solver) the scheduler may leave either waiting for longer than that: the arm then stops
although nothing failed. The robot drivers and the heartbeat process therefore ask for a
lower nice value (more CPU under load) when they start, before they start threads (on
Linux the nice value is per thread and new threads inherit it). Raising priority needs root
or CAP_SYS_NICE; without it they run as they are, and say so.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

#: the nice value the timing-critical processes ask for (0 is the default, -20 the highest)
TIMING_NICE = -10


def raise_priority(nice: int = TIMING_NICE) -> int | None:
    """Lower the calling thread's (at start: the process's) nice value to ``nice``; the
    value it runs at then, or None when that was not permitted (it runs as it was)."""
    try:
        current = os.getpriority(os.PRIO_PROCESS, 0)
        if current <= nice:
            return current
        os.setpriority(os.PRIO_PROCESS, 0, nice)
        return nice
    except (OSError, AttributeError):  # not permitted; no setpriority on this platform
        return None


def priority_note(nice: int | None) -> str:
    """One log line on the outcome of :func:`raise_priority`."""
    if nice is None:
        return "priority: not raised (needs root or CAP_SYS_NICE); late heartbeats may brake a loaded machine"
    return f"priority: nice {nice}"


@contextlib.contextmanager
def raised_priority(nice: int = TIMING_NICE) -> Iterator[int | None]:
    """:func:`raise_priority` for the threads started inside (a Zenoh session's routing
    threads), the calling thread back at its nice value after (the children it spawns later
    do not inherit the raise)."""
    before = os.getpriority(os.PRIO_PROCESS, 0)
    got = raise_priority(nice)
    try:
        yield got
    finally:
        if got is not None and got != before:
            with contextlib.suppress(OSError):
                os.setpriority(os.PRIO_PROCESS, 0, before)
