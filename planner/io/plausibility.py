"""Warnings for scenario values that are valid but probably not what the user meant.

Errors (values no real set-up can have, such as a joint speed of 180 rad/s) are raised by
the schemas; this module only flags values that are plausible but unusual, each as one
line ``file:line key.path: reason``. Units: metres, radians, seconds.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator
from typing import Any

from pydantic import BaseModel

from schemas.common import QUAT_NORM_RANGE, Pose
from schemas.scenario import Scenario

log = logging.getLogger("beamrelay.input")

UR5E_MAX_VELOCITY = math.pi
"""UR5e datasheet joint speed limit, rad/s (every joint)."""
RADIAN_LOOKING = tuple(k * math.pi / 4 for k in range(1, 9))
"""Angles (rad) that, written under ``rpy_deg``, look like radians: multiples of pi/4."""

Loc = tuple[str | int, ...]


def scenario_warnings(model: Scenario) -> list[tuple[Loc, str]]:
    """(key path, reason) of every suspicious value of a validated scenario."""
    found = [
        ((*loc, found[0]), found[1]) for loc, pose in poses(model) if (found := pose_warning(pose))
    ]
    for i, robot in enumerate(model.system.robots):
        if robot.urdf is None and robot.limits is not None and robot.limits.velocity:
            for j, v in enumerate(robot.limits.velocity):
                if v > UR5E_MAX_VELOCITY + 1e-9:
                    found.append(
                        (
                            ("system", "robots", i, "limits", "velocity", j),
                            f"{v:g} rad/s is above the UR5e datasheet maximum"
                            f" ({UR5E_MAX_VELOCITY:.4g} rad/s); the controller will not follow",
                        )
                    )
    incidence = model.solver.max_incidence_deg
    if incidence <= math.pi / 2 + 1e-6:
        found.append(
            (
                ("solver", "max_incidence_deg"),
                f"{incidence:g} deg looks like radians (max_incidence_deg is in degrees)",
            )
        )
    return found


def pose_warning(pose: Pose) -> tuple[str, str] | None:
    """(key, reason) when a pose looks mistaken: a quaternion far from unit length, or
    radians written under ``rpy_deg``."""
    n = pose.quat_length
    lo, hi = QUAT_NORM_RANGE
    if n is not None and not lo <= n <= hi:
        return "quat", (
            f"has length {n:.4g}, far from a unit quaternion [x, y, z, w] (normalised here);"
            " angles? write rpy or rpy_deg"
        )
    angles = pose.rpy_deg or []
    if not angles or max(abs(a) for a in angles) > 2 * math.pi + 1e-6:
        return None
    if any(abs(abs(a) - r) < 1e-3 for a in angles for r in RADIAN_LOOKING):
        return "rpy_deg", (
            f"{angles} looks like radians (multiples of pi/4); rpy_deg is in degrees, for"
            " radians write rpy"
        )
    return None


def poses(node: Any, loc: Loc = ()) -> Iterator[tuple[Loc, Pose]]:
    """Every :class:`Pose` inside a model, with its key path (file key names)."""
    if isinstance(node, Pose):
        yield loc, node
    elif isinstance(node, BaseModel):
        for name, info in type(node).model_fields.items():
            yield from poses(getattr(node, name), (*loc, info.alias or name))
    elif isinstance(node, list):
        for i, item in enumerate(node):
            yield from poses(item, (*loc, i))


def emit(lines: list[str]) -> None:
    """Log each warning line (one line each on stderr when logging is not configured)."""
    for line in lines:
        log.warning("warning: %s", line)
