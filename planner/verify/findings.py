"""The one result record of ``beamrelay check``: a :class:`Finding`.

Every check (solved targets, trajectory limits, the spot along the trajectory, metrics)
reports findings of this one type; a finding with severity ``error`` is a violation (exit
status 1), ``warning`` is worth a look, ``info`` carries a measured figure.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from planner.model.status import Reason

Severity = Literal["error", "warning", "info"]


@dataclass(frozen=True)
class Finding:
    """What a check found: the ``check`` (group name: ``spot``, ``mirrors``, ``joint
    limits``, ``trajectory limits``, ...), the ``target`` id (None: the whole plan), a
    ``message`` with the evidence, the worst ``value`` and the ``bound`` it was compared with
    (SI units), the ``reason`` a planner gives a target failing it (None: not a per-target
    finding), a machine ``code`` and the ``severity``."""

    check: str
    target: int | None
    message: str
    value: float = float("nan")
    bound: float = float("nan")
    reason: Reason | None = None
    code: str = ""
    severity: Severity = "error"


def trajectory_finding(
    severity: Severity,
    code: str,
    message: str,
    value: float = float("nan"),
    bound: float = float("nan"),
) -> Finding:
    """A whole-plan finding of the trajectory checks (group ``trajectory``)."""
    return Finding("trajectory", None, message, value, bound, None, code, severity)
