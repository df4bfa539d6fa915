"""Where the spot should go: points (with normals), a grid or a path, in a named frame.

Coordinates in metres, in ``frame`` (``world``, or ``camera`` = the camera's OpenCV optical
frame); normals are unit vectors (normalised on load) in the same frame.
"""

from __future__ import annotations

from typing import Annotated, Literal, Self

from pydantic import Field, StrictBool, model_validator

from schemas import defaults
from schemas.bounds import check_coordinates, check_length_scale
from schemas.common import (
    FieldError,
    NonNegNum,
    PosInt,
    PosNum,
    StrictModel,
    Vec3,
    exact_length,
    unit_rows,
)

NonNegVec3 = Annotated[list[NonNegNum], exact_length(3)]
Points = Annotated[list[Vec3], Field(min_length=1)]


def check_normals(points: list[list[float]], normals: list[list[float]] | None) -> None:
    if normals is not None and len(normals) != len(points):
        raise FieldError(
            ("normals",), f"expected {len(points)} normals (one per point), got {len(normals)}"
        )


def unit_normals(normals: list[list[float]] | None) -> list[list[float]] | None:
    """Normalise normals; a zero one is an error at ``normals[i]``."""
    if normals is None:
        return None
    try:
        return unit_rows(normals)
    except FieldError as exc:
        raise FieldError(("normals", *exc.loc), exc.reason) from None


class GridSpec(StrictModel):
    """``n[i]`` points per axis from ``center - size/2`` to ``center + size/2`` (m)."""

    center: Vec3
    size: NonNegVec3
    n: Annotated[list[PosInt], exact_length(3, "integers")]


class PathSpec(StrictModel):
    """A polyline swept continuously, resampled every ``spacing`` m (closed: back to start).

    ``normals`` are per vertex and interpolated between vertices. Where the direction turns
    by more than ``corner_deg`` (degrees) the corner is marked sharp (laser off at the vertex,
    run out, turn, run in); smaller turns are swept continuously. ``smooth`` reads the points
    as samples of a smooth curve through them (no corners).
    """

    points: Annotated[list[Vec3], Field(min_length=2)]
    normals: list[Vec3] | None = None
    closed: StrictBool = False
    spacing: PosNum = defaults.PATH_SPACING_M
    corner_deg: Annotated[PosNum, Field(le=180)] = 20.0
    smooth: StrictBool = False

    @model_validator(mode="after")
    def _normals(self) -> Self:
        check_normals(self.points, self.normals)
        self.normals = unit_normals(self.normals)
        return self


class TargetSpec(StrictModel):
    """Where the spot should go: exactly one of ``points`` (+``normals``), ``grid``, ``path``.

    Coordinates are in ``frame`` (``world``, or ``camera`` = the camera's optical frame).
    ``order: optimal`` (default; ``optimized`` is the same) lets the planner reorder
    points/grid targets, ``given`` keeps the file order.
    """

    frame: Literal["world", "camera"] = "world"
    points: Points | None = None
    normals: list[Vec3] | None = None
    grid: GridSpec | None = None
    path: PathSpec | None = None
    order: Literal["optimal", "optimized", "given"] = "optimal"

    @model_validator(mode="after")
    def _one_kind(self) -> Self:
        given = [k for k in ("points", "grid", "path") if getattr(self, k) is not None]
        if not given:
            raise ValueError("needs one of points, grid, path")
        if len(given) > 1:
            raise FieldError((given[1],), f"give only one of {', '.join(given)}")
        if self.normals is not None:
            if self.points is None:
                raise FieldError(("normals",), "only allowed with points")
            check_normals(self.points, self.normals)
            self.normals = unit_normals(self.normals)
        self._plausible()
        return self

    def _plausible(self) -> None:
        if self.points is not None:
            check_coordinates(self.points, ("points",), "world")
        if self.path is not None:
            check_coordinates(self.path.points, ("path", "points"), "world")
        if self.grid is not None:
            check_length_scale(self.grid.center, ("grid", "center"))
            check_length_scale(self.grid.size, ("grid", "size"))

    @property
    def kind(self) -> str:
        return "points" if self.points is not None else "grid" if self.grid is not None else "path"
