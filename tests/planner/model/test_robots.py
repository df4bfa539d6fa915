"""The robot-model registry: a model registered by name loads from a scenario."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from planner.errors import InputError, ScenarioError
from planner.io.resolved import resolved_scenario_dict
from planner.io.scenario import load_scenario, system_from_scenario
from planner.model import robots
from planner.model.collision import CapsuleSpec, CollisionShapes
from planner.model.kinematics import RobotKinematics, ur5e_urdf_path
from planner.model.limits import Limits
from planner.safety import PartKind, SafetyWorld
from planner.verify.urdf import UrdfChain
from tests.cli_run import assert_usage_error, beamrelay
from tests.paths import REPO

SHAPES = CollisionShapes(
    ("base", "l1", "l2", "l3", "l4", "l5", "l6"),
    (CapsuleSpec("upper", 2, (0.0, 0.0, 0.0), (-0.4, 0.0, 0.0), 0.05),),
)


def long_arm_urdf(path: Path) -> Path:
    """The shipped UR5e with a 0.5 m upper arm (instead of 0.425 m) and slower joints."""
    tree = ET.parse(ur5e_urdf_path())
    for joint in tree.getroot().iter("joint"):
        origin, limit = joint.find("origin"), joint.find("limit")
        if joint.get("name") == "elbow" and origin is not None:
            origin.set("xyz", "-0.5 0 0.0")
        if limit is not None:
            limit.set("velocity", "1.25")
    tree.write(path)
    return path


@pytest.fixture
def long_arm(tmp_path: Path) -> Iterator[Path]:
    urdf = long_arm_urdf(tmp_path / "long_arm.urdf")
    robots.register_model("long_arm", lambda: robots.urdf_model(urdf, "long_arm", collision=SHAPES))
    yield urdf
    robots.unregister_model("long_arm")


def scenario_with(tmp_path: Path, model_line: str) -> Path:
    text = (REPO / "scenarios/paper_n1.yaml").read_text()
    assert "      model: ur5e\n" in text
    path = tmp_path / "s.yaml"
    path.write_text(text.replace("      model: ur5e\n", model_line, 1))
    return path


def test_a_registered_model_loads_from_a_scenario(tmp_path: Path, long_arm: Path) -> None:
    scn = load_scenario(scenario_with(tmp_path, "      model: long_arm\n"))
    system = system_from_scenario(scn)
    robot = system.robots[0]
    assert robot.kinematics.name == "long_arm"
    # its own URDF limits: 1.25 rad/s, not the UR5e's pi rad/s
    np.testing.assert_array_equal(robot.limits.velocity, np.full(6, 1.25))
    np.testing.assert_array_equal(robot.limits.jerk, Limits.ur_default().jerk)
    # its kinematics, checked against the checker's independent numpy URDF chain
    q = np.array([0.3, -1.2, 1.1, -0.4, 0.7, 0.2])
    np.testing.assert_allclose(robot.kinematics.fk(q), UrdfChain(long_arm).fk(q), atol=1e-12)
    # at zero joints the arm lies along -x: the flange moves out by the extra 75 mm
    shift = robot.kinematics.fk(np.zeros(6))[:3, 3] - RobotKinematics.ur5e().fk(np.zeros(6))[:3, 3]
    np.testing.assert_allclose(shift, [-0.075, 0.0, 0.0], atol=1e-12)
    assert robots.collision_shapes("long_arm") is SHAPES
    links = [p.name for p in SafetyWorld(system).parts if p.kind == PartKind.LINK]
    assert links == ["arm0/upper"]  # the collision hook: the model's own shapes
    # the plan's scenario echo names the URDF, so the checker can re-verify the arm
    echo = resolved_scenario_dict(scn)["system"]["robots"][0]
    assert echo["urdf"] == str(long_arm.resolve()) and "model" not in echo


def test_an_unknown_model_is_one_located_error(tmp_path: Path) -> None:
    path = scenario_with(tmp_path, "      model: ur5x\n")
    with pytest.raises(ScenarioError) as info:
        system_from_scenario(load_scenario(path))
    message = str(info.value)
    assert "s.yaml:" in message and "system.robots[0].model" in message
    assert "unknown robot model 'ur5x' (known: ur5e)" in message
    assert_usage_error(beamrelay("validate", path), "unknown robot model 'ur5x'")


def test_registry_rules() -> None:
    assert "ur5e" in robots.known_models()
    ur5e = robots.robot_model("ur5e")
    assert ur5e is robots.robot_model("ur5e")  # built once
    assert ur5e.collision is not None and ur5e.collision.nq == ur5e.nq == 6
    with pytest.raises(ValueError, match="already registered"):
        robots.register_model("ur5e", lambda: ur5e)
    with pytest.raises(ValueError, match="not a model name"):
        robots.register_model("arm.urdf", lambda: ur5e)
    robots.register_model("short", lambda: robots.RobotModel("short", ur5e.kinematics,
                                                             Limits.ur_default(5)))  # fmt: skip
    try:
        with pytest.raises(InputError, match="limits for \\(5,\\) joints, kinematics has 6"):
            robots.robot_model("short")
    finally:
        robots.unregister_model("short")
    urdf = robots.robot_model(ur5e_urdf_path())  # a URDF path needs no registration
    assert urdf.collision is None and urdf.kinematics.name == "ur5e"


def test_a_model_without_shapes_is_refused_by_the_collision_world(tmp_path: Path) -> None:
    urdf = long_arm_urdf(tmp_path / "bare_arm.urdf")
    scn = load_scenario(scenario_with(tmp_path, f"      urdf: {urdf}\n"))
    with pytest.raises(InputError, match="no collision capsules for robot model 'bare_arm'"):
        SafetyWorld(system_from_scenario(scn))
