"""The small records of plan.json, one definition each for the file's schema
(:class:`schemas.plan.Plan` validates into them) and the planner's typed plan
(:class:`planner.io.plan.Plan` holds them): the trajectory's labelled :class:`Segment` and
:class:`Slowdown` spans and the summary :class:`Metrics` with their :class:`Exposure`.

Frozen dataclasses: pydantic validates a file into them (unknown keys are errors), and
``from_document`` / ``to_document`` map a document the planner wrote to and from them
without a pydantic pass, in the order plan.json is written (s, m, m/s, J as the SPEC says).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from enum import StrEnum
from typing import Any, Final

from pydantic import ConfigDict, with_config

from schemas.common import NonNegInt, NonNegNum, Num
from schemas.fields import Loc, opt_float, parse_enum, required

_STRICT = ConfigDict(extra="forbid")


class SegmentKind(StrEnum):
    """What the spot does in a span of the trajectory."""

    APPROACH = "approach"  # from the start to the first target (spot not on a target)
    MOVE = "move"  # between targets or path runs (spot not on a target)
    RUN_IN = "run_in"  # accelerating onto a path along its extension, laser off
    PATH = "path"  # on the path
    RUN_OUT = "run_out"  # leaving a path along its extension, laser off
    DWELL = "dwell"  # held on a target


_KIND_TEXT: Final = {k: k.value for k in SegmentKind}  # plain strings, looked up fast

#: the spans in which the laser gate may be on
LASER_KINDS = frozenset({SegmentKind.PATH, SegmentKind.DWELL})


class SlowdownLimit(StrEnum):
    """What binds where the marked spot runs slower than the spot speed."""

    SPOT = "spot"
    VELOCITY = "velocity"
    ACCELERATION = "acceleration"
    JERK = "jerk"
    POSITION = "position"  # a joint position limit
    REACH = "reach"  # the spot's line leaves the workspace (a run-in or run-out cut short)


@with_config(_STRICT)
@dataclass(frozen=True)
class Segment:
    """A labelled time span ``[t0, t1]`` (s) of the trajectory (:class:`SegmentKind`)."""

    kind: SegmentKind
    t0: Num
    t1: Num

    @classmethod
    def from_document(cls, d: Mapping[str, Any], loc: Loc) -> Segment:
        kind = parse_enum(SegmentKind, required(d, "kind", loc), (*loc, "kind"))
        return cls(kind, float(required(d, "t0", loc)), float(required(d, "t1", loc)))

    def to_document(self) -> dict[str, Any]:
        return {"kind": _KIND_TEXT[self.kind], "t0": self.t0, "t1": self.t1}


@with_config(_STRICT)
@dataclass(frozen=True)
class Slowdown:
    """Where the marked spot runs slower than the spot speed because a limit binds: arc
    length ``s0``..``s1`` (m) along the path, trajectory time ``t0``..``t1`` (s), the
    binding ``limit``, the slowest speed reached (m/s) and the joint (``robot``, index
    ``joint``; null and -1 when no one joint is named)."""

    s0: Num
    s1: Num
    t0: Num
    t1: Num
    limit: SlowdownLimit
    speed: NonNegNum
    robot: str | None = None
    joint: int = -1

    @classmethod
    def from_document(cls, d: Mapping[str, Any], loc: Loc) -> Slowdown:
        def num(key: str) -> float:
            return float(required(d, key, loc))

        limit = parse_enum(SlowdownLimit, required(d, "limit", loc), (*loc, "limit"))
        return cls(num("s0"), num("s1"), num("t0"), num("t1"), limit, num("speed"),
                   d.get("robot"), int(d.get("joint", -1)))  # fmt: skip

    def to_document(self) -> dict[str, Any]:
        return {"s0": self.s0, "s1": self.s1, "t0": self.t0, "t1": self.t1,
                "limit": self.limit.value, "robot": self.robot, "joint": self.joint,
                "speed": self.speed}  # fmt: skip


@with_config(_STRICT)
@dataclass(frozen=True)
class Exposure:
    """What the laser deposits (with ``laser.power``): fluence along paths (J/m = power /
    spot speed) at its smallest and largest over the marked samples, energy per dwell (J);
    None where it does not apply."""

    fluence_min: NonNegNum | None = None
    fluence_max: NonNegNum | None = None
    dwell_energy: NonNegNum | None = None


@with_config(_STRICT)
@dataclass(frozen=True)
class Metrics:
    """Summary figures; medians over solved targets (None when nothing was solved); errors
    in m, times in s; further numeric figures in ``extra``."""

    n_targets: NonNegInt
    n_ok: NonNegInt
    error_max: NonNegNum | None = None
    error_median: NonNegNum | None = None
    solve_time_median: NonNegNum | None = None
    solve_time_p95: NonNegNum | None = None
    duration: NonNegNum | None = None
    extra: Mapping[str, Num] = field(default_factory=dict)
    exposure: Exposure | None = None

    @classmethod
    def from_document(cls, d: Mapping[str, Any], loc: Loc = ("metrics",)) -> Metrics:
        e = d.get("exposure")
        return cls(
            int(required(d, "n_targets", loc)), int(required(d, "n_ok", loc)),
            opt_float(d.get("error_max")), opt_float(d.get("error_median")),
            opt_float(d.get("solve_time_median")), opt_float(d.get("solve_time_p95")),
            opt_float(d.get("duration")), dict(d.get("extra") or {}),
            None if e is None else Exposure(opt_float(e.get("fluence_min")),
                                            opt_float(e.get("fluence_max")),
                                            opt_float(e.get("dwell_energy"))),
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
