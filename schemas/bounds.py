"""Plausibility bounds of scenario and dataset values: the likely unit or frame mistake.

A value beyond these bounds is no real set-up's (a joint speed of 180 rad/s, a 75 m mirror):
the check raises a :class:`~schemas.common.FieldError` at the key that names the probable
mistake (degrees for radians, millimetres for metres, world coordinates in the camera frame).
Units: metres, radians, seconds.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from schemas.common import MAX_FLANGE_M, MAX_WORLD_M, FieldError, Pose, check_translation

if TYPE_CHECKING:
    from schemas.targets import TargetSpec

Loc = tuple[str | int, ...]

MAX_POSITION_RAD = 2 * math.pi + 0.01
"""Joint positions (limits, home) beyond +-2 pi rad are degrees given as radians."""
MAX_LIMIT = {"velocity": 4 * math.pi, "acceleration": 100.0, "jerk": 10000.0}
"""Joint limits above these (rad/s, rad/s^2, rad/s^3) are no arm's: degrees given as radians.
A UR5e's datasheet maximum is pi rad/s."""
LIMIT_UNITS = {"velocity": "rad/s", "acceleration": "rad/s^2", "jerk": "rad/s^3"}
MAX_SPOT_SPEED = 10.0
"""A spot speed (m/s) above this is mm/s given as m/s."""
MAX_TOLERANCE = 0.01
"""A solver tolerance (m) above this is a length in mm given as metres."""


def check_limit_values(name: str, values: list[float] | None) -> None:
    """Velocity/acceleration/jerk limits must be > 0 and below any arm's (``MAX_LIMIT``)."""
    unit, top = LIMIT_UNITS[name], MAX_LIMIT[name]
    for i, v in enumerate(values or []):
        if v <= 0:
            raise FieldError((name, i), f"must be > 0, got {v:g}")
        if v > top:
            raise FieldError(
                (name, i),
                f"{v:g} {unit} is above {top:.4g} {unit}, beyond any arm: did you give"
                f" {unit.replace('rad', 'deg')}? (limits are in radians)",
            )


def check_joint_angle(value: float, loc: Loc) -> None:
    """A :class:`FieldError` when a joint position (rad) lies beyond +-2 pi: degrees?"""
    if abs(value) > MAX_POSITION_RAD:
        raise FieldError(
            loc, f"{value:g} rad is beyond +-2 pi: did you give degrees? (joints are in radians)"
        )


def check_mirror(
    size: list[float] | None, roi_margin: float | None, flange_T_mirror: Pose | None
) -> None:
    """Mirror sides and offset must be plausible lengths in metres (<= 1 m)."""
    if flange_T_mirror is not None:
        check_translation(flange_T_mirror, "flange_T_mirror", MAX_FLANGE_M)
    for i, side in enumerate(size or []):
        if side > MAX_FLANGE_M:
            raise FieldError(
                ("size", i),
                f"{side:g} m is a mirror side above {MAX_FLANGE_M:g} m: did you give"
                " millimetres? (lengths are in metres)",
            )
    if roi_margin is not None and roi_margin > MAX_FLANGE_M:
        raise FieldError(
            ("roi_margin",), f"{roi_margin:g} m: did you give millimetres? (lengths are in metres)"
        )


def check_robot(home: list[float] | None, world_T_base: Pose | None) -> None:
    """Home angles in radians (within +-2 pi), base within the plausible world."""
    for i, v in enumerate(home or []):
        check_joint_angle(v, ("home", i))
    if world_T_base is not None:
        check_translation(world_T_base, "world_T_base", MAX_WORLD_M)


def check_camera_mount(
    world_T_camera: Pose | None,
    robot: str | None,
    flange_T_camera: Pose | None,
    *,
    partial: bool,
) -> None:
    """A camera is either fixed (``world_T_camera``) or on a flange (``robot`` +
    ``flange_T_camera``); translations must be plausible lengths in metres."""
    on_flange = robot is not None or flange_T_camera is not None
    if world_T_camera is not None and on_flange:
        key = "robot" if robot is not None else "flange_T_camera"
        raise FieldError(
            (key,),
            "give either world_T_camera (a fixed camera) or robot + flange_T_camera"
            " (a camera on that robot's flange), not both",
        )
    if not partial:
        if on_flange and robot is None:
            raise FieldError(("robot",), "missing: flange_T_camera needs the robot carrying it")
        if on_flange and flange_T_camera is None:
            raise FieldError(
                ("flange_T_camera",), f"missing: the camera pose on robot {robot!r}'s flange"
            )
        if world_T_camera is None and not on_flange:
            raise ValueError(
                "needs world_T_camera (a fixed camera) or robot + flange_T_camera (on a flange)"
            )
    if world_T_camera is not None:
        check_translation(world_T_camera, "world_T_camera", MAX_WORLD_M)
    if flange_T_camera is not None:
        check_translation(flange_T_camera, "flange_T_camera", MAX_FLANGE_M)


def check_coordinates(rows: list[list[float]], loc: Loc, frame: str) -> None:
    """Target points (m) must be plausible: within ``MAX_WORLD_M`` of the frame's origin
    and, in the camera frame, in front of the camera (z > 0)."""
    for i, row in enumerate(rows):
        check_length_scale(row, (*loc, i))
        if frame == "camera" and row[2] <= 0:
            raise FieldError((*loc, i), behind_camera(row[2]))


def check_in_front(spec: TargetSpec) -> None:
    """Camera-frame targets must lie in front of the camera (z > 0, OpenCV frame)."""
    if spec.points is not None:
        check_coordinates(spec.points, ("points",), "camera")
    if spec.path is not None:
        check_coordinates(spec.path.points, ("path", "points"), "camera")
    if spec.grid is not None:
        g = spec.grid
        if g.center[2] - g.size[2] / 2 <= 0:
            raise FieldError(("grid",), behind_camera(g.center[2] - g.size[2] / 2))


def check_length_scale(values: list[float], loc: Loc) -> None:
    """Lengths (m) beyond ``MAX_WORLD_M`` are millimetres given as metres."""
    if max(abs(x) for x in values) > MAX_WORLD_M:
        raise FieldError(
            loc,
            f"{values} is beyond {MAX_WORLD_M:g} m: did you give millimetres?"
            " (coordinates are in metres)",
        )


def behind_camera(z: float, hint: str = "world coordinates? then say frame: world") -> str:
    """Why a camera-frame point with depth ``z`` (m) <= 0 is wrong, and what to do."""
    return f"z = {z:g} m is not in front of the camera (camera frame: OpenCV, z forward): {hint}"
