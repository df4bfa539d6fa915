"""The plan inside the planner: a frozen :class:`Plan` of numpy tables, typed solutions and
enums, and the one mapping to and from the plan.json document (:meth:`Plan.to_document`,
:meth:`Plan.from_document`).

Every point is in the world frame (m); joints in rad (rad/s, rad/s^2); times in s from the
trajectory's start. The document keeps the key order plan.json is written in, so that a plan
read and written again gives the same text. Arrays held by a plan are read-only views. Its
parts: the tables (:mod:`planner.io.plan_tables`), the records shared with the file's
schema (:mod:`schemas.plan_records`), a reply's reports (:mod:`planner.io.plan_reports`)
and typed reads of its resolved scenario (:mod:`planner.io.plan_scenario`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from enum import StrEnum
from functools import cached_property
from typing import Any, Final

from planner.io.plan_reports import ClosedLoopReport, ClosedLoopTarget, TrackingReport
from planner.io.plan_scenario import PlannedScenario
from planner.io.plan_tables import Hit, PlanTargets, Solution, SurfaceLanding, Trajectory
from schemas.fields import parse_enum, required
from schemas.plan import PLAN_SCHEMA
from schemas.plan_records import Exposure, Metrics, Segment, SegmentKind, Slowdown

__all__ = [
    "PLAN_SCHEMA", "ClosedLoopReport", "ClosedLoopTarget", "Exposure", "Hit", "Metrics",
    "Plan", "PlanTargets", "PlannedScenario", "Segment", "SegmentKind", "Slowdown",
    "Solution", "SurfaceLanding", "TrackingReport", "Trajectory", "Verdict", "parse_enum",
]  # fmt: skip


class Verdict(StrEnum):
    """What the robot drivers said of an executed plan's trajectory."""

    ACCEPTED = "accepted"
    REJECTED = "rejected"


#: the optional top-level keys, in the order a reply carries them (absent when None)
_TAIL: Final = ("warnings", "id", "closed_loop", "tracking", "execution_unanswered",
                "execution", "execution_reason", "execution_chunks")  # fmt: skip


@dataclass(frozen=True)
class Plan:
    """A plan: the resolved ``scenario`` (the document that was planned, every pose a 4x4
    matrix), the robots and their joint names, the targets as planned, one :class:`Solution`
    per target, the :class:`Trajectory` (None when none was timed) and the :class:`Metrics`.

    A reply to a request adds its ``id``, ``warnings`` (one line each), the drivers'
    ``execution`` verdict with its reason (``execution_unanswered``: robots that gave none;
    ``execution_chunks``: a streamed trajectory's chunk count) and the closed-loop or
    tracking report (:class:`ClosedLoopReport`, :class:`TrackingReport`). :attr:`resolved`
    reads the scenario's sections typed."""

    scenario: Mapping[str, Any]
    robots: tuple[str, ...]
    joint_names: Mapping[str, tuple[str, ...]]
    targets: PlanTargets
    solutions: tuple[Solution, ...]
    metrics: Metrics
    trajectory: Trajectory | None = None
    trajectory_requested: bool | None = None
    warnings: tuple[str, ...] | None = None
    id: str | None = None
    closed_loop: ClosedLoopReport | None = None
    tracking: TrackingReport | None = None
    execution_unanswered: tuple[str, ...] | None = None
    execution: Verdict | None = None
    execution_reason: str | None = None
    execution_chunks: int | None = None
    schema: str = PLAN_SCHEMA

    @property
    def n_ok(self) -> int:
        """How many targets were solved."""
        return sum(s.ok for s in self.solutions)

    @property
    def any_ok(self) -> bool:
        return any(s.ok for s in self.solutions)

    @cached_property
    def resolved(self) -> PlannedScenario:
        """Typed reads of :attr:`scenario` (its laser, fixed camera's pose, safety, trajectory
        settings, keep-out volumes), each validated when first read."""
        return PlannedScenario(self.scenario)

    @classmethod
    def from_document(cls, doc: Mapping[str, Any]) -> Plan:
        """The plan of a plan.json document (or reply), its tables as arrays. FieldError
        naming the key path of a missing key or an unknown status, reason, verdict or kind."""
        traj, verdict = doc.get("trajectory"), doc.get("execution")
        warnings, unanswered = doc.get("warnings"), doc.get("execution_unanswered")
        chunks, closed, tracking = (
            doc.get(k) for k in ("execution_chunks", "closed_loop", "tracking")
        )
        return cls(
            required(doc, "scenario", ()), tuple(required(doc, "robots", ())),
            {r: tuple(n) for r, n in required(doc, "joint_names", ()).items()},
            PlanTargets.from_document(required(doc, "targets", ())),
            tuple(Solution.from_document(s, ("solutions", i))
                  for i, s in enumerate(required(doc, "solutions", ()))),
            Metrics.from_document(required(doc, "metrics", ())),
            None if traj is None else Trajectory.from_document(traj),
            doc.get("trajectory_requested"),
            None if warnings is None else tuple(warnings), doc.get("id"),
            None if closed is None else ClosedLoopReport.from_document(closed),
            None if tracking is None else TrackingReport.from_document(tracking),
            None if unanswered is None else tuple(unanswered),
            None if verdict is None else parse_enum(Verdict, verdict, ("execution",)),
            doc.get("execution_reason"), None if chunks is None else int(chunks),
            required(doc, "schema", ()),
        )  # fmt: skip

    def to_document(self, arrays: bool = False) -> dict[str, Any]:
        """The plan.json document (SPEC section 5) of this plan, as json writes it; with
        ``arrays`` the trajectory's dense tables stay arrays (for ``write_plan``)."""
        traj = None if self.trajectory is None else self.trajectory.to_document(arrays)
        doc: dict[str, Any] = {
            "schema": self.schema, "scenario": self.scenario, "robots": list(self.robots),
            "joint_names": {r: list(n) for r, n in self.joint_names.items()},
            "targets": self.targets.to_document(),
            "solutions": [s.to_document() for s in self.solutions], "trajectory": traj,
        }  # fmt: skip
        if self.trajectory_requested is not None:
            doc["trajectory_requested"] = self.trajectory_requested
        doc["metrics"] = self.metrics.to_document()
        for key in _TAIL:
            value = getattr(self, key)
            if key == "execution_reason" and self.execution is not None:
                doc[key] = value  # a verdict always says why (null: no reason)
            elif isinstance(value, StrEnum):
                doc[key] = value.value
            elif isinstance(value, ClosedLoopReport | TrackingReport):
                doc[key] = value.to_document()
            elif value is not None:
                doc[key] = list(value) if isinstance(value, tuple) else value
        return doc
