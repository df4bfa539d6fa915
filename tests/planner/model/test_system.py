"""System: stacked joint vectors and limits in robot order."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from planner.model.kinematics import RobotKinematics
from planner.model.system import DEFAULT_HOME, Limits, Mirror, Robot, System
from planner.model.transforms import make_T


def test_limits_stack_in_robot_order() -> None:
    kin = RobotKinematics.ur5e()
    a = Robot("a", kin, np.eye(4), Mirror(make_T(p=[0, 0, 0.03])), np.array(DEFAULT_HOME),
              Limits.ur_default())  # fmt: skip
    slow = Limits(-np.ones(6), np.ones(6), np.full(6, 0.5), np.full(6, 2.0), np.full(6, 7.0))
    system = System(np.eye(4), (a, replace(a, name="b", limits=slow)))
    lim = system.limits
    np.testing.assert_allclose(lim.velocity, [np.pi] * 6 + [0.5] * 6)
    np.testing.assert_allclose(lim.acceleration, [5.0] * 6 + [2.0] * 6)
    np.testing.assert_allclose(lim.jerk, [50.0] * 6 + [7.0] * 6)
    np.testing.assert_allclose(lim.upper[[2, 8]], [np.pi, 1.0])
    np.testing.assert_allclose(lim.lower, system.lower)
    np.testing.assert_allclose(lim.upper, system.upper)
    assert system.split_q(lim.velocity)["b"].tolist() == [0.5] * 6
