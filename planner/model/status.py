"""What became of a target: a :class:`Status` and, when it failed, a :class:`Reason`.

String enums, so plan.json carries exactly the strings the file format names (``ok``,
``failed``; ``unreachable``, ``outside_roi``, ...): ``Status.OK == "ok"`` and
``json.dumps(Reason.OCCLUDED) == '"occluded"'``. Inside the planner a reason travels as the
enum, next to a free-text detail, never folded into one ``"reason: detail"`` string.
"""

from __future__ import annotations

from enum import StrEnum
from typing import NamedTuple


class Status(StrEnum):
    """Outcome of one target."""

    OK = "ok"
    FAILED = "failed"


class Reason(StrEnum):
    """Why a target failed (machine-readable, as written to plan.json)."""

    UNREACHABLE = "unreachable"  # no configuration sends the beam there (reach, incidence)
    OUTSIDE_ROI = "outside_roi"  # only with a mirror hit outside its region of interest
    JOINT_LIMITS = "joint_limits"  # only outside the joint position limits
    BACK_FACE = "back_face"  # only with the beam on a mirror's back face or the target behind
    OCCLUDED = "occluded"  # the beam crosses a scene object or a robot link
    KEEP_OUT = "keep_out"  # the beam (or the target) inside a keep-out volume
    COLLISION = "collision"  # arms, or an arm and the scene, closer than the clearance
    SOLVER_FAILED = "solver_failed"  # the solver gave no usable answer


class Failure(NamedTuple):
    """Why something failed: the machine-readable ``reason`` and a human ``detail`` (the
    evidence, values with units), carried side by side, never parsed out of one string."""

    reason: Reason
    detail: str = ""

    def __str__(self) -> str:
        return f"{self.reason}: {self.detail}" if self.detail else str(self.reason)


def evidence_text(evidence: object, digits: int = 4) -> str:
    """Failure evidence (a JSON-like mapping of SI values, possibly nested) as one readable
    line: ``key=value`` pairs, numbers to ``digits`` significant digits, vectors in brackets,
    nested mappings in braces; joint vectors ``q`` are left out (they are in the plan)."""
    if isinstance(evidence, dict):
        return ", ".join(f"{k}={_value_text(v, digits)}" for k, v in evidence.items() if k != "q")
    return _value_text(evidence, digits)


def _value_text(value: object, digits: int) -> str:
    if hasattr(value, "tolist"):  # a numpy array or scalar
        value = value.tolist()
    if isinstance(value, dict):
        return "{" + evidence_text(value, digits) + "}"
    if isinstance(value, list | tuple):
        return "[" + " ".join(_value_text(v, digits) for v in value) + "]"
    if isinstance(value, float):
        return f"{value:.{digits}g}"
    return str(value)


class ServoStatus(StrEnum):
    """How a servo run ended (:mod:`planner.servo.loop`); here, with the other statuses, so
    that a client reads a closed-loop report's status without loading the servo."""

    CONVERGED = "converged"
    NOT_IMPROVING = "not_improving"
    NOT_SEEN = "not_seen"
    REFUSED = "refused"
    MAX_ITERATIONS = "max_iterations"
    ABORTED = "aborted"
