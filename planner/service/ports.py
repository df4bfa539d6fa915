"""What the closed loop and the start of tracking use of the planner node: typed ports.

:func:`planner.service.closed_loop.execute_on_node` and
:func:`planner.service.track_start.start_track` take the node through these protocols
rather than as ``Any``: a stand-in for a test (or another node) provides these attributes
and nothing else. :class:`planner.service.node.PlannerNode` provides both.
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:  # types only: the node's parts import the closed loop and the tracking
    from planner.bus.session import Keys
    from planner.service.execution import JointCache
    from planner.service.guard import Progress
    from planner.service.handler import RequestHandler
    from planner.service.spots import LaserLog, SpotBuffer
    from planner.service.stream import Execution
    from planner.service.track import TrackSession
    from planner.track.follow import TrackSettings


class ClosedLoopPort(Protocol):
    """The node as the closed loop uses it: its execution (moves sent to the drivers), the
    robots' joints, the spots and laser states it has seen, the stop it has seen, the bus
    session with its keys and its own session id, and its progress tick."""

    execution: Execution
    joints: JointCache
    spots: SpotBuffer
    laser: LaserLog
    stop_seen: threading.Event
    session: Any  # a zenoh.Session (or the tests' fake of one)
    keys: Keys
    session_id: str
    progress: Progress


class TrackPort(ClosedLoopPort, Protocol):
    """The node as the start of tracking uses it: the closed loop's port, its request
    handler, the running track session and its settings, and its driver check, stop and
    end-of-tracking report."""

    handler: RequestHandler
    track: TrackSession | None
    track_settings: TrackSettings | None

    def check_drivers(self) -> None: ...

    def send_stop(self, reason: str) -> None: ...

    def track_ended(self, summary: dict[str, Any]) -> None: ...
