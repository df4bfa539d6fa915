"""A URDF robot's own ``<limit>`` values are its default limits (not the UR5e's)."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from planner.errors import ScenarioError
from planner.io.resolved import resolved_scenario_dict
from planner.io.scenario import load_scenario, system_from_scenario
from planner.model.kinematics import ur5e_urdf_path
from planner.model.system import Limits

EDITED = {  # joint -> (lower, upper, velocity): a smaller arm's ranges and speeds
    "shoulder_pan": (-2.5, 2.0, 1.2),
    "shoulder_lift": (-3.0, 0.5, 1.1),
    "elbow": (-2.8, 2.8, 1.0),
    "wrist_1": (-3.1, 3.1, 2.0),
    "wrist_2": (-3.1, 3.1, 2.0),
    "wrist_3": (-4.0, 4.0, 2.5),
}

SCENARIO = """\
name: urdf-limits
system:
  laser: {world_T_laser: {xyz: [0.6, -0.4, 0.3], rpy_deg: [0, -90, 0]}}
  robots:
    - name: arm0
      urdf: small.urdf
      home: [0, -1.5, 1.5, -1.5, -1.5, 0]
      mirror: {flange_T_mirror: {xyz: [0, 0, 0.03]}, size: [0.075, 0.075]}
targets:
  points: [[0.5, 0.1, 0.0]]
"""


def write_urdf(path: Path) -> Path:
    """The shipped UR5e URDF with the limits of :data:`EDITED`, edited as XML."""
    tree = ET.parse(ur5e_urdf_path())
    for joint in tree.getroot().iter("joint"):
        if joint.get("name") in EDITED:
            lo, hi, v = EDITED[joint.get("name", "")]
            limit = joint.find("limit")
            assert limit is not None
            limit.set("lower", repr(lo))
            limit.set("upper", repr(hi))
            limit.set("velocity", repr(v))
    tree.write(path)
    return path


def urdf_limits(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(lower, upper, velocity) read straight from the XML, in joint order."""
    rows = []
    for joint in ET.parse(path).getroot().iter("joint"):
        limit = joint.find("limit")
        if joint.get("type") == "revolute" and limit is not None:
            rows.append([float(limit.get(k, "nan")) for k in ("lower", "upper", "velocity")])
    table = np.array(rows)
    return table[:, 0], table[:, 1], table[:, 2]


def test_urdf_limits_replace_the_ur5e_defaults(tmp_path: Path) -> None:
    write_urdf(tmp_path / "small.urdf")
    (tmp_path / "s.yaml").write_text(SCENARIO)
    scn = load_scenario(tmp_path / "s.yaml")
    limits = system_from_scenario(scn).robots[0].limits
    lower, upper, velocity = urdf_limits(tmp_path / "small.urdf")
    assert np.array_equal(limits.lower, lower) and np.array_equal(limits.upper, upper)
    assert np.array_equal(limits.velocity, velocity)
    spec = Limits.ur_default()  # URDF has no acceleration or jerk: the conservative defaults
    assert np.array_equal(limits.acceleration, spec.acceleration)
    assert np.array_equal(limits.jerk, spec.jerk)
    # plan.json's resolved scenario (what `check` verifies against) carries them too
    resolved = resolved_scenario_dict(scn)["system"]["robots"][0]["limits"]
    assert resolved["upper"] == upper.tolist() and resolved["velocity"] == velocity.tolist()


def test_scenario_limits_override_urdf_key_by_key(tmp_path: Path) -> None:
    write_urdf(tmp_path / "small.urdf")
    text = SCENARIO.replace(
        "      home:", "      limits: {velocity: [0.5, 0.5, 0.5, 0.5, 0.5, 0.5]}\n      home:"
    )
    (tmp_path / "s.yaml").write_text(text)
    limits = system_from_scenario(load_scenario(tmp_path / "s.yaml")).robots[0].limits
    assert np.array_equal(limits.velocity, np.full(6, 0.5))
    lower, upper, _ = urdf_limits(tmp_path / "small.urdf")
    assert np.array_equal(limits.lower, lower) and np.array_equal(limits.upper, upper)


def test_home_outside_the_urdf_range_is_an_error(tmp_path: Path) -> None:
    write_urdf(tmp_path / "small.urdf")
    (tmp_path / "s.yaml").write_text(SCENARIO.replace("[0, -1.5, 1.5,", "[0, 1.0, 1.5,"))
    with pytest.raises(ScenarioError) as exc:
        system_from_scenario(load_scenario(tmp_path / "s.yaml"))
    assert str(exc.value).endswith(
        "s.yaml:7 system.robots[0].home[1]: 1 rad is outside the joint limits [-3, 0.5]"
    )
