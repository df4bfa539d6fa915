"""The scenario file (docs/conventions.md): system, scene, targets, solver and trajectory settings.

All lengths in metres, angles in radians unless the key ends in ``_deg``; every pose is
``parent_T_child`` with the world frame as parent unless its name says otherwise. The
``Partial*`` models describe ``truth.system`` and ``include:`` files: the same keys, all
optional (robots still need their ``name``, by which they are matched).
"""
# long module: the scenario is one pydantic document (SPEC section 4); its models validate against each other

from __future__ import annotations

from typing import Annotated, Literal, Self

from pydantic import Field, field_validator, model_validator

from schemas import defaults
from schemas.bounds import (
    MAX_SPOT_SPEED,
    MAX_TOLERANCE,
    check_camera_mount,
    check_in_front,
    check_joint_angle,
    check_limit_values,
    check_mirror,
    check_robot,
)
from schemas.common import (
    MAX_WORLD_M,
    FieldError,
    JointVector,
    NonNegInt,
    NonNegNum,
    Num,
    Pose,
    PosInt,
    PosNum,
    StrictModel,
    check_translation,
    exact_length,
)
from schemas.motion import Motion
from schemas.targets import GridSpec as GridSpec
from schemas.targets import PathSpec as PathSpec
from schemas.targets import TargetSpec
from schemas.targets import check_normals as check_normals
from schemas.targets import unit_normals as unit_normals

UR_NQ = 6
PosVec2 = Annotated[list[PosNum], exact_length(2)]
PosVec3 = Annotated[list[PosNum], exact_length(3)]
Name = Annotated[str, Field(min_length=1)]
MAX_LASER_POWER_W = 1000.0
"""A laser power (W) above this is no laser a lab steers with mirrors on arms."""
MAX_BEAM_RADIUS_M = 0.02
"""A beam radius (m) above this is a unit mistake (mm given as m)."""


# --- system -------------------------------------------------------------------------------
class LaserGate(StrictModel):
    """The digital output (index ``output``) of robot ``robot`` that switches the laser."""

    robot: Name
    output: Annotated[NonNegInt, Field(le=7)] = 0


class LaserLimits(StrictModel):
    """Emission limits the gate's driver enforces whatever it is sent: the longest
    continuous treatment on-time ``max_on`` (s), the energy at one spot ``max_spot_energy``
    (J: one continuous on-interval) and in one driver session ``max_session_energy`` (J).
    The energies need ``laser.power``."""

    max_on: PosNum | None = None
    max_spot_energy: PosNum | None = None
    max_session_energy: PosNum | None = None


class Laser(StrictModel):
    """The fixed laser: the beam exits at the origin of ``world_T_laser`` along its +z.
    ``power`` (W, optional) gives the plan's exposure figures; ``gate`` names the robot
    digital output that switches the treatment beam, ``aim`` the coaxial aiming (pilot)
    beam's output on the same robot, or ``"gate"`` when the only laser is a low-power
    diagnostic diode (then measurements switch the gate); ``limits`` the emission limits;
    ``beam_radius`` (m) inflates keep-out and beam-vs-arm checks."""

    world_T_laser: Pose
    power: Annotated[PosNum, Field(le=MAX_LASER_POWER_W)] | None = None
    gate: LaserGate | None = None
    aim: LaserGate | Literal["gate"] | None = None
    limits: LaserLimits = Field(default_factory=LaserLimits)
    beam_radius: Annotated[NonNegNum, Field(le=MAX_BEAM_RADIUS_M)] = 0.0

    @model_validator(mode="after")
    def _plausible(self) -> Self:
        check_translation(self.world_T_laser, "world_T_laser", MAX_WORLD_M)
        return self

    @model_validator(mode="after")
    def _aim_and_limits(self) -> Self:
        aim, gate = self.aim, self.gate
        if aim is not None and gate is None:
            raise FieldError(("aim",), "needs laser.gate (the aim beam is switched by the "
                             "gate's driver)")  # fmt: skip
        if isinstance(aim, LaserGate) and gate is not None:
            if aim.robot != gate.robot:
                raise FieldError(("aim", "robot"), f"must be the gate's robot "
                                 f"{gate.robot!r} (one driver switches both), got {aim.robot!r}")  # fmt: skip
            if aim.output == gate.output:
                raise FieldError(("aim", "output"), f"must differ from the gate's output "
                                 f"{gate.output}; write aim: gate for a one-laser rig")  # fmt: skip
        for key in ("max_spot_energy", "max_session_energy"):
            if getattr(self.limits, key) is not None and self.power is None:
                raise FieldError(("limits", key), "needs laser.power (W)")
        return self


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
            check_limit_values(name, getattr(self, name))
        for name in ("lower", "upper"):
            for i, v in enumerate(getattr(self, name) or []):
                check_joint_angle(v, (name, i))
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
    roi_margin: NonNegNum = defaults.ROI_MARGIN_M

    @model_validator(mode="after")
    def _margin_fits(self) -> Self:
        check_mirror(self.size, self.roi_margin, self.flange_T_mirror)
        if 2 * self.roi_margin >= min(self.size):
            half = min(self.size) / 2
            if "roi_margin" in self.model_fields_set:
                raise FieldError(
                    ("roi_margin",),
                    f"{self.roi_margin:g} m is not below half the mirror ({half:g} m):"
                    " it leaves no usable area",
                )
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

    ``model`` (a registered robot model, default ``ur5e``; checked when the scenario is
    loaded) or ``urdf`` (a path relative to the scenario file) gives the kinematics; ``home``
    is the start configuration in rad.
    """

    name: Name
    model: Name | None = None
    urdf: Name | None = None
    world_T_base: Pose = Field(default_factory=Pose)
    home: JointVector | None = None
    limits: Limits | None = None
    mirror: Mirror

    @model_validator(mode="after")
    def _model_xor_urdf(self) -> Self:
        if self.model is not None and self.urdf is not None:
            raise FieldError(("urdf",), "give either model or urdf, not both")
        if self.urdf is None and self.model in (None, "ur5e"):
            check_joint_lengths(self.home, self.limits, UR_NQ)
        check_robot(self.home, self.world_T_base)
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
    """The RGB-D camera, OpenCV optical frame (x right, y down, z forward).

    Either fixed, ``world_T_camera``, or carried by a robot (eye-in-hand): ``robot`` names
    it and ``flange_T_camera`` is the camera's pose on its flange.
    """

    world_T_camera: Pose | None = None
    robot: Name | None = None
    flange_T_camera: Pose | None = None
    intrinsics: Intrinsics

    @model_validator(mode="after")
    def _one_mount(self) -> Self:
        check_camera_mount(self.world_T_camera, self.robot, self.flange_T_camera, partial=False)
        return self


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

    @model_validator(mode="after")
    def _camera_robot(self) -> Self:
        names = [r.name for r in self.robots]
        cam = self.camera
        if cam is not None and cam.robot is not None and cam.robot not in names:
            raise FieldError(
                ("camera", "robot"), f"no robot named {cam.robot!r} (robots: {', '.join(names)})"
            )
        return self

    @model_validator(mode="after")
    def _gate_robot(self) -> Self:
        gate = self.laser.gate
        names = [r.name for r in self.robots]
        if gate is not None and gate.robot not in names:
            raise FieldError(
                ("laser", "gate", "robot"),
                f"no robot named {gate.robot!r} (robots: {', '.join(names)})",
            )
        return self


# --- partial system (include files, truth) --------------------------------------------------
class PartialLaser(StrictModel):
    world_T_laser: Pose | None = None

    @model_validator(mode="after")
    def _plausible(self) -> Self:
        if self.world_T_laser is not None:
            check_translation(self.world_T_laser, "world_T_laser", MAX_WORLD_M)
        return self


class PartialMirror(StrictModel):
    flange_T_mirror: Pose | None = None
    size: PosVec2 | None = None
    roi_margin: NonNegNum | None = None

    @model_validator(mode="after")
    def _plausible(self) -> Self:
        check_mirror(self.size, self.roi_margin, self.flange_T_mirror)
        return self


class PartialRobot(StrictModel):
    """A robot override, matched to the scenario's robot of the same ``name``."""

    name: Name
    model: Name | None = None
    urdf: Name | None = None
    world_T_base: Pose | None = None
    home: JointVector | None = None
    limits: Limits | None = None
    mirror: PartialMirror | None = None

    @model_validator(mode="after")
    def _plausible(self) -> Self:
        check_robot(self.home, self.world_T_base)
        return self


class PartialIntrinsics(StrictModel):
    width: PosInt | None = None
    height: PosInt | None = None
    fx: PosNum | None = None
    fy: PosNum | None = None
    cx: Num | None = None
    cy: Num | None = None


class PartialCamera(StrictModel):
    """Camera overrides; a mount given here (fixed or on a flange) replaces the other one."""

    world_T_camera: Pose | None = None
    robot: Name | None = None
    flange_T_camera: Pose | None = None
    intrinsics: PartialIntrinsics | None = None

    @model_validator(mode="after")
    def _one_mount(self) -> Self:
        check_camera_mount(self.world_T_camera, self.robot, self.flange_T_camera, partial=True)
        return self


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
    in object coordinates times ``scale``. ``motion`` (:class:`schemas.motion.Motion`, simulation
    only) moves the object in the simulated world; planning ignores it.
    """

    name: Name
    box: PosVec3 | None = None
    mesh: Name | None = None
    scale: PosNum | None = None
    sphere: PosNum | None = None
    cylinder: PosVec2 | None = None
    world_T_object: Pose = Field(default_factory=Pose)
    motion: Motion | None = None

    @model_validator(mode="after")
    def _one_shape(self) -> Self:
        given = [k for k in SHAPE_KEYS if getattr(self, k) is not None]
        if not given:
            raise ValueError(f"needs one shape: {', '.join(SHAPE_KEYS)}")
        if len(given) > 1:
            raise FieldError((given[1],), f"give only one shape of {', '.join(given)}")
        if self.scale is not None and self.mesh is None:
            raise FieldError(("scale",), "only allowed with mesh")
        check_translation(self.world_T_object, "world_T_object", MAX_WORLD_M)
        sizes = {"box": self.box, "sphere": [self.sphere], "cylinder": self.cylinder}
        for key, values in sizes.items():
            for i, v in enumerate(values or []):
                if v is not None and v > MAX_WORLD_M:
                    loc = (key,) if key == "sphere" else (key, i)
                    raise FieldError(loc, f"{v:g} m: did you give millimetres? (metres)")
        return self

    @property
    def shape(self) -> str:
        return next(k for k in SHAPE_KEYS if getattr(self, k) is not None)


KEEP_OUT_SHAPES = ("sphere", "box", "mesh")


class KeepOutObject(StrictModel):
    """A volume the beam must never enter while the laser is on (an eye, a finger): exactly
    one of ``sphere`` (radius), ``box`` (full extents [x, y, z], centred) or ``mesh`` (a
    closed triangle mesh, taken as its convex hull; path relative to the scenario, times
    ``scale``), in the frame ``world_T_object`` (m). A target inside one fails as
    ``keep_out``. ``attached_to`` names the tracked object (a scene object, or the stream id
    of a ``mode: track`` request) it moves with: while that object is tracked the volume is
    moved by the tracked point's displacement from the request's point (its pose here is
    the one it has when the object is where the request's point says)."""

    name: Name
    attached_to: Name | None = None
    sphere: PosNum | None = None
    box: PosVec3 | None = None
    mesh: Name | None = None
    scale: PosNum | None = None
    world_T_object: Pose = Field(default_factory=Pose)

    @model_validator(mode="after")
    def _one_shape(self) -> Self:
        given = [k for k in KEEP_OUT_SHAPES if getattr(self, k) is not None]
        if not given:
            raise ValueError(f"needs one shape: {', '.join(KEEP_OUT_SHAPES)}")
        if len(given) > 1:
            raise FieldError((given[1],), f"give only one shape of {', '.join(given)}")
        if self.scale is not None and self.mesh is None:
            raise FieldError(("scale",), "only allowed with mesh")
        check_translation(self.world_T_object, "world_T_object", MAX_WORLD_M)
        sizes = {"box": self.box, "sphere": [self.sphere]}
        for key, values in sizes.items():
            for i, v in enumerate(values or []):
                if v is not None and v > MAX_WORLD_M:
                    loc = (key,) if key == "sphere" else (key, i)
                    raise FieldError(loc, f"{v:g} m: did you give millimetres? (metres)")
        return self

    @property
    def shape(self) -> str:
        return next(k for k in KEEP_OUT_SHAPES if getattr(self, k) is not None)


#: m: the largest clearance accepted (a larger value is almost surely millimetres)
MAX_CLEARANCE = 0.5

#: keep-out and beam-vs-arm volumes grow by beam_radius + this x the spot uncertainty
UNCERTAINTY_K = 3.0


def safety_margin(beam_radius: float, spot_uncertainty: float) -> float:
    """m by which keep-out volumes and arm parts are inflated for the beam checks:
    ``beam_radius`` + :data:`UNCERTAINTY_K` x ``spot_uncertainty`` (both m)."""
    return float(beam_radius) + UNCERTAINTY_K * float(spot_uncertainty)


class Safety(StrictModel):
    """Hard safety margins. ``clearance`` (m): the least distance arm-arm, arm-scene and
    beam-arm; ``return_cone_deg``: a reflected beam passing within ``return_radius`` (m) of
    the laser exit (or the camera centre) travelling back within this angle of the laser
    axis (the camera's optical axis) counts as entering the laser aperture (the lens).
    ``spot_uncertainty`` (m): the spot uncertainty of the calibration, filled in from the
    included calibration's ``report.spot_uncertainty`` (the largest of the file's own value
    and every include's; resolved plans echo it); keep-out and beam-vs-arm volumes are
    inflated by ``laser.beam_radius`` + :data:`UNCERTAINTY_K` x this."""

    clearance: NonNegNum = 0.01
    return_cone_deg: Annotated[PosNum, Field(le=90)] = 10.0
    return_radius: PosNum = 0.01
    spot_uncertainty: NonNegNum = 0.0

    @model_validator(mode="after")
    def _plausible(self) -> Self:
        for key in ("clearance", "return_radius", "spot_uncertainty"):
            value = getattr(self, key)
            if value > MAX_CLEARANCE:
                raise FieldError(
                    (key,),
                    f"{value:g} m is above {MAX_CLEARANCE:g} m: did you give millimetres? (metres)",
                )
        return self


# --- settings -----------------------------------------------------------------------------
class Solver(StrictModel):
    """IK settings: ``tolerance`` is a spot error (m); ``max_incidence_deg`` in degrees."""

    tolerance: PosNum = defaults.SPOT_TOLERANCE_M
    max_iter: PosInt = defaults.SOLVER_MAX_ITER
    max_incidence_deg: Annotated[PosNum, Field(le=90)] = defaults.MAX_INCIDENCE_DEG

    @model_validator(mode="after")
    def _plausible(self) -> Self:
        if self.tolerance > MAX_TOLERANCE:
            raise FieldError(
                ("tolerance",),
                f"{self.tolerance:g} m is a spot error above {MAX_TOLERANCE:g} m: did you"
                " give millimetres? (metres)",
            )
        return self


class TrajectorySettings(StrictModel):
    """Path timing: spot speed (m/s), dwell per target (s), sample rate (Hz), the largest
    distance (m) of the spot from the path while the laser is on, and the visit order of
    points (``optimal``/``optimized`` or ``given``; overrides ``targets.order``)."""

    spot_speed: PosNum = defaults.SPOT_SPEED_MPS
    dwell: NonNegNum = defaults.DWELL_S
    rate: PosNum = defaults.SERVO_RATE_HZ
    path_tolerance: Annotated[PosNum, Field(le=MAX_TOLERANCE)] = defaults.PATH_TOLERANCE_M
    order: Literal["optimal", "optimized", "given"] | None = None

    @model_validator(mode="after")
    def _plausible(self) -> Self:
        if self.spot_speed > MAX_SPOT_SPEED:
            raise FieldError(
                ("spot_speed",),
                f"{self.spot_speed:g} m/s is above {MAX_SPOT_SPEED:g} m/s: did you give mm/s?"
                " (m/s)",
            )
        return self


class Scenario(StrictModel):
    """A whole scenario file. ``include`` paths are relative to the file that names them."""

    name: Name | None = None
    system: System
    scene: list[SceneObject] = Field(default_factory=list)
    keep_out: list[KeepOutObject] = Field(default_factory=list)
    safety: Safety = Field(default_factory=Safety)
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

    @field_validator("keep_out")
    @classmethod
    def _unique_keep_out(cls, volumes: list[KeepOutObject]) -> list[KeepOutObject]:
        check_unique_names([o.name for o in volumes], "keep_out volume")
        return volumes

    @model_validator(mode="after")
    def _camera_frame(self) -> Self:
        if self.targets.frame == "camera" and self.system.camera is None:
            raise FieldError(("targets", "frame"), "is camera but system.camera is not given")
        if self.targets.frame == "camera":
            try:
                check_in_front(self.targets)
            except FieldError as exc:
                raise FieldError(("targets", *exc.loc), exc.reason) from None
        if self.truth is not None:
            names = {r.name for r in self.system.robots}
            for i, r in enumerate(self.truth.system.robots or []):
                if r.name not in names:
                    raise FieldError(
                        ("truth", "system", "robots", i, "name"), f"no robot named {r.name!r}"
                    )
        return self
