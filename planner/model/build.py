"""Systems built in code (studies, benchmarks, tests, notebooks) rather than from a scenario.

:func:`ur5e_robot` is one nominal UR5e with a flat mirror on its flange; :func:`build_system`
puts such arms (``arm0``, ``arm1``, ...) at given base poses behind a laser. Poses ``a_T_b``
(4 x 4), metres, radians.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from planner.model.kinematics import RobotKinematics
from planner.model.mirror import DEFAULT_MIRROR_SIZE, DEFAULT_ROI_MARGIN, Mirror
from planner.model.system import DEFAULT_HOME, Camera, Limits, Robot, System
from planner.model.transforms import Array, make_T

MIRROR_OFFSET = 0.03  # m: default mirror centre along the flange's z axis


def ur5e_robot(
    name: str = "arm0",
    world_T_base: Array | None = None,
    *,
    flange_T_mirror: Array | None = None,
    size: tuple[float, float] = DEFAULT_MIRROR_SIZE,
    roi_margin: float = DEFAULT_ROI_MARGIN,
    home: Sequence[float] | Array | None = None,
    limits: Limits | None = None,
    kinematics: RobotKinematics | None = None,
) -> Robot:
    """A UR5e (nominal model unless ``kinematics`` is given) at ``world_T_base`` (default the
    world origin) carrying a flat mirror of ``size`` (m) at ``flange_T_mirror`` (default
    :data:`MIRROR_OFFSET` along the flange z axis); ``home`` (rad) and ``limits`` default to
    the UR defaults."""
    return Robot(
        name,
        kinematics or RobotKinematics.ur5e(),
        np.eye(4) if world_T_base is None else np.asarray(world_T_base, dtype=float),
        Mirror(
            make_T(p=[0.0, 0.0, MIRROR_OFFSET]) if flange_T_mirror is None else flange_T_mirror,
            size,
            roi_margin,
        ),
        np.array(DEFAULT_HOME if home is None else home, dtype=float),
        limits or Limits.ur_default(),
    )


def build_system(
    world_T_laser: Array,
    bases: Sequence[Array] = (np.eye(4),),
    *,
    camera: Camera | None = None,
    size: tuple[float, float] = DEFAULT_MIRROR_SIZE,
    roi_margin: float = DEFAULT_ROI_MARGIN,
) -> System:
    """UR5e arms ``arm0``, ``arm1``, ... at ``world_T_base = bases[i]`` (one shared nominal
    model, default mirrors of ``size`` and ``roi_margin``, m) behind the laser at
    ``world_T_laser``, with an optional camera."""
    kin = RobotKinematics.ur5e()
    robots = tuple(
        ur5e_robot(f"arm{i}", T, kinematics=kin, size=size, roi_margin=roi_margin)
        for i, T in enumerate(bases)
    )
    return System(np.asarray(world_T_laser, dtype=float), robots, camera)
