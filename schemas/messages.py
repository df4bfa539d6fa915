"""Zenoh message bodies (docs/conventions.md: Zenoh interface). JSON, encoding ``application/json``.

Points in metres (in the frame a message names), joints in rad, rad/s, rad/s^2, times in
seconds (``t`` is the sender's clock, UNIX time unless stated otherwise).
"""

from __future__ import annotations

from typing import Annotated, Final, Literal, Self

from pydantic import AfterValidator, Field, StrictBool, ValidationError, model_validator
from pydantic_core import PydanticCustomError

from schemas.bounds import check_coordinates
from schemas.common import (
    FieldError,
    JointVector,
    NonNegInt,
    Num,
    StrictModel,
    Vec3,
    exact_length,
)
from schemas.scenario import check_normals, unit_normals

REQUEST_SCHEMA: Final = "beamrelay.request/1"
TRAJECTORY_SCHEMA: Final = "beamrelay.trajectory/1"
ERROR_SCHEMA: Final = "beamrelay.error/1"
JOINT_STATE_SCHEMA: Final = "beamrelay.joint_state/1"
STATUS_SCHEMA: Final = "beamrelay.status/1"
LASER_SCHEMA: Final = "beamrelay.laser/1"
MAX_LASER_INTERVALS = 100_000  # laser_on intervals per trajectory
SPOT_SCHEMA: Final = "beamrelay.spot/1"
HEARTBEAT_SCHEMA: Final = "beamrelay.heartbeat/1"
STOP_SCHEMA: Final = "beamrelay.stop/1"
SETPOINT_SCHEMA: Final = "beamrelay.setpoint/1"
TARGET_STREAM_SCHEMA: Final = "beamrelay.target_stream/1"
CALIBRATION_SCHEMA: Final = "beamrelay.calibration/1"
TRACK_SCHEMA: Final = "beamrelay.track/1"
RECOVER_SCHEMA: Final = "beamrelay.recover/1"
#: largest closed-loop tolerance a request may ask for (m): beyond it, it is a unit mistake
MAX_TOLERANCE = 0.05
#: longest dwell a request may ask for (s)
MAX_DWELL = 600.0
MAX_REQUEST_POINTS = 10_000
MAX_ID_LENGTH = 256
#: a request/session id: 1..256 characters, no lone surrogates (they cannot be encoded)
Ident = Annotated[str, Field(min_length=1, max_length=MAX_ID_LENGTH)]
#: largest |coordinate| of a requested point (m): beyond it, it is a unit mistake or garbage
MAX_COORDINATE = 100.0
#: largest |component| of a requested normal (only its direction counts)
MAX_NORMAL_COMPONENT = 1e6


def _within(limit: float, unit: str, hint: str = "") -> AfterValidator:
    """A check that a number's magnitude is at most ``limit`` (``unit`` and ``hint`` for the
    message)."""

    def check(v: float) -> float:
        if abs(v) > limit:
            raise PydanticCustomError(
                "out_of_range",
                "expected |value| <= {limit}{unit}, got {value}{unit}{hint}",
                {"limit": f"{limit:g}", "unit": unit, "value": f"{v:g}", "hint": hint},
            )
        return v

    return AfterValidator(check)


Coordinate = Annotated[Num, _within(MAX_COORDINATE, " m", ": did you give millimetres?")]
Point = Annotated[list[Coordinate], exact_length(3)]
Direction = Annotated[list[Annotated[Num, _within(MAX_NORMAL_COMPONENT, "")]], exact_length(3)]


class TargetRequest(StrictModel):
    """Targets to plan for: ``points`` (+ optional unit ``normals``) in ``frame``.

    ``mode: path`` sweeps the points as one polyline; ``mode: track`` follows the target
    stream (``beamrelay/targets/stream``) whose ``id`` the first point names; ``execute``
    sends the trajectory to the robots after planning; ``trajectory`` plans it (from the
    robots' current state, as ``execute`` would) without sending it, for a preview.
    ``closed_loop`` corrects each target from the camera's measured spot until it is within
    ``tolerance`` (m; default the scenario's, 0.3 mm); ``dwell`` (s) holds the spot on each target with the laser on.
    Coordinates are bounded by :data:`MAX_COORDINATE` (m) and, as in a scenario file, by
    :func:`schemas.bounds.check_coordinates` (20 m: millimetres given as metres; in the
    camera frame, in front of the camera).
    """

    schema_: Literal["beamrelay.request/1"] = Field(alias="schema")
    id: Ident
    frame: Literal["world", "camera"] = "world"
    points: Annotated[list[Point], Field(min_length=1, max_length=MAX_REQUEST_POINTS)]
    normals: list[Direction] | None = None
    mode: Literal["points", "path", "track"] = "points"
    execute: StrictBool = False
    trajectory: StrictBool = False
    closed_loop: StrictBool = False
    dwell: Annotated[Num, Field(ge=0, le=MAX_DWELL)] | None = None
    tolerance: Annotated[Num, Field(gt=0, le=MAX_TOLERANCE)] | None = None
    duration: Annotated[Num, Field(gt=0, le=3600)] | None = None
    """``mode: track`` only: how long to follow the stream (s); default until ``stop``"""

    @model_validator(mode="after")
    def _normals(self) -> Self:
        check_normals(self.points, self.normals)
        self.normals = unit_normals(self.normals)
        if self.mode == "path" and len(self.points) < 2:
            raise FieldError(("points",), "a path needs at least 2 points")
        check_coordinates(self.points, ("points",), self.frame)  # a scenario file's bounds
        return self


class JointState(StrictModel):
    """A robot's measured joints at time ``t`` (published at >= 100 Hz)."""

    schema_: Literal["beamrelay.joint_state/1"] = Field(default=JOINT_STATE_SCHEMA, alias="schema")
    t: Num
    names: list[str]
    q: JointVector
    qd: JointVector

    @model_validator(mode="after")
    def _lengths(self) -> Self:
        for key in ("q", "qd"):
            n = len(getattr(self, key))
            if n != len(self.names):
                raise FieldError(
                    (key,), f"expected {len(self.names)} numbers (one per name), got {n}"
                )
        return self


def check_intervals(spans: list[list[float]], key: str, within: tuple[float, float]) -> None:
    """FieldError unless ``spans`` ([t0, t1] s) are ordered, disjoint and inside ``within``."""
    for k, (t0, t1) in enumerate(spans):
        if not t0 <= t1:
            raise FieldError((key, k), f"ends ({t1:g} s) before it starts ({t0:g} s)")
        if k and t0 < spans[k - 1][1]:
            raise FieldError((key, k), "intervals must be in order, not overlapping")
        if t0 < within[0] or t1 > within[1]:
            raise FieldError((key, k), f"[{t0:g}, {t1:g}] s is outside the "
                             f"trajectory's [{within[0]:g}, {within[1]:g}] s")  # fmt: skip


class JointTrajectory(StrictModel):
    """A trajectory for one robot: ``q[k]`` (rad) at ``t[k]`` (s from its start).

    ``id`` is the request it executes; ``session`` the planner session (its heartbeat's
    ``session``) that sent it: the driver follows that planner's heartbeat while it moves.
    """

    schema_: Literal["beamrelay.trajectory/1"] = Field(default=TRAJECTORY_SCHEMA, alias="schema")
    robot: str
    id: Ident | None = None
    session: Ident | None = None
    t: Annotated[list[Num], Field(min_length=1)]
    names: list[str]
    q: list[JointVector]
    qd: list[JointVector]
    qdd: list[JointVector]
    laser_on: (
        Annotated[
            list[Annotated[list[Num], exact_length(2)]], Field(max_length=MAX_LASER_INTERVALS)
        ]
        | None
    ) = None
    """for the robot whose digital output gates the laser: the intervals ``[t0, t1]`` (s, on
    the ``t`` axis) in which the gate is on; off outside them"""
    aim_on: (
        Annotated[
            list[Annotated[list[Num], exact_length(2)]], Field(max_length=MAX_LASER_INTERVALS)
        ]
        | None
    ) = None
    """likewise for the aiming (pilot) beam (``laser.aim``): the intervals in which it is on,
    for measurements; the treatment gate stays off in them unless ``laser_on`` says so"""

    @model_validator(mode="after")
    def _shapes(self) -> Self:
        for k in range(1, len(self.t)):
            if self.t[k] <= self.t[k - 1]:
                raise FieldError(("t", k), "times must increase")
        for key in ("laser_on", "aim_on"):
            check_intervals(getattr(self, key) or [], key, (self.t[0], self.t[-1]))
        for key in ("q", "qd", "qdd"):
            rows: list[list[float]] = getattr(self, key)
            if len(rows) != len(self.t):
                raise FieldError(
                    (key,), f"expected {len(self.t)} rows (one per t), got {len(rows)}"
                )
            for k, row in enumerate(rows):
                if len(row) != len(self.names):
                    raise FieldError(
                        (key, k), f"expected {len(self.names)} numbers, got {len(row)}"
                    )
        return self


class TrajectoryAck(StrictModel):
    """A driver's verdict on the trajectory with request ``id``: accepted, or rejected with
    the reason (``"<field>: <what>"``, e.g. ``"q[12]: joint wrist_3 moves 0.5 rad in 2 ms"``)."""

    id: str | None = None
    accepted: StrictBool
    reason: str | None = None
    t: Num


class StreamAck(StrictModel):
    """A driver's view of the latest setpoint stream (``beamrelay/<robot>/setpoint``) of
    planner ``session`` and request ``id``.

    ``state``: ``streaming`` (being followed), ``ended`` (no setpoint for 50 ms, a stop, a
    heartbeat loss, a fault, or replaced by a trajectory), ``rejected`` (a setpoint, or a body
    on the key, broke a rule: the stream ended, or never started when it was its first).
    ``reason`` says why it ended (``"<field>: <what>"`` with the figures, e.g. ``"q: wrist_3
    moves 0.0500 rad in 0.0020 s since seq 41 = 25.0 rad/s > 3.1416 rad/s"``); ``braked``
    whether the arm was moving then (it braked with the stop deceleration; else it rests on
    the last setpoint). ``seq`` is the last setpoint followed, ``n`` how many were; ``t`` the
    UNIX time of the last change of state.
    """

    id: str | None = None
    session: str | None = None
    state: Literal["streaming", "ended", "rejected"]
    reason: str | None = None
    braked: StrictBool = False
    seq: NonNegInt | None = None
    n: NonNegInt = 0
    t: Num


class RobotStatus(StrictModel):
    """Controller state: ``mode`` (driver-defined text), protective stop flag, fault text.

    ``trajectory`` is the verdict on the latest trajectory received (published at once on
    receipt, then repeated with every status); ``stream`` likewise for setpoint streams
    (published at once when a stream starts, is rejected or ends).
    """

    schema_: Literal["beamrelay.status/1"] = Field(default=STATUS_SCHEMA, alias="schema")
    robot: str
    t: Num
    mode: str
    protective_stop: StrictBool = False
    fault: str | None = None
    trajectory: TrajectoryAck | None = None
    stream: StreamAck | None = None
    laser_on: StrictBool | None = None
    """the laser gate's state, from the driver of the robot that switches it (else null)"""
    safety_mode: str | None = None  # the controller's safety mode (normal, reduced, ...)


class RecoverRequest(StrictModel):
    """An operator's request to recover a UR robot from a protective stop (on
    ``<prefix>/<robot>/recover``; ``t`` UNIX s, ``operator`` who asked)."""

    schema_: Literal["beamrelay.recover/1"] = Field(default=RECOVER_SCHEMA, alias="schema")
    robot: str
    t: Num
    operator: Annotated[str, Field(max_length=200)] = ""


#: largest recover body read (bytes); a longer one is refused unread
MAX_RECOVER_BYTES: Final = 4096


def parse_recover(payload: bytes, robot: str) -> str:
    """The operator text of a valid recover request for ``robot`` (what the UR driver acts
    on and the supervisor logs); ValueError otherwise."""

    if len(payload) > MAX_RECOVER_BYTES:
        raise ValueError(f"recover body of {len(payload)} bytes > {MAX_RECOVER_BYTES}")
    try:
        body = RecoverRequest.model_validate_json(payload)
    except ValidationError as exc:
        raise ValueError(f"not a {RECOVER_SCHEMA} body: {exc.errors()[0]['msg']}") from None
    if body.robot != robot:
        raise ValueError(f"recover request for {body.robot!r}, this is {robot!r}")
    return body.operator


class LaserState(StrictModel):
    """The laser gate as its robot driver last switched it (published on ``<prefix>/laser``
    at every switch and with every status): ``on`` (the treatment gate), ``aim`` (the aiming
    beam; None without ``laser.aim``), the digital ``output`` index, why it
    changed, and the switching figures of the last switch: ``lag`` (s of trajectory time
    between the interval's edge and the control period that switched) and ``latency`` (s
    from the start of that period to the output command). ``t`` is UNIX time."""

    schema_: Literal["beamrelay.laser/1"] = Field(default=LASER_SCHEMA, alias="schema")
    robot: str
    t: Num
    on: StrictBool
    aim: StrictBool | None = None
    output: NonNegInt | None = None
    reason: str | None = None
    lag: Num | None = None
    latency: Num | None = None


class Heartbeat(StrictModel):
    """The planner's heartbeat (>= 50 Hz): ``session`` is random per planner process,
    ``seq`` counts up from 0, ``t`` is the sender's UNIX time (s)."""

    schema_: Literal["beamrelay.heartbeat/1"] = Field(default=HEARTBEAT_SCHEMA, alias="schema")
    t: Num
    session: Ident
    seq: NonNegInt


class StopMessage(StrictModel):
    """What ``beamrelay/stop`` carries when we send it. Nodes stop on *any* sample on that
    key, whatever its body (a stop must never be lost to a parse error)."""

    schema_: Literal["beamrelay.stop/1"] = Field(default=STOP_SCHEMA, alias="schema")
    t: Num
    source: str = ""
    reason: str = ""


class SpotMessage(StrictModel):
    """Detected laser spot in the camera optical frame (m), or null when none was seen."""

    schema_: Literal["beamrelay.spot/1"] = Field(default=SPOT_SCHEMA, alias="schema")
    t: Num
    p_camera: Vec3 | None = None
    confidence: Annotated[Num, Field(ge=0, le=1)] = 0.0


class Setpoint(StrictModel):
    """One streamed joint setpoint for ``robot`` (``beamrelay/<robot>/setpoint``): positions
    ``q`` (rad) and velocities ``qd`` (rad/s) to be reached at ``t`` (UNIX s, sender's clock).
    ``session`` is the planner session (its heartbeat's); ``seq`` counts up per stream;
    ``laser_on`` asks the gating robot's driver for the treatment gate with this setpoint,
    ``aim`` for the aiming beam (measurements, tracking acquisition). The
    driver follows within its limits and stops when no setpoint arrived for 50 ms."""

    schema_: Literal["beamrelay.setpoint/1"] = Field(default=SETPOINT_SCHEMA, alias="schema")
    robot: str
    t: Num
    session: Ident
    seq: NonNegInt
    id: Ident | None = None
    q: JointVector
    qd: JointVector
    laser_on: StrictBool = False
    aim: StrictBool = False

    @model_validator(mode="after")
    def _lengths(self) -> Self:
        if len(self.qd) != len(self.q):
            raise FieldError(("qd",), f"expected {len(self.q)} numbers (as q), got {len(self.qd)}")
        return self


class TargetStream(StrictModel):
    """A tracker's latest estimate of a moving target (``beamrelay/targets/stream``): ``points``
    (m, world frame) with optional unit ``normals``, measured at ``t`` (UNIX s, the camera
    frame's capture time, not the send time). ``id`` names the tracked target."""

    schema_: Literal["beamrelay.target_stream/1"] = Field(
        default=TARGET_STREAM_SCHEMA, alias="schema"
    )
    t: Num
    id: Ident
    frame: Literal["world", "camera"] = "world"
    points: Annotated[list[Point], Field(min_length=1, max_length=MAX_REQUEST_POINTS)]
    normals: list[Direction] | None = None

    @model_validator(mode="after")
    def _normals(self) -> Self:
        check_normals(self.points, self.normals)
        self.normals = unit_normals(self.normals)
        return self


class CalibrationMessage(StrictModel):
    """The planner's current calibration after an online refinement (``beamrelay/calibration``):
    ``calibration`` is the calibration YAML document (``system:`` + ``report:``) as JSON,
    ``version`` counts refits from 1, ``samples`` is how many measured spots it used."""

    schema_: Literal["beamrelay.calibration/1"] = Field(default=CALIBRATION_SCHEMA, alias="schema")
    t: Num
    version: NonNegInt
    samples: NonNegInt
    calibration: dict[str, object]


class ErrorReply(StrictModel):
    """Reply to an invalid request: ``field`` is the offending key path (``points[3]``)."""

    schema_: Literal["beamrelay.error/1"] = Field(default=ERROR_SCHEMA, alias="schema")
    id: str | None = None
    error: str
    field: str | None = None
