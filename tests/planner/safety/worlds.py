"""Systems for the safety tests: one UR5e, and a two-robot relay with bases 1.05 m apart."""

from __future__ import annotations

import numpy as np

from planner.model.build import ur5e_robot
from planner.model.system import DEFAULT_HOME, Robot, System
from planner.model.transforms import Array, look_at, make_T, rot_z

#: both arms stretched horizontally toward each other (they overlap in the middle)
REACH = np.array([np.pi, 0.0, 0.0, 0.0, 0.0, 0.0])
#: arms upright, far apart
UPRIGHT = np.array(DEFAULT_HOME)


def robot(name: str, world_T_base: Array, mount_z: float = 0.03) -> Robot:
    return ur5e_robot(name, world_T_base, flange_T_mirror=make_T(p=[0.0, 0.0, mount_z]))


def single() -> System:
    r = robot("arm0", np.eye(4))
    laser = look_at([0.6, -0.4, 0.3], [0.0, -0.2, 0.9])
    return System(laser, (r,))


def relay(gap: float = 1.05) -> System:
    """arm0 at the origin, arm1 at (gap, 0, 0) turned 180 deg about z: they face each other."""
    a = robot("arm0", np.eye(4))
    b = robot("arm1", make_T(rot_z(np.pi), [gap, 0.0, 0.0]))
    laser = look_at([0.5, -0.6, 0.3], [0.0, -0.2, 0.9])
    return System(laser, (a, b))


def parallel_slack(p0: Array, p1: Array, q0: Array, q1: Array) -> float:
    """Tolerance (m) for coal's capsule-capsule distance against an exact one: coal treats
    axes within ~1e-5 rad of parallel as parallel and can then be off by up to
    length x sin(angle) (seen: 1.5e-7 m at 7.5e-6 rad, where the numpy value matches a
    20001-point brute force to 2e-13 m); 1e-9 m otherwise."""
    u, v = p1 - p0, q1 - q0
    sin = np.linalg.norm(np.cross(u, v)) / (np.linalg.norm(u) * np.linalg.norm(v) + 1e-300)
    if sin >= 1e-4:
        return 1e-9
    return max(1e-9, float(sin * max(np.linalg.norm(u), np.linalg.norm(v))))
