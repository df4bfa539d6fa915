"""The scenario file (SPEC section 4): system, scene, targets, solver and trajectory settings.

All lengths in metres, angles in radians unless the key ends in ``_deg``; every pose is
``parent_T_child`` with the world frame as parent unless its name says otherwise. The
``Partial*`` models describe ``truth.system`` and ``include:`` files: the same keys, all
optional (robots still need their ``name``, by which they are matched).
"""

from __future__ import annotations

from typing import Annotated, Literal, Self

from pydantic import Field, StrictBool, field_validator, model_validator

from schemas.common import (
    FieldError,
    JointVector,
    NonNegNum,
    Num,
    Pose,
    PosInt,
    PosNum,
    StrictModel,
    Vec3,
    exact_length,
    unit_rows,
)

UR_NQ = 6
PosVec2 = Annotated[list[PosNum], exact_length(2)]
PosVec3 = Annotated[list[PosNum], exact_length(3)]
NonNegVec3 = Annotated[list[NonNegNum], exact_length(3)]
Points = Annotated[list[Vec3], Field(min_length=1)]
Name = Annotated[str, Field(min_length=1)]


# --- system -------------------------------------------------------------------------------
class Laser(StrictModel):
    """The fixed laser: the beam exits at the origin of ``world_T_laser`` along its +z."""

    world_T_laser: Pose


class Limits(StrictModel):
    """Per-joint limits (rad, rad/s, rad/s^2, rad/s^3); each list optional (UR defaults)."""

    lower: JointVector | None = None
    upper: JointVector | None = None
    velocity: JointVector | None = None
    acceleration: JointVector | None = None
    jerk: JointVector | None = None

    @model_validator(mode="after")
    def _consistent(self) -> Self:
        for name in ("velocity", "acceleration", "jerk"):
            for i, v in enumerate(getattr(self, name) or []):
                if v <= 0:
                    raise FieldError((name, i), f"must be > 0, got {v:g}")
        if self.lower is not None and self.upper is not None:
            for i, (lo, hi) in enumerate(zip(self.lower, self.upper, strict=False)):
                if lo >= hi:
                    raise FieldError(("upper", i), f"must be above lower ({lo:g}), got {hi:g}")
        return self


class Mirror(StrictModel):
    """A flat mirror: centre and outward normal (+z) from ``flange_T_mirror``.

    ``size`` is the full ``[w, h]`` along mirror x/y (m); the beam must stay ``roi_margin``
    (m) inside the edges.
    """

    flange_T_mirror: Pose
    size: PosVec2
    roi_margin: NonNegNum = 0.005

    @model_validator(mode="after")
    def _margin_fits(self) -> Self:
        if 2 * self.roi_margin >= min(self.size):
            if "roi_margin" in self.model_fields_set:
                raise FieldError(("roi_margin",), f"{self.roi_margin:g} m leaves no usable area")
            raise FieldError(("size",), f"leaves no area inside roi_margin {self.roi_margin:g}")
        return self


def check_joint_lengths(home: list[float] | None, limits: Limits | None, nq: int) -> None:
    """Raise :class:`FieldError` when ``home`` or a limits list has not ``nq`` entries."""
    vectors: list[tuple[tuple[str, ...], list[float] | None]] = [(("home",), home)]
    if limits is not None:
        for key in ("lower", "upper", "velocity", "acceleration", "jerk"):
            vectors.append((("limits", key), getattr(limits, key)))
    for loc, values in vectors:
        if values is not None and len(values) != nq:
            raise FieldError(loc, f"expected {nq} numbers (one per joint), got {len(values)}")


class Robot(StrictModel):
    """One arm holding a mirror, its base at ``world_T_base`` (default: the world frame).

    ``model`` (default ``ur5e``) or ``urdf`` (a path relative to the scenario file) gives the
    kinematics; ``home`` is the start configuration in rad.
    """

    name: Name
    model: Literal["ur5e"] | None = None
    urdf: Name | None = None
    world_T_base: Pose = Field(default_factory=Pose)
    home: JointVector | None = None
    limits: Limits | None = None
    mirror: Mirror

    @model_validator(mode="after")
    def _model_xor_urdf(self) -> Self:
        if self.model is not None and self.urdf is not None:
            raise FieldError(("urdf",), "give either model or urdf, not both")
        if self.urdf is None:
            check_joint_lengths(self.home, self.limits, UR_NQ)
        return self


class Intrinsics(StrictModel):
    """Pinhole intrinsics in pixels (OpenCV convention)."""

    width: PosInt
    height: PosInt
    fx: PosNum
    fy: PosNum
    cx: Num
    cy: Num


class Camera(StrictModel):
    """The RGB-D camera: ``world_T_camera`` is its OpenCV optical frame (z forward)."""

    world_T_camera: Pose
    intrinsics: Intrinsics


def check_unique_names(names: list[str], what: str) -> None:
    seen: dict[str, int] = {}
    for i, name in enumerate(names):
        if name in seen:
            raise FieldError(
                (i, "name"), f"duplicate {what} name {name!r} (also at [{seen[name]}])"
            )
        seen[name] = i


class System(StrictModel):
    """Laser, robots in beam order (robot 0's mirror is hit first), optional camera."""

    laser: Laser
    robots: Annotated[list[Robot], Field(min_length=1)]
    camera: Camera | None = None

    @field_validator("robots")
    @classmethod
    def _unique(cls, robots: list[Robot]) -> list[Robot]:
        check_unique_names([r.name for r in robots], "robot")
        return robots


# --- partial system (include files, truth) --------------------------------------------------
class PartialLaser(StrictModel):
    world_T_laser: Pose | None = None


class PartialMirror(StrictModel):
    flange_T_mirror: Pose | None = None
    size: PosVec2 | None = None
    roi_margin: NonNegNum | None = None


class PartialRobot(StrictModel):
    """A robot override, matched to the scenario's robot of the same ``name``."""

    name: Name
    model: Literal["ur5e"] | None = None
    urdf: Name | None = None
    world_T_base: Pose | None = None
    home: JointVector | None = None
    limits: Limits | None = None
    mirror: PartialMirror | None = None


class PartialIntrinsics(StrictModel):
    width: PosInt | None = None
    height: PosInt | None = None
    fx: PosNum | None = None
    fy: PosNum | None = None
    cx: Num | None = None
    cy: Num | None = None


class PartialCamera(StrictModel):
    world_T_camera: Pose | None = None
    intrinsics: PartialIntrinsics | None = None


class PartialSystem(StrictModel):
    """``system`` keys, all optional: merged key by key over a scenario's ``system``."""

    laser: PartialLaser | None = None
    robots: list[PartialRobot] | None = None
    camera: PartialCamera | None = None

    @field_validator("robots")
    @classmethod
    def _unique(cls, robots: list[PartialRobot] | None) -> list[PartialRobot] | None:
        check_unique_names([r.name for r in robots or []], "robot")
        return robots


class Truth(StrictModel):
    """Simulation only: the real geometry the simulated drivers use (partial ``system``)."""

    system: PartialSystem


# --- scene --------------------------------------------------------------------------------
SHAPE_KEYS = ("box", "mesh", "sphere", "cylinder")


class SceneObject(StrictModel):
    """A named object in the scene: exactly one shape, in the frame ``world_T_object``.

    ``box``: full extents [x, y, z] centred on the frame; ``sphere``: radius; ``cylinder``:
    [radius, height] along z, centred; ``mesh``: PLY/OBJ/STL path (relative to the scenario)
    in object coordinates times ``scale``.
    """

    name: Name
    box: PosVec3 | None = None
    mesh: Name | None = None
    scale: PosNum | None = None
    sphere: PosNum | None = None
    cylinder: PosVec2 | None = None
    world_T_object: Pose = Field(default_factory=Pose)

    @model_validator(mode="after")
    def _one_shape(self) -> Self:
        given = [k for k in SHAPE_KEYS if getattr(self, k) is not None]
        if not given:
            raise ValueError(f"needs one shape: {', '.join(SHAPE_KEYS)}")
        if len(given) > 1:
            raise FieldError((given[1],), f"give only one shape of {', '.join(given)}")
        if self.scale is not None and self.mesh is None:
            raise FieldError(("scale",), "only allowed with mesh")
        return self

    @property
    def shape(self) -> str:
        return next(k for k in SHAPE_KEYS if getattr(self, k) is not None)


# --- targets ------------------------------------------------------------------------------
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

    ``normals`` are per vertex and interpolated between vertices.
    """

    points: Annotated[list[Vec3], Field(min_length=2)]
    normals: list[Vec3] | None = None
    closed: StrictBool = False
    spacing: PosNum = 0.001

    @model_validator(mode="after")
    def _normals(self) -> Self:
        check_normals(self.points, self.normals)
        self.normals = unit_normals(self.normals)
        return self


class TargetSpec(StrictModel):
    """Where the spot should go: exactly one of ``points`` (+``normals``), ``grid``, ``path``.

    Coordinates are in ``frame`` (``world``, or ``camera`` = the camera's optical frame).
    ``order: optimized`` lets the planner reorder points/grid targets.
    """

    frame: Literal["world", "camera"] = "world"
    points: Points | None = None
    normals: list[Vec3] | None = None
    grid: GridSpec | None = None
    path: PathSpec | None = None
    order: Literal["optimized", "given"] = "optimized"

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
        return self

    @property
    def kind(self) -> str:
        return "points" if self.points is not None else "grid" if self.grid is not None else "path"


# --- settings -----------------------------------------------------------------------------
class Solver(StrictModel):
    """IK settings: ``tolerance`` is a spot error (m); ``max_incidence_deg`` in degrees."""

    tolerance: PosNum = 1e-9
    max_iter: PosInt = 200
    max_incidence_deg: Annotated[PosNum, Field(le=90)] = 80.0


class TrajectorySettings(StrictModel):
    """Path timing: spot speed (m/s), dwell per target (s), sample rate (Hz)."""

    spot_speed: PosNum = 0.02
    dwell: NonNegNum = 0.0
    rate: PosNum = 500.0


class Scenario(StrictModel):
    """A whole scenario file. ``include`` paths are relative to the file that names them."""

    name: Name | None = None
    system: System
    scene: list[SceneObject] = Field(default_factory=list)
    targets: TargetSpec
    solver: Solver = Field(default_factory=Solver)
    trajectory: TrajectorySettings = Field(default_factory=TrajectorySettings)
    include: list[Name] = Field(default_factory=list)
    truth: Truth | None = None

    @field_validator("scene")
    @classmethod
    def _unique(cls, scene: list[SceneObject]) -> list[SceneObject]:
        check_unique_names([o.name for o in scene], "scene object")
        return scene

    @model_validator(mode="after")
    def _camera_frame(self) -> Self:
        if self.targets.frame == "camera" and self.system.camera is None:
            raise FieldError(("targets", "frame"), "is camera but system.camera is not given")
        if self.truth is not None:
            names = {r.name for r in self.system.robots}
            for i, r in enumerate(self.truth.system.robots or []):
                if r.name not in names:
                    raise FieldError(
                        ("truth", "system", "robots", i, "name"), f"no robot named {r.name!r}"
                    )
        return self
