"""Calibration datasets and output (docs/conventions.md: Calibration data).

Points in metres, joints in rad. ``points_camera`` / ``spot_camera`` are in the camera's
optical frame, ``spot_world`` and ``board.points`` as named (board points in the board's own
frame).
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal, Self

from pydantic import Field, model_validator

from schemas.bounds import behind_camera, check_joint_angle, check_length_scale
from schemas.common import MAX_FLANGE_M, FieldError, JointVector, NonNegInt, StrictModel, Vec3
from schemas.scenario import PartialSystem

HANDEYE_SCHEMA = "beamrelay.handeye/1"
BEAM_SCHEMA = "beamrelay.beam/1"


class Board(StrictModel):
    """Marker points (m) in the board's own frame."""

    points: Annotated[list[Vec3], Field(min_length=3)]

    @model_validator(mode="after")
    def _metres(self) -> Self:
        for i, p in enumerate(self.points):
            if max(abs(x) for x in p) > MAX_FLANGE_M:
                raise FieldError(
                    ("points", i),
                    f"{p} is more than {MAX_FLANGE_M:g} m from the board's origin: did you"
                    " give millimetres? (metres)",
                )
        return self


def check_camera_point(p: list[float], loc: tuple[str | int, ...], hint: str) -> None:
    """A point seen by the camera (m, optical frame): in front of it, plausibly far."""
    check_length_scale(p, loc)
    if p[2] <= 0:
        raise FieldError(loc, behind_camera(p[2], hint))


def check_joints(q: list[float], loc: tuple[str | int, ...]) -> None:
    for j, v in enumerate(q):
        check_joint_angle(v, (*loc, j))


class HandEyeSample(StrictModel):
    """Robot joints and the board markers as the camera saw them (null = not seen)."""

    q: JointVector
    points_camera: list[Vec3 | None]

    @model_validator(mode="after")
    def _plausible(self) -> Self:
        check_joints(self.q, ("q",))
        for i, p in enumerate(self.points_camera):
            if p is not None:
                check_camera_point(p, ("points_camera", i), "points in another frame?")
        return self


class HandEyeDataset(StrictModel):
    """Hand-eye data. eye_to_hand: camera fixed, board on the flange; eye_in_hand: the reverse."""

    schema_: Literal["beamrelay.handeye/1"] = Field(alias="schema")
    robot: Annotated[str, Field(min_length=1)]
    mode: Literal["eye_to_hand", "eye_in_hand"]
    board: Board
    samples: Annotated[list[HandEyeSample], Field(min_length=1)]

    @model_validator(mode="after")
    def _shapes(self) -> Self:
        n = len(self.board.points)
        for i, s in enumerate(self.samples):
            if len(s.points_camera) != n:
                raise FieldError(
                    ("samples", i, "points_camera"),
                    f"expected {n} entries (one per board point), got {len(s.points_camera)}",
                )
        return self


class BeamSample(StrictModel):
    """Joints of every robot up to the calibrated one, and the spot seen on board ``board``."""

    q: dict[str, JointVector]
    spot_world: Vec3 | None = None
    spot_camera: Vec3 | None = None
    board: NonNegInt = 0

    @model_validator(mode="after")
    def _one_spot(self) -> Self:
        if (self.spot_world is None) == (self.spot_camera is None):
            raise ValueError("give exactly one of spot_world, spot_camera")
        for name, q in self.q.items():
            check_joints(q, ("q", name))
        if self.spot_world is not None:
            check_length_scale(self.spot_world, ("spot_world",))
        if self.spot_camera is not None:
            check_camera_point(
                self.spot_camera, ("spot_camera",), "world coordinates? then write spot_world"
            )
        return self


class BeamDataset(StrictModel):
    """Laser-spot data for the mirror plane of ``robot`` (and the laser line if it is first)."""

    schema_: Literal["beamrelay.beam/1"] = Field(alias="schema")
    robot: Annotated[str, Field(min_length=1)]
    samples: Annotated[list[BeamSample], Field(min_length=1)]

    @model_validator(mode="after")
    def _robot_present(self) -> Self:
        for i, s in enumerate(self.samples):
            if self.robot not in s.q:
                raise FieldError(("samples", i, "q"), f"has no joints for robot {self.robot!r}")
        return self


def report_spot_uncertainty(report: Any) -> float:
    """The spot uncertainty (m) a calibration ``report`` gives: its ``spot_uncertainty``,
    else for a beam calibration the RMS of its spot residuals (from ``residuals.mean`` and
    ``residuals.std``: sqrt(mean^2 + std^2)), else 0 (a hand-eye result reports none)."""
    if not isinstance(report, dict):
        return 0.0
    value = report.get("spot_uncertainty")
    if isinstance(value, int | float) and not isinstance(value, bool):
        return max(float(value), 0.0)
    res = report.get("residuals")
    if report.get("kind") != "beam" or not isinstance(res, dict):
        return 0.0
    mean, std = res.get("mean"), res.get("std")
    if not all(isinstance(x, int | float) and math.isfinite(x) for x in (mean, std)):
        return 0.0
    return math.hypot(float(mean), float(std))  # type: ignore[arg-type]


class CalibrationFile(StrictModel):
    """Calibration output, includable by a scenario: a partial ``system`` and a ``report``."""

    system: PartialSystem = Field(default_factory=PartialSystem)
    report: dict[str, Any] = Field(default_factory=dict)
