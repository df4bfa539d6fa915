"""The checker's own numpy URDF kinematics against Pinocchio (the planner's model)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from planner.errors import InputError
from planner.model.kinematics import RobotKinematics, ur5e_urdf_path
from planner.verify.urdf import UrdfChain

# A branched arm: a root link above "base", a tilted (unaligned) revolute axis, a prismatic
# joint, and a side branch whose joint name sorts first (joint order must follow Pinocchio).
ARM = """<?xml version="1.0"?>
<robot name="odd">
  <link name="world"/><link name="base"/><link name="l1"/><link name="l2"/><link name="l3"/>
  <link name="side"/><link name="tool0"/>
  <joint name="mount" type="fixed"><parent link="world"/><child link="base"/>
    <origin xyz="0.1 -0.2 0.3" rpy="0.1 0.2 0.3"/></joint>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>
    <origin xyz="0 0 0.2" rpy="0 0 0"/><axis xyz="0 0 1"/>
    <limit lower="-3" upper="3" velocity="1" effort="1"/></joint>
  <joint name="a_side" type="revolute"><parent link="l1"/><child link="side"/>
    <origin xyz="0.05 0 0" rpy="0 0 0"/><axis xyz="1 0 0"/>
    <limit lower="-3" upper="3" velocity="1" effort="1"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/>
    <origin xyz="0 0.1 0.3" rpy="0.5 0 -0.4"/><axis xyz="0.3 0.4 0.866"/>
    <limit lower="-3" upper="3" velocity="1" effort="1"/></joint>
  <joint name="j3" type="prismatic"><parent link="l2"/><child link="l3"/>
    <origin xyz="0.2 0 0" rpy="0 0.3 0"/><axis xyz="0 1 1"/>
    <limit lower="0" upper="0.3" velocity="1" effort="1"/></joint>
  <joint name="flange" type="fixed"><parent link="l3"/><child link="tool0"/>
    <origin xyz="0 0 0.1" rpy="0 0 1.0"/></joint>
</robot>
"""


@pytest.mark.parametrize("which", ["ur5e", "odd"])
def test_numpy_urdf_fk_matches_pinocchio(tmp_path: Path, which: str) -> None:
    path = ur5e_urdf_path()
    if which == "odd":
        path = tmp_path / "odd.urdf"
        path.write_text(ARM)
    chain, kin = UrdfChain(path), RobotKinematics.from_urdf(path)
    assert chain.nq == kin.nq
    assert tuple(chain.movable) == kin.joint_names
    rng = np.random.default_rng(1)
    for q in rng.uniform(-2.0, 2.0, size=(20, kin.nq)):
        np.testing.assert_allclose(chain.fk(q), kin.fk(q), atol=1e-12)


def test_bad_urdfs_are_input_errors(tmp_path: Path) -> None:
    bad = tmp_path / "bad.urdf"
    bad.write_text(ARM.replace('type="prismatic"', 'type="floating"'))
    with pytest.raises(InputError, match="floating"):
        UrdfChain(bad)
    bad.write_text("<robot")
    with pytest.raises(InputError, match="cannot read URDF"):
        UrdfChain(bad)
    bad.write_text(ARM)
    with pytest.raises(InputError, match="'flange0' not in the robot model"):
        UrdfChain(bad, flange="flange0")
