"""Scenario errors name the file, the 1-based line and the key path, in plain words."""

from __future__ import annotations

from pathlib import Path

import pytest

from planner.errors import InputError, ScenarioError
from planner.io.validate import validate_file
from schemas.scenario import Scenario
from schemas.yamlio import format_loc, read_yaml

VALID = """\
name: t
system:
  laser:
    world_T_laser: {xyz: [0.6, -0.4, 0.3], rpy_deg: [0, -90, 0]}
  robots:
    - name: arm0
      home: [0, -1.5708, 1.5708, -1.5708, -1.5708, 0]
      mirror:
        flange_T_mirror: {xyz: [0, 0, 0.03]}
        size: [0.075, 0.075]
targets:
  points:
    - [0.5, 0.1, 0.0]
    - [0.5, 0.2, 0.0]
  normals:
    - [0, 0, 2]
    - [0, 0, 1]
"""


def error_of(tmp_path: Path, text: str) -> str:
    path = tmp_path / "x.yaml"
    path.write_text(text)
    with pytest.raises(InputError) as info:
        validate_file(path)
    return str(info.value).replace(str(tmp_path) + "/", "")


def test_valid_baseline(tmp_path: Path) -> None:
    path = tmp_path / "x.yaml"
    path.write_text(VALID)
    kind, model = validate_file(path)
    assert kind == "scenario" and isinstance(model, Scenario)
    assert model.targets.normals == [[0, 0, 1], [0, 0, 1]]


@pytest.mark.parametrize(
    "old, new, message",
    [
        (
            "size: [0.075, 0.075]",
            "size: [0.075, 0.075, 0.1]",
            "x.yaml:10 system.robots[0].mirror.size: expected 2 numbers, got 3",
        ),
        (
            "        size: [0.075, 0.075]\n",
            "        size: [0.075, 0.075]\n        colour: red\n",
            "x.yaml:11 system.robots[0].mirror.colour: unknown key "
            "(allowed: flange_T_mirror, size, roi_margin)",
        ),
        (
            "        flange_T_mirror: {xyz: [0, 0, 0.03]}\n",
            "",
            "x.yaml:8 system.robots[0].mirror.flange_T_mirror: missing required key",
        ),
        (
            "rpy_deg: [0, -90, 0]",
            "quat: [0, 0, 0, 0]",
            "x.yaml:4 system.laser.world_T_laser.quat: quaternion has length 0, "
            "cannot be normalised",
        ),
        (
            "    - [0, 0, 1]\n",
            "",
            "x.yaml:15 targets.normals: expected 2 normals (one per point), got 1",
        ),
        (
            "    - [0, 0, 2]",
            "    - [0, 0, 0]",
            "x.yaml:16 targets.normals[0]: zero-length normal",
        ),
        (
            "targets:\n",
            "targets:\n  frame: camera\n",
            "x.yaml:12 targets.frame: is camera but system.camera is not given",
        ),
        (
            "      home: [0, -1.5708, 1.5708, -1.5708, -1.5708, 0]",
            "      home: [0, -1.5708, 1.5708, -1.5708, -1.5708]",
            "x.yaml:7 system.robots[0].home: expected 6 numbers (one per joint), got 5",
        ),
        (
            "    - [0.5, 0.2, 0.0]",
            "    - [0.5, 0.2, abc]",
            "x.yaml:14 targets.points[1][2]: expected a number, got 'abc'",
        ),
        (
            "name: t\n",
            "name: t\nsolver: {tolerance: -1}\n",
            "x.yaml:2 solver.tolerance: must be > 0, got -1",
        ),
        ("name: t\n", "", None),
        ("targets:\n", "target:\n", "x.yaml:11 target: unknown key (did you mean 'targets'?)"),
        ("  laser:\n", "  lazer:\n", "x.yaml:3 system.lazer: unknown key (did you mean 'laser'?)"),
        (
            "    - name: arm0\n",
            "    - name: arm0\n      model: ur10\n",
            "x.yaml:7 system.robots[0].model: unknown robot model 'ur10' (known: ur5e)",
        ),
    ],
)
def test_error_messages(tmp_path: Path, old: str, new: str, message: str | None) -> None:
    assert old in VALID
    text = VALID.replace(old, new, 1)
    if message is None:
        path = tmp_path / "x.yaml"
        path.write_text(text)
        validate_file(path)
    else:
        assert error_of(tmp_path, text) == message


def test_duplicate_robot_names(tmp_path: Path) -> None:
    robot = VALID.split("  robots:\n")[1].split("targets:")[0]
    text = VALID.replace(robot, robot + robot)
    assert (
        error_of(tmp_path, text)
        == "x.yaml:11 system.robots[1].name: duplicate robot name 'arm0' (also at [0])"
    )


def test_first_error_by_line(tmp_path: Path) -> None:
    text = VALID.replace("size: [0.075, 0.075]", "size: [1]").replace("name: t", "name: t\nfoo: 1")
    assert error_of(tmp_path, text).startswith("x.yaml:2 foo: unknown key")


def test_yaml_syntax_error(tmp_path: Path) -> None:
    text = VALID.replace("size: [0.075, 0.075]", "size: [0.075, 0.075")
    message = error_of(tmp_path, text)
    assert message.startswith("x.yaml:11: YAML syntax error:")
    assert "\n" not in message


def test_duplicate_key_is_error(tmp_path: Path) -> None:
    text = VALID.replace("name: t\n", "name: t\nname: u\n")
    assert error_of(tmp_path, text).startswith("x.yaml:2: YAML syntax error")


def test_yaml_12_numbers_and_booleans(tmp_path: Path) -> None:
    path = tmp_path / "n.yaml"
    path.write_text("a: 1e-9\nb: yes\nc: [1, 2.5]\nd: .inf\ne: 0o17\n")
    data, origins = read_yaml(path)
    assert data == {"a": 1e-9, "b": "yes", "c": [1, 2.5], "d": float("inf"), "e": 15}
    assert type(data["a"]) is float and type(data["c"][0]) is int
    assert origins[("c", 1)] == (str(path), 3)


def test_scenario_errors_are_scenario_errors(tmp_path: Path) -> None:
    path = tmp_path / "x.yaml"
    path.write_text(VALID.replace("size: [0.075, 0.075]", "size: [1]"))
    with pytest.raises(ScenarioError):
        validate_file(path)


def test_missing_file() -> None:
    with pytest.raises(InputError, match="file not found"):
        validate_file("/nonexistent/x.yaml")


def test_format_loc() -> None:
    assert format_loc(("system", "robots", 0, "mirror", "size")) == "system.robots[0].mirror.size"
    assert format_loc(()) == ""


def test_anchors_and_merge_keys(tmp_path: Path) -> None:
    path = tmp_path / "a.yaml"
    path.write_text("a: &x {b: 1}\nc:\n  <<: *x\n  d: 2\n")
    data, origins = read_yaml(path)
    assert data == {"a": {"b": 1}, "c": {"b": 1, "d": 2}}
    assert origins[("c", "d")][1] == 4 and origins[("c", "b")][1] == 2
