"""Calibration datasets and output (SPEC section 7).

Points in metres, joints in rad. ``points_camera`` / ``spot_camera`` are in the camera's
optical frame, ``spot_world`` and ``board.points`` as named (board points in the board's own
frame).
"""

from __future__ import annotations

from typing import Annotated, Any, Literal, Self

from pydantic import Field, model_validator

from schemas.common import FieldError, JointVector, NonNegInt, StrictModel, Vec3
from schemas.scenario import PartialSystem

HANDEYE_SCHEMA = "beamrelay.handeye/1"
BEAM_SCHEMA = "beamrelay.beam/1"


class Board(StrictModel):
    """Marker points (m) in the board's own frame."""

    points: Annotated[list[Vec3], Field(min_length=3)]


class HandEyeSample(StrictModel):
    """Robot joints and the board markers as the camera saw them (null = not seen)."""

    q: JointVector
    points_camera: list[Vec3 | None]


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


class CalibrationFile(StrictModel):
    """Calibration output, includable by a scenario: a partial ``system`` and a ``report``."""

    system: PartialSystem = Field(default_factory=PartialSystem)
    report: dict[str, Any] = Field(default_factory=dict)
