"""The plan's tables: one :class:`Solution` per target (with its mirror :class:`Hit` s and,
for a camera-frame target, its :class:`SurfaceLanding`), the :class:`PlanTargets` and the
dense :class:`Trajectory`, each with its mapping to and from its plan.json section.

Every point is in the world frame (m); joints in rad (rad/s, rad/s^2); times in s from the
trajectory's start. Arrays held are read-only views (the caller's array stays writable).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from planner.model.transforms import Array
from schemas.common import FieldError
from schemas.fields import Loc, opt_float, parse_enum, required
from schemas.plan_records import Segment, SegmentKind, Slowdown
from schemas.status import Reason, Status


def read_only(x: Any, loc: Loc, ndim: int | None = None) -> Array:
    """``x`` as a read-only float array (a view: the caller's array stays writable);
    FieldError at ``loc`` when it is no array of numbers (of ``ndim`` dimensions)."""
    try:
        a = np.asarray(x, dtype=float).view()
    except (TypeError, ValueError):
        raise FieldError(loc, "expected numbers") from None
    if ndim is not None and a.ndim != ndim and a.size:
        raise FieldError(loc, f"expected {ndim}-D numbers, got shape {a.shape}")
    a.flags.writeable = False
    return a


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
        status = parse_enum(Status, required(d, "status", loc), (*loc, "status"))
        reason = d.get("reason")
        surface = d.get("surface")
        return cls(
            int(required(d, "target", loc)), status,
            None if reason is None else parse_enum(Reason, reason, (*loc, "reason")),
            {r: read_only(q, (*loc, "q", r), 1) for r, q in (d.get("q") or {}).items()},
            None if d.get("spot") is None else read_only(d["spot"], (*loc, "spot"), 1),
            opt_float(d.get("error")), opt_float(d.get("incidence")),
            tuple(Hit(h["robot"], read_only(h["p"], (*loc, "hits", i, "p")),
                      read_only(h["uv"], (*loc, "hits", i, "uv")))
                  for i, h in enumerate(d.get("hits") or [])),
            float(d.get("solve_time", 0.0)), int(d.get("iterations", 0)),
            None if surface is None else SurfaceLanding(
                surface["object"], read_only(surface["requested"], (*loc, "surface", "requested")),
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
        ids = np.array([int(required(t, "id", ("targets", k))) for k, t in enumerate(rows)], int)
        ids.flags.writeable = False
        p = read_only(
            [required(t, "p", ("targets", k)) for k, t in enumerate(rows)], ("targets",), 2
        )
        normals = [t.get("n") for t in rows]
        n = None
        if any(x is not None for x in normals):
            n = read_only([[math.nan] * 3 if x is None else x for x in normals], ("targets",), 2)
        return cls(ids, p.reshape(-1, 3), n)

    def to_document(self) -> list[dict[str, Any]]:
        return [{"id": int(i), "p": self.p[k].tolist(),
                 "n": None if (n := self.normal(k)) is None else n.tolist()}
                for k, i in enumerate(self.ids)]  # fmt: skip


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
    laser_on: Array = field(default_factory=lambda: read_only(np.zeros((0, 2)), ()))
    slowdowns: tuple[Slowdown, ...] = ()
    aim_on: Array | None = None

    @property
    def duration(self) -> float:
        """Seconds from the first to the last sample (0 when empty)."""
        return float(self.t[-1] - self.t[0]) if len(self.t) else 0.0

    @classmethod
    def from_document(cls, d: Mapping[str, Any], loc: Loc = ("trajectory",)) -> Trajectory:
        """The trajectory of a plan.json ``trajectory`` mapping (its tables as read-only
        arrays); FieldError naming the key path of a missing key or an unknown kind."""
        tables = {k: {r: read_only(x, (*loc, k, r), 2) for r, x in (required(d, k, loc) or {}).items()}
                  for k in ("q", "qd", "qdd")}  # fmt: skip
        aim = d.get("aim_on")
        return cls(
            read_only(required(d, "t", loc), (*loc, "t"), 1), tables["q"], tables["qd"], tables["qdd"],
            _segments(d.get("segments") or [], (*loc, "segments")),
            _intervals(d.get("laser_on"), (*loc, "laser_on")),
            tuple(Slowdown.from_document(s, (*loc, "slowdowns", i))
                  for i, s in enumerate(d.get("slowdowns") or [])),
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
        d["segments"] = [s.to_document() for s in self.segments]
        d["laser_on"] = self.laser_on.tolist()
        d["slowdowns"] = [s.to_document() for s in self.slowdowns]
        if self.aim_on is not None:
            d["aim_on"] = self.aim_on.tolist()
        return d


_KINDS: Final = {k.value: k for k in SegmentKind}  # a dict lookup: 2x faster than SegmentKind(x)


def _segments(rows: list[Mapping[str, Any]], loc: Loc) -> tuple[Segment, ...]:
    """The segments of a trajectory (one per dwell: 10^5 of them for as many targets), read
    at once; when one is malformed, read again one by one for the error naming it."""
    try:
        return tuple(Segment(_KINDS[s["kind"]], float(s["t0"]), float(s["t1"])) for s in rows)
    except (KeyError, TypeError, ValueError):
        return tuple(Segment.from_document(s, (*loc, i)) for i, s in enumerate(rows))


def _intervals(x: Any, loc: Loc) -> Array:
    return read_only(np.asarray(x or [], dtype=float).reshape(-1, 2), loc)
