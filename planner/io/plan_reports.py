"""What a reply adds to its plan when the node ran the request: the closed-loop report
(:class:`ClosedLoopReport`: the run's settings and one :class:`ClosedLoopTarget` per target)
and the start of a tracking session (:class:`TrackingReport`), each with its one mapping to
and from its section of the reply (``closed_loop``, ``tracking``), in the order the reply
carries its keys.

Points in the world frame unless the name says camera (the camera's optical frame); m, s,
rad. Arrays held are read-only.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from planner.io.plan_tables import read_only
from planner.model.transforms import Array
from schemas.fields import Loc, opt_float, parse_either, parse_enum, required
from schemas.status import Interruption, Reason, ServoStatus


@dataclass(frozen=True)
class ServoFigures:
    """A servoed target's run: ``iterations`` correction steps, camera ``frames`` grabbed,
    its ``time`` (s), the measured error ``error_before`` (at the planned joints) and
    ``error_after`` (at the last joints; m, None when the spot was not seen), every
    measurement's error in order (``errors``, m, NaN where not seen), the last measured
    ``spot`` (world, m; None when not seen) and the joints ``q`` the arms were left at (rad
    per robot)."""

    iterations: int
    frames: int
    time: float
    error_before: float | None
    error_after: float | None
    errors: Array
    spot: Array | None
    q: Mapping[str, Array]

    @classmethod
    def from_document(cls, d: Mapping[str, Any], loc: Loc) -> ServoFigures:
        errors = [math.nan if e is None else e for e in d.get("errors") or []]
        spot = d.get("measured_spot")
        return cls(
            int(required(d, "iterations", loc)), int(required(d, "frames", loc)),
            float(required(d, "time", loc)), opt_float(d.get("measured_error_before")),
            opt_float(d.get("measured_error_after")), read_only(errors, (*loc, "errors"), 1),
            None if spot is None else read_only(spot, (*loc, "measured_spot"), 1),
            {r: read_only(q, (*loc, "q", r), 1) for r, q in (d.get("q") or {}).items()},
        )  # fmt: skip

    def figures(self) -> dict[str, Any]:
        """The run's keys of a row, up to the measured spot (``q`` comes last in a row)."""
        return {"iterations": self.iterations, "frames": self.frames, "time": self.time,
                "measured_error_before": self.error_before,
                "measured_error_after": self.error_after,
                "errors": [e if math.isfinite(e) else None for e in self.errors.tolist()],
                "measured_spot": None if self.spot is None else self.spot.tolist()}  # fmt: skip


@dataclass(frozen=True)
class ClosedLoopTarget:
    """One target of a closed-loop run: its ``id``, how it ended (:class:`ServoStatus`), the
    treatment ``dwell`` held on it (s) and whether it was ``treated`` (None: the run never
    reached it, ``not_executed``); its ``servo`` run (None when it had none); why a run was
    refused or cut short (``reason``: a :class:`Reason` or an :class:`Interruption`, with
    its ``detail``); for a camera-frame request, the target and the last measured spot as
    the camera sees them (``target_camera``, ``spot_camera``, m) and their distance
    ``error_camera`` (m)."""

    id: int
    status: ServoStatus
    dwell: float = 0.0
    treated: bool | None = False
    servo: ServoFigures | None = None
    reason: Reason | Interruption | None = None
    detail: str | None = None
    target_camera: Array | None = None
    spot_camera: Array | None = None
    error_camera: float | None = None

    @property
    def converged(self) -> bool:
        return self.status is ServoStatus.CONVERGED

    @classmethod
    def from_document(cls, d: Mapping[str, Any], loc: Loc) -> ClosedLoopTarget:
        """A row of ``closed_loop.targets``; FieldError naming the key path of a missing key
        or an unknown status or reason."""
        status = parse_enum(ServoStatus, required(d, "status", loc), (*loc, "status"))
        reason = d.get("reason")
        treated, target, spot = (
            d.get("treated"),
            d.get("target_camera"),
            d.get("measured_spot_camera"),
        )
        return cls(
            int(required(d, "id", loc)), status, float(d.get("dwell", 0.0)),
            None if treated is None else bool(treated),
            ServoFigures.from_document(d, loc) if "frames" in d else None,
            None if reason is None else _reason(reason, (*loc, "reason")),
            d.get("detail"),
            None if target is None else read_only(target, (*loc, "target_camera"), 1),
            None if spot is None else read_only(spot, (*loc, "measured_spot_camera"), 1),
            opt_float(d.get("measured_error_camera")),
        )  # fmt: skip

    def to_document(self) -> dict[str, Any]:
        """The row as the reply carries it: a run's figures only for a servoed target,
        ``reason`` and ``detail`` with them or when there is a reason."""
        d: dict[str, Any]
        if self.treated is None:
            d = {"id": self.id, "status": self.status.value, "dwell": self.dwell}
        else:
            d = {"id": self.id, "dwell": self.dwell, "treated": self.treated,
                 "status": self.status.value}  # fmt: skip
        if self.servo is not None:
            d |= self.servo.figures()
        if self.servo is not None or self.reason is not None:
            d["reason"] = None if self.reason is None else self.reason.value
            d["detail"] = self.detail
        if self.servo is not None:
            d["q"] = {r: q.tolist() for r, q in self.servo.q.items()}
        if self.target_camera is not None:
            d["target_camera"] = self.target_camera.tolist()
        if self.spot_camera is not None:
            d["measured_spot_camera"] = self.spot_camera.tolist()
            d["measured_error_camera"] = self.error_camera
        return d


def _reason(value: Any, loc: Loc) -> Reason | Interruption:
    got = parse_either((Reason, Interruption), value, loc)
    assert isinstance(got, Reason | Interruption)
    return got


@dataclass(frozen=True)
class FramesDropped:
    """Camera frames the closed loop's plausibility gate left out: too little confidence,
    or a spot too far from the predicted one."""

    low_confidence: int = 0
    implausible: int = 0


@dataclass(frozen=True)
class ClosedLoopReport:
    """A closed-loop run: its ``tolerance`` (m), frames per measurement, treatment ``dwell``
    (s), the ``moves`` sent, the frames dropped, the request's ``frame`` (``world`` or
    ``camera``) and one :class:`ClosedLoopTarget` per target in the request's order."""

    tolerance: float
    frames_per_measurement: int
    dwell: float
    moves: int
    dropped: FramesDropped = field(default_factory=FramesDropped)
    frame: str = "world"
    targets: tuple[ClosedLoopTarget, ...] = ()

    @property
    def converged(self) -> int:
        """How many targets converged."""
        return sum(r.converged for r in self.targets)

    def spots(self, n: int) -> list[Array | None]:
        """The last measured spot (world, m) of each of ``n`` targets (None where not
        measured), as new arrays."""
        spots: list[Array | None] = [None] * n
        for k, row in enumerate(self.targets[:n]):
            if row.servo is not None and row.servo.spot is not None:
                spots[k] = np.array(row.servo.spot, dtype=float)
        return spots

    @classmethod
    def from_document(cls, d: Mapping[str, Any], loc: Loc = ("closed_loop",)) -> ClosedLoopReport:
        dropped = d.get("dropped") or {}
        return cls(
            float(required(d, "tolerance", loc)), int(required(d, "frames_per_measurement", loc)),
            float(required(d, "dwell", loc)), int(required(d, "moves", loc)),
            FramesDropped(int(dropped.get("low_confidence", 0)), int(dropped.get("implausible", 0))),
            str(d.get("frame", "world")),
            tuple(ClosedLoopTarget.from_document(r, (*loc, "targets", i))
                  for i, r in enumerate(required(d, "targets", loc))),
        )  # fmt: skip

    def to_document(self, targets: bool = True) -> dict[str, Any]:
        """The reply's ``closed_loop`` mapping (without ``targets``: the run's settings)."""
        d: dict[str, Any] = {
            "tolerance": self.tolerance, "frames_per_measurement": self.frames_per_measurement,
            "dwell": self.dwell, "moves": self.moves,
            "dropped": {"low_confidence": self.dropped.low_confidence,
                        "implausible": self.dropped.implausible},
            "frame": self.frame,
        }  # fmt: skip
        if targets:
            d["targets"] = [r.to_document() for r in self.targets]
        return d


@dataclass(frozen=True)
class TrackingReport:
    """The start of a tracking session: the target ``stream`` followed (the request id), its
    ``duration`` (s; None: until stopped), the laser-on ``tolerance`` (m), the follower's
    ``rate`` (Hz) and what became of the camera-frame spot correction (``on``, or ``off:``
    and why)."""

    stream: str
    duration: float | None
    tolerance: float
    rate: float
    camera_correction: str

    @classmethod
    def from_document(cls, d: Mapping[str, Any], loc: Loc = ("tracking",)) -> TrackingReport:
        return cls(str(required(d, "stream", loc)), opt_float(d.get("duration")),
                   float(required(d, "tolerance", loc)), float(required(d, "rate", loc)),
                   str(required(d, "camera_correction", loc)))  # fmt: skip

    def to_document(self) -> dict[str, Any]:
        return {"stream": self.stream, "duration": self.duration, "tolerance": self.tolerance,
                "rate": self.rate, "camera_correction": self.camera_correction}  # fmt: skip
