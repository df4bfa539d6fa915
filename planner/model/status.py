"""What became of a target: a :class:`Status` and, when it failed, a :class:`Reason`
(the file format's string enums, :mod:`schemas.status`, re-exported here with the servo's
:class:`ServoStatus`), and a :class:`Failure`: the reason with its evidence.

Inside the planner a reason travels as the enum, next to a free-text detail, never folded
into one ``"reason: detail"`` string.
"""

from __future__ import annotations

from typing import NamedTuple

from schemas.status import Interruption, Reason, ServoStatus, Status

__all__ = ["Failure", "Interruption", "Reason", "ServoStatus", "Status", "evidence_text"]


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
