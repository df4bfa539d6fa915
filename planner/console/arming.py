"""Arm, then fire: the console's Execute runs only what the operator armed, shortly after.

*Arm* previews the current target list and shows what Execute will do (targets, motion time,
treatment time with the laser on, and the energy when the scenario gives ``laser.power``).
Execute is then allowed once, within :data:`ARM_WINDOW` s, for exactly that request. Anything
that changes what would happen, or says the system is not healthy, drops the arming: an edit
of the list or of the options, a new driver fault or a protective stop, a silent planner
heartbeat, a STOP, the window running out. A fault a driver still reports from before (the
stop that ended the last motion) does not refuse an arming; a protective stop or a silent
heartbeat does. Pure logic on an injected clock; the page wires it and feeds it
:meth:`Arming.watch` with the faults it sees on the bus.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.io.plan import Plan
from planner.model.status import Status

#: s an arming lasts
ARM_WINDOW = 30.0
#: the fault source of a silent planner heartbeat, and a driver's protective stop
HEARTBEAT = "heartbeat"
PROTECTIVE_STOP = "protective stop"


@dataclass(frozen=True)
class Armed:
    """What one arming allows: the request (without its ``execute`` flag) and its summary."""

    request: str  # canonical JSON of the request's planning content
    at: float  # clock s
    summary: str
    faults: frozenset[tuple[str, str]]  # (source, fault) reported when it was armed


def request_key(request: dict[str, Any]) -> str:
    """The request's content that decides the motion (its id and ``execute`` left out)."""
    content = {k: v for k, v in request.items() if k not in ("id", "execute")}
    return json.dumps(content, sort_keys=True, default=str)


def treatment(plan: Plan, power: float | None) -> str:
    """``N targets, motion T s, laser on L s[, E J]`` of a previewed plan."""
    traj = plan.trajectory
    motion = 0.0 if traj is None else traj.duration
    on = 0.0 if traj is None else float(np.clip(np.diff(traj.laser_on, axis=1), 0.0, None).sum())
    ok = sum(s.status is Status.OK for s in plan.solutions)
    energy = "" if power is None else f", energy {power * on:.3g} J at {power:g} W"
    return (f"{ok}/{len(plan.targets)} targets, motion {motion:.1f} s, treatment laser on "
            f"{on:.2f} s{energy}")  # fmt: skip


@dataclass
class Arming:
    """The page's arming (see the module docstring). ``clock``: monotonic s."""

    clock: Callable[[], float] = time.monotonic
    window: float = ARM_WINDOW
    armed: Armed | None = None
    dropped: str = ""  # why the last arming ended without an Execute

    def arm(self, request: dict[str, Any], summary: str, faults: dict[str, str]) -> Armed | str:
        """Arm ``request`` (``faults``: source -> fault now on the bus, :data:`HEARTBEAT` for
        a silent planner heartbeat); the arming, or why it may not be armed."""
        blocking = "; ".join(f"{k}: {v}" for k, v in sorted(faults.items())
                             if k == HEARTBEAT or v == PROTECTIVE_STOP)  # fmt: skip
        if blocking:
            self.drop(blocking)
            return blocking
        self.armed = Armed(request_key(request), self.clock(), summary,
                           frozenset(faults.items()))  # fmt: skip
        self.dropped = ""
        return self.armed

    def watch(self, faults: dict[str, str]) -> None:
        """Drop the arming when ``faults`` holds one it was not armed with."""
        if self.armed is None:
            return
        new = sorted(set(faults.items()) - self.armed.faults)
        if new:
            self.drop("; ".join(f"{k}: {v}" for k, v in new))

    def remaining(self) -> float:
        """s left of the arming; 0 when not armed (an expired arming is dropped here)."""
        if self.armed is None:
            return 0.0
        left = self.armed.at + self.window - self.clock()
        if left <= 0:
            self.drop(f"the {self.window:.0f} s arming window ran out")
            return 0.0
        return left

    def drop(self, why: str) -> None:
        """End the arming (nothing happens when not armed)."""
        if self.armed is not None:
            self.armed, self.dropped = None, why

    def fire(self, request: dict[str, Any]) -> str | None:
        """Consume the arming for ``request``: None when Execute may go, else why not."""
        if self.remaining() <= 0:
            why = f" ({self.dropped})" if self.dropped else ""
            return f"not armed{why}: press Arm, check what it will do, then Execute"
        assert self.armed is not None
        if request_key(request) != self.armed.request:
            self.drop("the targets or options changed after Arm")
            return "not armed (the targets or options changed after Arm): press Arm again"
        self.armed = None
        return None
