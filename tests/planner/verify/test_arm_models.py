"""A new arm is one registered model for the planner and one checker twin: planned by name,
re-checked by the checker's own kinematics, never by another arm's."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pinocchio as pin
import pytest

from planner.model import robots
from planner.model.kinematics import RobotKinematics, ur5e_urdf_path
from planner.model.ur5e import UR5E_SHAPES
from planner.verify import arm_models
from planner.verify.numpy_beam import ur5e_dh_fk
from planner.verify.safety_shapes import arm_shapes
from tests.cli_run import beamrelay
from tests.paths import REPO

MODEL = "code_arm"  # a UR5e built in code (no URDF source the checker could read instead)


@pytest.fixture
def code_arm() -> Iterator[None]:
    def factory() -> robots.RobotModel:
        kin = RobotKinematics(pin.buildModelFromUrdf(str(ur5e_urdf_path())), name=MODEL,
                              source="built in code", analytic="ur5e")  # fmt: skip
        return robots.RobotModel(MODEL, kin, kin.default_limits(), UR5E_SHAPES)

    robots.register_model(MODEL, factory)
    yield
    robots.unregister_model(MODEL)
    arm_models.unregister_checker_arm(MODEL)


def _scenario(tmp_path: Path) -> Path:
    text = (REPO / "scenarios/paper_n1.yaml").read_text()
    assert "      model: ur5e\n" in text
    scenario = tmp_path / "s.yaml"
    scenario.write_text(text.replace("      model: ur5e\n", f"      model: {MODEL}\n", 1))
    return scenario


def test_without_a_twin_nothing_is_planned_with_the_ur5e_borrowed(
    tmp_path: Path, code_arm: None
) -> None:
    """``plan`` re-checks every solution with the checker, which has no kinematics of its
    own for the new arm: one line, exit 2, no plan written."""
    out = tmp_path / "plan.json"
    ran = beamrelay("plan", _scenario(tmp_path), "-o", out)
    assert ran.returncode == 2
    assert f"no independent kinematics for robot model '{MODEL}'" in ran.stderr
    assert not out.exists()


def test_with_its_twin_the_arm_is_planned_by_name_and_rechecked(
    tmp_path: Path, code_arm: None
) -> None:
    arm_models.register_checker_arm(MODEL, arm_models.CheckerArm(6, ur5e_dh_fk, arm_shapes))
    out = tmp_path / "plan.json"
    ran = beamrelay("plan", _scenario(tmp_path), "-o", out)
    assert ran.returncode == 0, ran.stderr
    doc = json.loads(out.read_text())
    robot = doc["scenario"]["system"]["robots"][0]
    assert robot.get("model") == MODEL and "urdf" not in robot  # planned by name
    assert all(s["status"] == "ok" for s in doc["solutions"])
    ran = beamrelay("check", out)
    assert ran.returncode == 0, ran.stdout + ran.stderr


def test_registry_rules() -> None:
    assert arm_models.checker_arm(None) is arm_models.checker_arm("ur5e")
    assert arm_models.checker_arm("nope") is None
    with pytest.raises(ValueError, match="already registered"):
        arm_models.register_checker_arm("ur5e", arm_models.CheckerArm(6, ur5e_dh_fk))
    arm_models.unregister_checker_arm("ur5e")  # the default stays
    assert arm_models.checker_arm("ur5e") is not None
