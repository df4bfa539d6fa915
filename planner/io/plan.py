"""The plan inside the planner: a frozen :class:`Plan` of numpy tables, typed solutions and
enums, and the one mapping to and from the plan.json document (:meth:`Plan.to_document`,
:meth:`Plan.from_document`).

Every point is in the world frame (m); joints in rad (rad/s, rad/s^2); times in s from the
trajectory's start. The document keeps the key order plan.json is written in, so that a plan
read and written again gives the same text. Arrays held by a plan are read-only views.
"""
# long module: the typed plan and its one mapping to and from plan.json (SPEC section 5), field by field

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from enum import StrEnum
from typing import Any, Final, TypeVar

import numpy as np
import numpy.typing as npt

from planner.model.status import Reason, Status
from planner.model.transforms import Array
from schemas.common import FieldError

PLAN_SCHEMA: Final = "beamrelay.plan/1"
Loc = tuple[str | int, ...]
E = TypeVar("E", bound=StrEnum)


class Verdict(StrEnum):
    """What the robot drivers said of an executed plan's trajectory."""

    ACCEPTED = "accepted"
    REJECTED = "rejected"


def _ro(x: Any, loc: Loc, ndim: int | None = None) -> Array:
    """``x`` as a read-only float array (a view: the caller's array stays writable)."""
    try:
        a = np.asarray(x, dtype=float).view()
    except (TypeError, ValueError):
        raise FieldError(loc, "expected numbers") from None
    if ndim is not None and a.ndim != ndim and a.size:
        raise FieldError(loc, f"expected {ndim}-D numbers, got shape {a.shape}")
    a.flags.writeable = False
    return a


def parse_enum(kind: type[E], value: Any, loc: Loc) -> E:
    """``value`` as a member of the string enum ``kind``; FieldError naming ``loc`` and the
    allowed values otherwise."""
    try:
        return kind(value)
    except ValueError:
        allowed = ", ".join(m.value for m in kind)
        raise FieldError(loc, f"unknown {kind.__name__.lower()} {value!r} ({allowed})") from None


def _key(doc: Mapping[str, Any], key: str, loc: Loc) -> Any:
    if not isinstance(doc, Mapping):
        raise FieldError(loc, "expected a mapping")
    if key not in doc:
        raise FieldError((*loc, key), "required")
    return doc[key]


def _opt_float(x: Any) -> float | None:
    return None if x is None else float(x)


@dataclass(frozen=True)
class Hit:
    """Where the beam meets ``robot``'s mirror: ``p`` in the world (m), ``uv`` in mirror x/y (m)."""

    robot: str
    p: Array
    uv: Array


@dataclass(frozen=True)
class SurfaceLanding:
    """A camera-frame target planned onto the scene surface ``object`` its beam meets: the
    ``requested`` world point (m) and ``offset_m`` (m, signed along the beam)."""

    object: str
    requested: Array
    offset_m: float

    def to_document(self) -> dict[str, Any]:
        return {"object": self.object, "requested": self.requested.tolist(),
                "offset_m": self.offset_m}  # fmt: skip


@dataclass(frozen=True)
class Solution:
    """The IK result of target ``target``: ``q`` per robot (rad, empty when failed), the spot
    (world, m), its ``error`` (m), ``incidence`` (rad), mirror ``hits``, ``solve_time`` (s)."""

    target: int
    status: Status
    reason: Reason | None = None
    q: Mapping[str, Array] = field(default_factory=dict)
    spot: Array | None = None
    error: float | None = None
    incidence: float | None = None
    hits: tuple[Hit, ...] = ()
    solve_time: float = 0.0
    iterations: int = 0
    surface: SurfaceLanding | None = None

    @property
    def ok(self) -> bool:
        return self.status is Status.OK

    @classmethod
    def from_document(cls, d: Mapping[str, Any], loc: Loc) -> Solution:
        status = parse_enum(Status, _key(d, "status", loc), (*loc, "status"))
        reason = d.get("reason")
        surface = d.get("surface")
        return cls(
            int(_key(d, "target", loc)), status,
            None if reason is None else parse_enum(Reason, reason, (*loc, "reason")),
            {r: _ro(q, (*loc, "q", r), 1) for r, q in (d.get("q") or {}).items()},
            None if d.get("spot") is None else _ro(d["spot"], (*loc, "spot"), 1),
            _opt_float(d.get("error")), _opt_float(d.get("incidence")),
            tuple(Hit(h["robot"], _ro(h["p"], (*loc, "hits", i, "p")),
                      _ro(h["uv"], (*loc, "hits", i, "uv")))
                  for i, h in enumerate(d.get("hits") or [])),
            float(d.get("solve_time", 0.0)), int(d.get("iterations", 0)),
            None if surface is None else SurfaceLanding(
                surface["object"], _ro(surface["requested"], (*loc, "surface", "requested")),
                float(surface["offset_m"])),
        )  # fmt: skip

    def to_document(self) -> dict[str, Any]:
        d: dict[str, Any] = {"target": self.target, "status": self.status.value,
                             "reason": None if self.reason is None else self.reason.value}  # fmt: skip
        if self.q:
            d["q"] = {r: q.tolist() for r, q in self.q.items()}
        if self.spot is not None:
            d["spot"] = self.spot.tolist()
        if self.error is not None:
            d["error"] = self.error
        if self.incidence is not None:
            d["incidence"] = self.incidence
        if self.q or self.hits:
            d["hits"] = [{"robot": h.robot, "p": h.p.tolist(), "uv": h.uv.tolist()}
                         for h in self.hits]  # fmt: skip
        if self.surface is not None:
            d["surface"] = self.surface.to_document()
        d["solve_time"] = self.solve_time
        d["iterations"] = self.iterations
        return d


@dataclass(frozen=True)
class PlanTargets:
    """The planned targets: ``ids`` (M,), world points ``p`` (M x 3, m) and unit normals
    ``n`` (M x 3; a row of NaN for a target without one; None when no target has one)."""

    ids: npt.NDArray[np.int_]
    p: Array
    n: Array | None = None

    def __len__(self) -> int:
        return len(self.ids)

    def normal(self, k: int) -> Array | None:
        """Target ``k``'s normal, or None."""
        if self.n is None or not np.isfinite(self.n[k]).all():
            return None
        return self.n[k]

    @classmethod
    def from_document(cls, rows: list[Mapping[str, Any]]) -> PlanTargets:
        ids = np.array([int(_key(t, "id", ("targets", k))) for k, t in enumerate(rows)], int)
        ids.flags.writeable = False
        p = _ro([_key(t, "p", ("targets", k)) for k, t in enumerate(rows)], ("targets",), 2)
        normals = [t.get("n") for t in rows]
        n = None
        if any(x is not None for x in normals):
            n = _ro([[math.nan] * 3 if x is None else x for x in normals], ("targets",), 2)
        return cls(ids, p.reshape(-1, 3), n)

    def to_document(self) -> list[dict[str, Any]]:
        return [{"id": int(i), "p": self.p[k].tolist(),
                 "n": None if (n := self.normal(k)) is None else n.tolist()}
                for k, i in enumerate(self.ids)]  # fmt: skip


@dataclass(frozen=True)
class Segment:
    """A labelled time span ``[t0, t1]`` (s): approach, move, run_in, path, run_out, dwell."""

    kind: str
    t0: float
    t1: float


@dataclass(frozen=True)
class Slowdown:
    """Where the spot runs slower than the spot speed: arc length ``s0``..``s1`` (m), time
    ``t0``..``t1`` (s), the binding ``limit``, the joint (robot, index; -1 none), speed (m/s)."""

    s0: float
    s1: float
    t0: float
    t1: float
    limit: str
    robot: str | None
    joint: int
    speed: float


@dataclass(frozen=True)
class Trajectory:
    """The dense trajectory: ``q[robot][k]`` (rad) at ``t[k]`` (s), its rates ``qd``,
    ``qdd``; ``laser_on`` (K x 2, s): when the laser gate is on; ``aim_on`` likewise for
    the aiming beam (a closed-loop measurement move only)."""

    t: Array
    q: Mapping[str, Array]
    qd: Mapping[str, Array]
    qdd: Mapping[str, Array]
    segments: tuple[Segment, ...] = ()
    laser_on: Array = field(default_factory=lambda: _ro(np.zeros((0, 2)), ()))
    slowdowns: tuple[Slowdown, ...] = ()
    aim_on: Array | None = None

    @property
    def duration(self) -> float:
        """Seconds from the first to the last sample (0 when empty)."""
        return float(self.t[-1] - self.t[0]) if len(self.t) else 0.0

    @classmethod
    def from_document(cls, d: Mapping[str, Any], loc: Loc = ("trajectory",)) -> Trajectory:
        tables = {k: {r: _ro(x, (*loc, k, r), 2) for r, x in (_key(d, k, loc) or {}).items()}
                  for k in ("q", "qd", "qdd")}  # fmt: skip
        aim = d.get("aim_on")
        return cls(
            _ro(_key(d, "t", loc), (*loc, "t"), 1), tables["q"], tables["qd"], tables["qdd"],
            tuple(Segment(s["kind"], float(s["t0"]), float(s["t1"])) for s in d.get("segments") or []),
            _intervals(d.get("laser_on"), (*loc, "laser_on")),
            tuple(Slowdown(float(s["s0"]), float(s["s1"]), float(s["t0"]), float(s["t1"]),
                           s["limit"], s.get("robot"), int(s.get("joint", -1)), float(s["speed"]))
                  for s in d.get("slowdowns") or []),
            None if aim is None else _intervals(aim, (*loc, "aim_on")),
        )  # fmt: skip

    def to_document(self, arrays: bool = False) -> dict[str, Any]:
        """The ``trajectory`` mapping; with ``arrays`` its dense tables stay numpy arrays
        (what :func:`planner.io.plan_file.write_plan` writes without copying to lists)."""

        def table(x: Array) -> Any:
            return x if arrays else x.tolist()

        d: dict[str, Any] = {"t": table(self.t)}
        for key in ("q", "qd", "qdd"):
            d[key] = {r: table(x) for r, x in getattr(self, key).items()}
        d["segments"] = [{"kind": s.kind, "t0": s.t0, "t1": s.t1} for s in self.segments]
        d["laser_on"] = self.laser_on.tolist()
        d["slowdowns"] = [{"s0": s.s0, "s1": s.s1, "t0": s.t0, "t1": s.t1, "limit": s.limit,
                           "robot": s.robot, "joint": s.joint, "speed": s.speed}
                          for s in self.slowdowns]  # fmt: skip
        if self.aim_on is not None:
            d["aim_on"] = self.aim_on.tolist()
        return d


def _intervals(x: Any, loc: Loc) -> Array:
    return _ro(np.asarray(x or [], dtype=float).reshape(-1, 2), loc)


@dataclass(frozen=True)
class Exposure:
    """What the laser deposits: fluence along paths (J/m) at its smallest and largest, and
    the energy per dwell (J); None where it does not apply."""

    fluence_min: float | None = None
    fluence_max: float | None = None
    dwell_energy: float | None = None


@dataclass(frozen=True)
class Metrics:
    """Summary figures; medians over solved targets (None when nothing was solved); errors
    in m, times in s; further figures in ``extra``."""

    n_targets: int
    n_ok: int
    error_max: float | None = None
    error_median: float | None = None
    solve_time_median: float | None = None
    solve_time_p95: float | None = None
    duration: float | None = None
    extra: Mapping[str, float] = field(default_factory=dict)
    exposure: Exposure | None = None

    @classmethod
    def from_document(cls, d: Mapping[str, Any]) -> Metrics:
        e = d.get("exposure")
        loc = ("metrics",)
        return cls(
            int(_key(d, "n_targets", loc)), int(_key(d, "n_ok", loc)),
            _opt_float(d.get("error_max")), _opt_float(d.get("error_median")),
            _opt_float(d.get("solve_time_median")), _opt_float(d.get("solve_time_p95")),
            _opt_float(d.get("duration")), dict(d.get("extra") or {}),
            None if e is None else Exposure(_opt_float(e.get("fluence_min")),
                                            _opt_float(e.get("fluence_max")),
                                            _opt_float(e.get("dwell_energy"))),
        )  # fmt: skip

    def to_document(self) -> dict[str, Any]:
        d: dict[str, Any] = {"n_targets": self.n_targets, "n_ok": self.n_ok,
                             "error_max": self.error_max, "error_median": self.error_median,
                             "solve_time_median": self.solve_time_median,
                             "solve_time_p95": self.solve_time_p95, "duration": self.duration,
                             "extra": dict(self.extra)}  # fmt: skip
        if self.exposure is not None:
            e = self.exposure
            d["exposure"] = {"fluence_min": e.fluence_min, "fluence_max": e.fluence_max,
                             "dwell_energy": e.dwell_energy}  # fmt: skip
        return d

    def with_extra(self, **figures: float) -> Metrics:
        """These metrics with ``figures`` added to (or replacing theirs in) ``extra``."""

        return replace(self, extra={**self.extra, **figures})


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
    tracking report (their own JSON sections, carried as they are)."""

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
    closed_loop: Mapping[str, Any] | None = None
    tracking: Mapping[str, Any] | None = None
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

    @classmethod
    def from_document(cls, doc: Mapping[str, Any]) -> Plan:
        """The plan of a plan.json document (or reply), its tables as arrays. FieldError
        naming the key path of a missing key or an unknown status, reason or verdict."""
        traj, verdict = doc.get("trajectory"), doc.get("execution")
        warnings, unanswered = doc.get("warnings"), doc.get("execution_unanswered")
        chunks = doc.get("execution_chunks")
        return cls(
            _key(doc, "scenario", ()), tuple(_key(doc, "robots", ())),
            {r: tuple(n) for r, n in _key(doc, "joint_names", ()).items()},
            PlanTargets.from_document(_key(doc, "targets", ())),
            tuple(Solution.from_document(s, ("solutions", i))
                  for i, s in enumerate(_key(doc, "solutions", ()))),
            Metrics.from_document(_key(doc, "metrics", ())),
            None if traj is None else Trajectory.from_document(traj),
            doc.get("trajectory_requested"),
            None if warnings is None else tuple(warnings), doc.get("id"),
            doc.get("closed_loop"), doc.get("tracking"),
            None if unanswered is None else tuple(unanswered),
            None if verdict is None else parse_enum(Verdict, verdict, ("execution",)),
            doc.get("execution_reason"), None if chunks is None else int(chunks),
            _key(doc, "schema", ()),
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
            elif value is not None:
                doc[key] = list(value) if isinstance(value, tuple) else value
        if self.closed_loop is not None:
            doc["closed_loop"] = dict(self.closed_loop)
        return doc
