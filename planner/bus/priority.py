"""Real-time CPU priority for the threads whose timing keeps the arm safe.

A robot driver brakes when the planner's heartbeat is silent for 100 ms, and its control
loop must run every period. On a loaded machine (a browser rendering in software, a
solver, a test suite) the normal scheduler may leave either waiting longer than that: the
arm then stops although nothing failed, and a lower nice value does not prevent it. The
heartbeat path (the heartbeat process, the Zenoh threads of ``up``'s hub, of each robot
driver and of the planner node, which send its setpoints and stops), the drivers' control
loops and the planner's setpoint streamer therefore ask
for ``SCHED_FIFO`` at :data:`RT_PRIORITY`, per thread: the threads that compute (solvers,
parsers, the camera) stay normal, except that tracking's frame solver (30 Hz, a few ms
each) asks for nice :data:`TIMING_NICE` (a late solve lets the target stream go stale).
Every such thread sleeps each period, so it cannot starve the machine. A Python callback
on a raised Zenoh thread still needs the GIL: the drivers therefore take heartbeats and
setpoints from Zenoh's own queues in the control loop instead of in callbacks.

``SCHED_FIFO`` needs root, ``CAP_SYS_NICE`` or an rtprio limit: ``ulimit -r 15``, or a line
``<user> - rtprio 15`` in ``/etc/security/limits.d/beamrelay.conf`` (then log in again).
Without it the thread asks for nice :data:`TIMING_NICE`, and without that runs as it was;
:attr:`Priority.note` says which, and what to set. ``BEAMRELAY_NO_RT=1`` in the environment
skips ``SCHED_FIFO`` (nice only), to measure what it buys (``beamrelay bench brakes``).

On Linux scheduling policy and nice value are per thread; new threads inherit them.
"""

from __future__ import annotations

import contextlib
import enum
import os
import resource
from collections.abc import Iterator
from dataclasses import dataclass

#: the SCHED_FIFO priority asked for (1-99; ur_rtde's threads run at 70-80 on a real arm)
RT_PRIORITY = 15
#: the nice value asked for when SCHED_FIFO is not permitted (0 default, -20 highest)
TIMING_NICE = -10
#: set to 1 to skip SCHED_FIFO (nice only)
NO_RT_ENV = "BEAMRELAY_NO_RT"


class Policy(enum.Enum):
    FIFO = "SCHED_FIFO"
    NICE = "nice"
    UNCHANGED = "unchanged"


@dataclass(frozen=True)
class Priority:
    """What a thread obtained: ``level`` is the FIFO priority (FIFO) or the nice value;
    ``why`` says why SCHED_FIFO was not obtained (empty when it was)."""

    policy: Policy
    level: int
    why: str = ""

    @property
    def note(self) -> str:
        """One log line: what was obtained and, when not real time, what to set."""
        if self.policy is Policy.FIFO:
            return f"priority: SCHED_FIFO {self.level} (real time)"
        got = f"nice {self.level}" if self.policy is Policy.NICE else "normal (nice not raised)"
        return f"priority: {got}, not real time: {self.why}; late heartbeats may brake a loaded machine"


def rtprio_limit() -> int:
    """The soft RLIMIT_RTPRIO (the highest SCHED_FIFO priority allowed without CAP_SYS_NICE)."""
    soft = resource.getrlimit(resource.RLIMIT_RTPRIO)[0]
    return 99 if soft == resource.RLIM_INFINITY else int(soft)


def _try_fifo(priority: int, reset_on_fork: bool) -> tuple[int | None, str]:
    """SCHED_FIFO for the calling thread at ``priority`` (or the rtprio limit, if lower
    but not 0): the priority obtained, or None and why not."""
    if os.environ.get(NO_RT_ENV, "") not in ("", "0"):
        return None, f"SCHED_FIFO skipped ({NO_RT_ENV} is set)"
    flags = os.SCHED_RESET_ON_FORK if reset_on_fork else 0
    limit = rtprio_limit()
    for p in dict.fromkeys((priority, min(priority, limit))):
        if p < 1:
            continue
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO | flags, os.sched_param(p))
            return p, ""
        except OSError:  # PermissionError: neither CAP_SYS_NICE nor a high enough limit
            continue
    return None, (
        f"SCHED_FIFO not permitted (RLIMIT_RTPRIO {limit}, needs {priority}: run as root, "
        f"or `ulimit -r {priority}`, or '<user> - rtprio {priority}' in /etc/security/limits.d/)"
    )


def raise_priority(
    priority: int = RT_PRIORITY, nice: int = TIMING_NICE, *, reset_on_fork: bool = False
) -> Priority:
    """SCHED_FIFO at ``priority`` for the calling thread, else nice ``nice``, else as it
    was. ``reset_on_fork``: processes (and threads) it starts later begin normal again;
    without it new threads inherit the priority (how a Zenoh runtime is raised)."""
    got, why = _try_fifo(priority, reset_on_fork)
    if got is not None:
        return Priority(Policy.FIFO, got)
    try:
        current = os.getpriority(os.PRIO_PROCESS, 0)
        if current > nice:
            os.setpriority(os.PRIO_PROCESS, 0, nice)
            current = nice
        return Priority(Policy.NICE, current, why)
    except OSError:  # not permitted
        return Priority(Policy.UNCHANGED, os.getpriority(os.PRIO_PROCESS, 0), why)


@contextlib.contextmanager
def raised_priority(priority: int = RT_PRIORITY, nice: int = TIMING_NICE) -> Iterator[Priority]:
    """:func:`raise_priority` for the threads started inside (a Zenoh session's runtime
    threads), the calling thread back at its policy and nice value after (the processes
    and threads it starts later do not inherit the raise)."""
    policy, param = os.sched_getscheduler(0), os.sched_getparam(0)
    before = os.getpriority(os.PRIO_PROCESS, 0)
    try:
        yield raise_priority(priority, nice)
    finally:
        with contextlib.suppress(OSError):
            os.sched_setscheduler(0, policy, param)
        with contextlib.suppress(OSError):
            os.setpriority(os.PRIO_PROCESS, 0, before)
