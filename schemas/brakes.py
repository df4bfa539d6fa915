"""Why a robot driver braked an arm or refused a move: one enum, used by the driver that
writes the reason and by every client that acts on it.

A driver's reason (``RobotStatus.fault``, ``TrajectoryAck.reason``, ``StreamAck.reason``, or
the text of a refusal) is free text for the operator (SPEC section 6 fixes the messages, not
their reasons); the ones a client must tell apart begin with a :class:`Brake` value, which
the driver writes through :meth:`Brake.say` and a client reads back with :func:`brake_of`.
Adding a cause is one member here, never a string copied into a client.
"""

from __future__ import annotations

from enum import StrEnum


class Brake(StrEnum):
    """A cause of a brake or a refused move; the value is the reason's first words."""

    OPERATOR_STOP = "stop requested on"
    """an operator (or a supervisor) published on the stop key: the arm braked"""
    SENT_BEFORE_STOP = "received before the stop requested on"
    """a move or stream sent before the last stop: refused"""
    HEARTBEAT_LOST = "planner heartbeat lost"
    """the session that moves the arm went silent for longer than the timeout: braked"""
    NO_PLANNER = "no planner alive (watchdog)"
    """no planner heartbeat at all: moves refused, shown as the status's fault"""
    SESSION_SILENT = "no heartbeat from planner session"
    """the move's session was not heard within the timeout: refused"""

    def say(self, detail: str = "") -> str:
        """The reason text: this cause's words followed by ``detail`` (with its own leading
        space or colon)."""
        return self.value + detail

    @property
    def late_heartbeat(self) -> bool:
        """Heartbeats came late (no fault of the move: a loaded machine, a restarted
        planner); the move may be made again once the arm rests."""
        return self in (Brake.HEARTBEAT_LOST, Brake.NO_PLANNER, Brake.SESSION_SILENT)


def brake_of(reason: str | None) -> Brake | None:
    """The :class:`Brake` a driver's reason begins with (None: another reason, or none).
    The longest matching value wins, so a cause whose words begin another's is not taken
    for it."""
    if not reason:
        return None
    text = reason.lstrip()
    found = [b for b in Brake if text.startswith(b.value)]
    return max(found, key=lambda b: len(b.value)) if found else None
