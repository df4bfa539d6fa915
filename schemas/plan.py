"""plan.json (docs/conventions.md: plan.json): the output of planning and the body of a plan reply.

Every point (``p``, ``spot``, hit ``p``) is in the world frame, in metres; joint values in
rad (rad/s, rad/s^2); times in seconds from the trajectory start.
"""

from __future__ import annotations

from typing import Annotated, Any, Final, Literal, Self

import numpy as np
from pydantic import AfterValidator, Field, model_validator

from schemas.common import (
    FieldError,
    JointVector,
    NonNegInt,
    NonNegNum,
    Num,
    StrictModel,
    Vec2,
    Vec3,
)
from schemas.plan_records import Metrics, Segment, Slowdown
from schemas.status import Reason, Status

PLAN_SCHEMA: Final = "beamrelay.plan/1"
FAILURE_REASONS: Final[tuple[str, ...]] = tuple(r.value for r in Reason)
JointRows = list[JointVector]


class PlanTarget(StrictModel):
    """Target ``id`` at ``p`` with optional unit surface normal ``n`` (world frame)."""

    id: NonNegInt
    p: Vec3
    n: Vec3 | None = None


class Hit(StrictModel):
    """Where the beam meets ``robot``'s mirror: ``p`` in the world, ``uv`` in mirror x/y (m)."""

    robot: str
    p: Vec3
    uv: Vec2


class SurfaceLanding(StrictModel):
    """A camera-frame target planned onto the scene surface its beam meets near it: the
    scene ``object``, the ``requested`` point (world, m: the camera's point through the
    calibrated camera pose; the target's ``p`` is where it landed) and ``offset_m``, signed
    along the beam (m; < 0: the surface lies before the requested point)."""

    object: str
    requested: Vec3
    offset_m: Num


class Solution(StrictModel):
    """The IK result for one target. ``error`` is the spot error (m), ``incidence`` the angle
    between the arriving beam and the target normal (rad, only with a normal); ``surface``
    where a camera-frame target landed (:class:`SurfaceLanding`)."""

    target: NonNegInt
    status: Status
    reason: Reason | None = None
    q: dict[str, JointVector] = Field(default_factory=dict)
    spot: Vec3 | None = None
    error: NonNegNum | None = None
    incidence: Num | None = None
    hits: list[Hit] = Field(default_factory=list)
    solve_time: NonNegNum = 0.0
    iterations: NonNegInt = 0
    surface: SurfaceLanding | None = None

    @model_validator(mode="after")
    def _reason(self) -> Self:
        if self.status is Status.OK and self.reason is not None:
            raise FieldError(("reason",), "must be null when status is ok")
        if self.status is Status.FAILED and self.reason is None:
            raise FieldError(
                ("reason",), f"required when status is failed: {', '.join(FAILURE_REASONS)}"
            )
        return self


def _ordered(segment: Segment) -> Segment:
    if segment.t1 < segment.t0:
        raise FieldError(("t1",), f"ends before t0 ({segment.t0:g})")
    return segment


class Trajectory(StrictModel):
    """Dense joint trajectory at the scenario's rate: ``q[robot][k]`` at time ``t[k]``.

    ``laser_on``: the time intervals ``[t0, t1]`` (s) in which the laser gate is on (off
    outside them); ``slowdowns``: where the marked spot is slower than the spot speed."""

    t: list[Num]
    q: dict[str, JointRows]
    qd: dict[str, JointRows]
    qdd: dict[str, JointRows]
    segments: list[Annotated[Segment, AfterValidator(_ordered)]] = Field(default_factory=list)
    laser_on: list[Annotated[list[Num], Field(min_length=2, max_length=2)]] = Field(
        default_factory=list
    )
    slowdowns: list[Slowdown] = Field(default_factory=list)

    @model_validator(mode="after")
    def _shapes(self) -> Self:
        for k in range(1, len(self.t)):
            if self.t[k] < self.t[k - 1]:
                raise FieldError(("t", k), "times must not decrease")
        for k, (t0, t1) in enumerate(self.laser_on):
            if t1 < t0:
                raise FieldError(("laser_on", k), f"ends ({t1:g} s) before it starts ({t0:g} s)")
            if k and t0 < self.laser_on[k - 1][1]:
                raise FieldError(("laser_on", k), "intervals must be in order, not overlapping")
        for key in ("q", "qd", "qdd"):
            table: dict[str, list[list[float]]] = getattr(self, key)
            if set(table) != set(self.q):
                raise FieldError((key,), f"robots {sorted(table)} differ from q's {sorted(self.q)}")
            for robot, rows in table.items():
                if len(rows) != len(self.t):
                    raise FieldError(
                        (key, robot), f"expected {len(self.t)} rows (one per t), got {len(rows)}"
                    )
        return self


class Plan(StrictModel):
    """The plan document. ``scenario`` is the resolved scenario (every pose a matrix)."""

    schema_: Literal["beamrelay.plan/1"] = Field(default=PLAN_SCHEMA, alias="schema")
    scenario: dict[str, Any]
    robots: Annotated[list[str], Field(min_length=1)]
    joint_names: dict[str, list[str]]
    targets: list[PlanTarget]
    solutions: list[Solution]
    trajectory: Trajectory | None = None
    trajectory_requested: bool | None = None
    """whether a trajectory was asked for (batch planning: always; a request: when it
    executes); unless false, ``beamrelay check`` requires one whenever a target is solved"""
    metrics: Metrics
    id: str | None = None
    """the request id (plans made for a TargetRequest)"""
    execution: Literal["accepted", "rejected"] | None = None
    """for an ``execute`` request: did every robot driver accept its trajectory"""
    execution_reason: str | None = None
    """with ``rejected``: which driver rejected it and why"""
    warnings: list[str] | None = None
    """one line each: what the user should know before trusting the plan (a target far
    from every scene surface, so the spot lands elsewhere)"""

    @model_validator(mode="after")
    def _consistent(self) -> Self:
        if set(self.joint_names) != set(self.robots):
            raise FieldError(("joint_names",), f"expected one entry per robot {self.robots}")
        ids = {t.id for t in self.targets}
        for i, sol in enumerate(self.solutions):
            if sol.target not in ids:
                raise FieldError(("solutions", i, "target"), f"no target with id {sol.target}")
            for robot, q in sol.q.items():
                _check_robot_row(("solutions", i, "q", robot), robot, q, self.joint_names)
        if self.trajectory is not None:
            for key in ("q", "qd", "qdd"):
                table: dict[str, list[list[float]]] = getattr(self.trajectory, key)
                for robot, rows in table.items():
                    for k, row in enumerate(rows):
                        _check_robot_row(
                            ("trajectory", key, robot, k), robot, row, self.joint_names
                        )
        return self


def _check_robot_row(
    loc: tuple[str | int, ...], robot: str, q: list[float], joint_names: dict[str, list[str]]
) -> None:
    if robot not in joint_names:
        raise FieldError(loc, f"unknown robot {robot!r}")
    if len(q) != len(joint_names[robot]):
        raise FieldError(loc, f"expected {len(joint_names[robot])} numbers, got {len(q)}")


TABLE_KEYS: Final = ("t", "q", "qd", "qdd")


def take_tables(doc: dict[str, Any]) -> dict[str, Any] | None:
    """Take the dense tables (``t``, ``q``, ``qd``, ``qdd``) out of a plan document's
    trajectory, leaving empty ones in their place (one empty table per robot), so that the
    model validates the rest at its size and :func:`check_tables` the tables with numpy.
    None when there is no trajectory mapping; put them back with ``traj.update(tables)``."""
    traj = doc.get("trajectory")
    if not isinstance(traj, dict):
        return None
    tables = {k: traj[k] for k in TABLE_KEYS if k in traj}
    for k in tables:
        traj[k] = {r: [] for r in tables[k]} if isinstance(tables[k], dict) else []
    return tables


def check_tables(tables: dict[str, Any], joint_names: dict[str, list[str]]) -> None:
    """The rules of :class:`Trajectory` and :class:`Plan` for the dense tables (what
    :func:`take_tables` took), with numpy: finite numbers, times that do not decrease, the
    robots of ``q`` in every table, one row per time, one number per joint.
    FieldError at the key path below ``trajectory``."""

    t = _numbers(tables.get("t", []), ("t",))
    if t.ndim != 1:
        raise FieldError(("t",), "expected a list of numbers")
    back = np.flatnonzero(np.diff(t) < 0)
    if len(back):
        raise FieldError(("t", int(back[0]) + 1), "times must not decrease")
    robots = tables.get("q", {})
    for key in ("q", "qd", "qdd"):
        table = tables.get(key, {})
        if not isinstance(table, dict):
            raise FieldError((key,), "expected a mapping of robot name to rows")
        if set(table) != set(robots):
            raise FieldError((key,), f"robots {sorted(table)} differ from q's {sorted(robots)}")
        for robot, rows in table.items():
            if robot not in joint_names:
                raise FieldError((key, robot), f"unknown robot {robot!r}")
            n = len(joint_names[robot])
            if isinstance(rows, list):  # ragged (the reader made no array of it)
                for k, row in enumerate(rows):
                    if not isinstance(row, list) or len(row) != n:
                        got = len(row) if isinstance(row, list) else "not a list"
                        raise FieldError((key, robot, k), f"expected {n} numbers, got {got}")
            X = _numbers(rows, (key, robot))
            if X.ndim != 2 and len(X):
                raise FieldError((key, robot), "expected rows of numbers")
            if len(X) != len(t):
                raise FieldError((key, robot), f"expected {len(t)} rows (one per t), got {len(X)}")
            if len(X) and X.shape[1] != n:
                raise FieldError((key, robot, 0), f"expected {n} numbers, got {X.shape[1]}")


def _numbers(x: Any, loc: tuple[str | int, ...]) -> Any:

    try:
        a = np.asarray(x)
    except ValueError:  # ragged
        raise FieldError(loc, "expected rows of numbers") from None
    if a.dtype.kind not in "iuf" and a.size:  # strings, booleans, null, mappings
        raise FieldError(loc, "expected numbers")
    a = a.astype(float)
    bad = np.argwhere(~np.isfinite(a))
    if len(bad):
        raise FieldError(
            (*loc, *map(int, bad[0])), f"expected a finite number, got {a[tuple(bad[0])]}"
        )
    return a
