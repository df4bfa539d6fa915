"""Values in the wrong unit or frame: one located error (or warning) naming the likely mistake."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from planner.errors import InputError
from planner.io.validate import validate_file
from tests.cli_run import assert_usage_error, beamrelay
from tests.paths import REPO

ROOT = REPO

VALID = """\
name: t
system:
  laser:
    world_T_laser: {xyz: [0.6, -0.4, 0.3], rpy_deg: [0, -90, 0]}
  robots:
    - name: arm0
      home: [0, -1.5708, 1.5708, -1.5708, -1.5708, 0]
      limits: {velocity: [3, 3, 3, 3, 3, 3], acceleration: [5, 5, 5, 5, 5, 5]}
      mirror:
        flange_T_mirror: {xyz: [0, 0, 0.03]}
        size: [0.075, 0.075]
        roi_margin: 0.005
  camera:
    world_T_camera: {xyz: [1, 1, 1], rpy: [0, 0, 0]}
    intrinsics: {width: 848, height: 480, fx: 430.0, fy: 430.0, cx: 424.0, cy: 240.0}
targets:
  frame: world
  points:
    - [0.5, 0.1, 0.4]
    - [0.5, 0.2, 0.4]
trajectory: {spot_speed: 0.02}
solver: {tolerance: 1.0e-9}
"""


def message(tmp_path: Path, old: str, new: str) -> str:
    assert old in VALID, old
    path = tmp_path / "x.yaml"
    path.write_text(VALID.replace(old, new, 1))
    with pytest.raises(InputError) as info:
        validate_file(path)
    return str(info.value).replace(str(tmp_path) + "/", "")


def test_baseline_is_valid_and_quiet(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    path = tmp_path / "x.yaml"
    path.write_text(VALID)
    with caplog.at_level(logging.WARNING, logger="beamrelay.input"):
        assert validate_file(path)[0] == "scenario"
    assert caplog.records == []


@pytest.mark.parametrize(
    "old, new, where, words",
    [
        # degrees where radians belong
        ("rpy_deg: [0, -90, 0]", "rpy: [0, -90, 0]", "x.yaml:4 system.laser.world_T_laser.rpy[1]",
         "beyond 2 pi: rpy is in radians; for degrees write rpy_deg"),
        ("velocity: [3, 3, 3, 3, 3, 3]", "velocity: [180, 180, 180, 180, 180, 180]",
         "x.yaml:8 system.robots[0].limits.velocity[0]", "did you give deg/s?"),
        ("acceleration: [5, 5, 5, 5, 5, 5]", "acceleration: [5, 5, 5, 5, 286, 5]",
         "x.yaml:8 system.robots[0].limits.acceleration[4]", "did you give deg/s^2?"),
        ("velocity: [3, 3, 3, 3, 3, 3]", "velocity: [3, 3, 3, 3, 3, 3], jerk: [5e4, 50, 50, 50, 50, 50]",
         "x.yaml:8 system.robots[0].limits.jerk[0]", "did you give deg/s^3?"),
        ("velocity: [3, 3, 3, 3, 3, 3]", "velocity: [3, 3, 3, 3, 3, 3], upper: [360, 360, 180, 360, 360, 360]",
         "x.yaml:8 system.robots[0].limits.upper[0]", "did you give degrees?"),
        ("home: [0, -1.5708, 1.5708, -1.5708, -1.5708, 0]", "home: [0, -90, 90, -90, -90, 0]",
         "x.yaml:7 system.robots[0].home[1]", "did you give degrees?"),
        # millimetres where metres belong
        ("size: [0.075, 0.075]", "size: [75, 75]", "x.yaml:11 system.robots[0].mirror.size[0]",
         "did you give millimetres?"),
        ("flange_T_mirror: {xyz: [0, 0, 0.03]}", "flange_T_mirror: {xyz: [0, 0, 30]}",
         "x.yaml:10 system.robots[0].mirror.flange_T_mirror.xyz", "did you give millimetres?"),
        ("roi_margin: 0.005", "roi_margin: 5", "x.yaml:12 system.robots[0].mirror.roi_margin",
         "did you give millimetres?"),
        ("roi_margin: 0.005", "roi_margin: 0.04", "x.yaml:12 system.robots[0].mirror.roi_margin",
         "is not below half the mirror (0.0375 m)"),
        ("xyz: [0.6, -0.4, 0.3]", "xyz: [600, -400, 300]", "x.yaml:4 system.laser.world_T_laser.xyz",
         "did you give millimetres?"),
        ("    - name: arm0\n", "    - name: arm0\n      world_T_base: {xyz: [1200, 0, 0]}\n",
         "x.yaml:7 system.robots[0].world_T_base.xyz", "did you give millimetres?"),
        ("    - [0.5, 0.2, 0.4]", "    - [500, 200, 400]", "x.yaml:20 targets.points[1]",
         "did you give millimetres?"),
        ("spot_speed: 0.02", "spot_speed: 20", "x.yaml:21 trajectory.spot_speed", "did you give mm/s?"),
        ("tolerance: 1.0e-9", "tolerance: 0.5", "x.yaml:22 solver.tolerance", "did you give millimetres?"),
        # wrong frame
        ("  frame: world\n  points:\n    - [0.5, 0.1, 0.4]",
         "  frame: camera\n  points:\n    - [0.5, 0.1, -0.2]",
         "x.yaml:19 targets.points[0]", "not in front of the camera"),
        # a camera mounted twice, or not at all
        ("    world_T_camera: {xyz: [1, 1, 1], rpy: [0, 0, 0]}\n",
         "    world_T_camera: {xyz: [1, 1, 1], rpy: [0, 0, 0]}\n    robot: arm0\n",
         "x.yaml:15 system.camera.robot", "either world_T_camera"),
        ("    world_T_camera: {xyz: [1, 1, 1], rpy: [0, 0, 0]}\n", "",
         "x.yaml:13 system.camera", "needs world_T_camera (a fixed camera) or robot + flange_T_camera"),
        ("    world_T_camera: {xyz: [1, 1, 1], rpy: [0, 0, 0]}\n",
         "    robot: arm9\n    flange_T_camera: {xyz: [0, 0.06, 0.02]}\n",
         "x.yaml:14 system.camera.robot", "no robot named 'arm9'"),
        ("    world_T_camera: {xyz: [1, 1, 1], rpy: [0, 0, 0]}\n",
         "    robot: arm0\n    flange_T_camera: {xyz: [0, 60, 20]}\n",
         "x.yaml:15 system.camera.flange_T_camera.xyz", "did you give millimetres?"),
    ],
)  # fmt: skip
def test_wrong_unit_or_frame_is_one_located_error(
    tmp_path: Path, old: str, new: str, where: str, words: str
) -> None:
    text = message(tmp_path, old, new)
    assert text.startswith(where + ": "), text
    assert words in text and "\n" not in text


def test_plausible_values_pass(tmp_path: Path) -> None:
    """The bounds leave room for real set-ups: a wrist at 2 pi rad/s, a 0.3 m mirror, +-2 pi."""
    text = VALID.replace("velocity: [3, 3, 3, 3, 3, 3]", "velocity: [3, 3, 3, 6.2, 6.2, 6.2]")
    text = text.replace("size: [0.075, 0.075]", "size: [0.3, 0.3]")
    text = text.replace("rpy: [0, 0, 0]", "rpy: [6.2831853, -3.14159, 0]")
    path = tmp_path / "x.yaml"
    path.write_text(text)
    assert validate_file(path)[0] == "scenario"


@pytest.mark.parametrize(
    "old, new, where, words",
    [
        ("rpy_deg: [0, -90, 0]", "rpy_deg: [0, -1.5708, 0]",
         "x.yaml:4 system.laser.world_T_laser.rpy_deg", "looks like radians"),
        ("rpy: [0, 0, 0]", "quat: [0, 0, 90, 1]", "x.yaml:14 system.camera.world_T_camera.quat",
         "far from a unit quaternion"),
        ("velocity: [3, 3, 3, 3, 3, 3]", "velocity: [3, 3, 3, 3, 3, 6]",
         "x.yaml:8 system.robots[0].limits.velocity[5]", "above the UR5e datasheet maximum"),
        ("tolerance: 1.0e-9", "tolerance: 1.0e-9, max_incidence_deg: 1.4",
         "x.yaml:22 solver.max_incidence_deg", "looks like radians"),
    ],
)  # fmt: skip
def test_suspicious_values_warn_with_location(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, old: str, new: str, where: str, words: str
) -> None:
    path = tmp_path / "x.yaml"
    path.write_text(VALID.replace(old, new, 1))
    with caplog.at_level(logging.WARNING, logger="beamrelay.input"):
        assert validate_file(path)[0] == "scenario"
    lines = [r.getMessage().replace(str(tmp_path) + "/", "") for r in caplog.records]
    assert len(lines) == 1 and lines[0].startswith(f"warning: {where}: "), lines
    assert words in lines[0]


def test_degrees_as_radians_stops_plan_with_exit_2(tmp_path: Path) -> None:
    """The shipped scenario with ``rpy: [40, 0, 0]`` used to plan 1000/1000 targets."""
    text = (ROOT / "scenarios/paper_n1.yaml").read_text()
    assert "rpy_deg: [40, 0, 0]" in text
    path = tmp_path / "deg.yaml"
    path.write_text(text.replace("rpy_deg: [40, 0, 0]", "rpy: [40, 0, 0]"))
    proc = beamrelay("plan", path, "-o", tmp_path / "plan.json")
    assert_usage_error(proc, f"{path}:22 system.laser.world_T_laser.rpy[0]: 40 rad is beyond 2 pi")
    assert not (tmp_path / "plan.json").exists()


def test_unit_mistakes_in_validate_exit_2_one_line(tmp_path: Path) -> None:
    path = tmp_path / "x.yaml"
    path.write_text(VALID.replace("size: [0.075, 0.075]", "size: [75, 75]"))
    proc = beamrelay("validate", path)
    assert_usage_error(proc, f"{path}:11 system.robots[0].mirror.size[0]: 75 m", "millimetres")


def test_warning_is_one_stderr_line_and_exit_0(tmp_path: Path) -> None:
    path = tmp_path / "x.yaml"
    path.write_text(VALID.replace("rpy_deg: [0, -90, 0]", "rpy_deg: [0, -1.5708, 0]"))
    proc = beamrelay("validate", path)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.strip().splitlines() == [
        f"warning: {path}:4 system.laser.world_T_laser.rpy_deg: [0.0, -1.5708, 0.0] looks like"
        " radians (multiples of pi/4); rpy_deg is in degrees, for radians write rpy"
    ]
