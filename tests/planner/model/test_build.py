"""One way to build a system in code; the test helpers and studies are thin wrappers of it."""

from __future__ import annotations

import numpy as np

from planner.model.build import MIRROR_OFFSET, build_system, ur5e_robot
from planner.model.mirror import DEFAULT_MIRROR_SIZE, DEFAULT_ROI_MARGIN
from planner.model.system import DEFAULT_HOME, Limits
from planner.model.transforms import make_T, rot_z
from tests.planner.calibration import cal_systems
from tests.planner.ik import ik_systems


def test_ur5e_robot_defaults() -> None:
    r = ur5e_robot()
    assert r.name == "arm0" and r.kinematics.name == "ur5e" and r.nq == 6
    np.testing.assert_array_equal(r.world_T_base, np.eye(4))
    np.testing.assert_array_equal(r.mirror.flange_T_mirror, make_T(p=[0, 0, MIRROR_OFFSET]))
    assert (r.mirror.size, r.mirror.roi_margin) == (DEFAULT_MIRROR_SIZE, DEFAULT_ROI_MARGIN)
    np.testing.assert_array_equal(r.home, DEFAULT_HOME)
    np.testing.assert_array_equal(r.limits.upper, Limits.ur_default().upper)


def test_build_system_names_bases_and_shares_the_model() -> None:
    bases = [np.eye(4), make_T(rot_z(np.pi), [0.0, 1.0, 0.0])]
    laser = make_T(p=[0.5, 0.0, 0.3])
    s = build_system(laser, bases, roi_margin=0.01)
    assert s.robot_names == ("arm0", "arm1") and s.camera is None
    assert s.robots[0].kinematics is s.robots[1].kinematics
    np.testing.assert_array_equal(s.robots[1].world_T_base, bases[1])
    assert all(r.mirror.roi_margin == 0.01 for r in s.robots)


def test_test_helpers_are_the_builder() -> None:
    n2 = ik_systems.n2()
    ref = build_system(ik_systems.LASER, [r.world_T_base for r in n2.robots], roi_margin=0.01)
    for a, b in zip(n2.robots, ref.robots, strict=True):
        assert (a.name, a.mirror.size, a.mirror.roi_margin) == (b.name, b.mirror.size, 0.01)
        np.testing.assert_array_equal(a.mirror.flange_T_mirror, b.mirror.flange_T_mirror)
    cal = cal_systems.nominal_system()
    assert cal.camera is not None and cal.robots[0].mirror.size == DEFAULT_MIRROR_SIZE
    np.testing.assert_array_equal(cal.robots[0].mirror.flange_T_mirror,
                                  ur5e_robot().mirror.flange_T_mirror)  # fmt: skip
