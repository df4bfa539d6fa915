"""A camera is fixed (``world_T_camera``) or on a robot's flange (``robot`` + ``flange_T_camera``)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.errors import ScenarioError
from planner.io.resolved import resolved_scenario_dict
from planner.io.scenario import (
    load_scenario,
    scenario_from_dict,
    system_from_scenario,
    targets_from_scenario,
)
from planner.model.transforms import make_T, rpy_to_matrix
from planner.verify.numpy_beam import ur5e_dh_fk

BASE = """\
name: eye-in-hand
system:
  laser: {world_T_laser: {xyz: [0.6, -0.4, 0.3], rpy_deg: [0, -90, 0]}}
  robots:
    - name: arm0
      mirror: {flange_T_mirror: {xyz: [0, 0, 0.03]}, size: [0.075, 0.075]}
    - name: arm1
      world_T_base: {xyz: [1.2, 0, 0], rpy_deg: [0, 0, 180]}
      mirror: {flange_T_mirror: {xyz: [0, 0, 0.03]}, size: [0.075, 0.075]}
  camera:
    robot: arm1
    flange_T_camera: {xyz: [0, 0.06, 0.02], rpy: [0, 0, 1.5707963267948966]}
    intrinsics: {width: 848, height: 480, fx: 430.0, fy: 430.0, cx: 424.0, cy: 240.0}
targets:
  frame: camera
  points: [[0.01, 0.02, 0.4]]
"""
FLANGE_T_CAMERA = make_T(rpy_to_matrix([0, 0, np.pi / 2]), [0, 0.06, 0.02])
WORLD_T_BASE1 = make_T(rpy_to_matrix([0, 0, np.pi]), [1.2, 0, 0])

joints = st.lists(st.floats(-3.0, 3.0), min_size=6, max_size=6).map(np.array)


@pytest.fixture(scope="module")
def scn(tmp_path_factory: pytest.TempPathFactory):
    path = tmp_path_factory.mktemp("cam") / "s.yaml"
    path.write_text(BASE)
    return load_scenario(path)


@settings(max_examples=30, deadline=None)
@given(joints, joints)
def test_world_T_camera_follows_the_flange(scn, q0: np.ndarray, q1: np.ndarray) -> None:
    system = system_from_scenario(scn)
    expected = WORLD_T_BASE1 @ ur5e_dh_fk(q1) @ FLANGE_T_CAMERA  # independent DH chain
    assert np.abs(system.world_T_camera(np.concatenate([q0, q1])) - expected).max() < 1e-9
    assert np.abs(system.world_T_camera({"arm1": q1}) - expected).max() < 1e-9
    home = system.robot("arm1").home
    at_home = WORLD_T_BASE1 @ ur5e_dh_fk(home) @ FLANGE_T_CAMERA
    assert np.abs(system.world_T_camera({"arm0": q0}) - at_home).max() < 1e-9  # arm1 unknown
    assert np.abs(system.camera.world_T_camera - at_home).max() < 1e-9  # type: ignore[union-attr]


def test_camera_frame_targets_use_the_camera_at_home(scn) -> None:
    system = system_from_scenario(scn)
    home = system.robot("arm1").home
    world_T_camera = WORLD_T_BASE1 @ ur5e_dh_fk(home) @ FLANGE_T_CAMERA
    expected = world_T_camera[:3, :3] @ [0.01, 0.02, 0.4] + world_T_camera[:3, 3]
    assert np.allclose(targets_from_scenario(scn, system).points[0], expected, atol=1e-12)


def test_camera_frame_requests_use_the_camera_at_the_start_joints(scn) -> None:
    from planner.service.handler import RequestHandler
    from schemas.messages import TargetRequest

    system = system_from_scenario(scn)
    q1 = np.array([0.3, -1.2, 1.1, -1.4, -1.6, 0.2])
    req = TargetRequest.model_validate({"schema": "beamrelay.request/1", "id": "c",
                                        "frame": "camera", "points": [[0.01, 0.02, 0.4]]})  # fmt: skip
    handler = RequestHandler(system, plan_fn=None)  # type: ignore[arg-type]
    world_T_camera = WORLD_T_BASE1 @ ur5e_dh_fk(q1) @ FLANGE_T_CAMERA
    expected = world_T_camera[:3, :3] @ [0.01, 0.02, 0.4] + world_T_camera[:3, 3]
    got = handler.targets(req, {"arm0": system.robot("arm0").home, "arm1": q1})
    assert np.allclose(got.points[0], expected, atol=1e-12)
    assert got.surface_tolerance == 0.015  # camera-frame points may land on their surface


def test_resolved_dict_keeps_the_flange_mount(scn) -> None:
    resolved = resolved_scenario_dict(scn)
    cam = resolved["system"]["camera"]
    assert set(cam) == {"robot", "flange_T_camera", "intrinsics"} and cam["robot"] == "arm1"
    again = scenario_from_dict(json.loads(json.dumps(resolved)))
    assert resolved_scenario_dict(again) == resolved
    assert np.allclose(system_from_scenario(again).camera.flange_T_camera, FLANGE_T_CAMERA)  # type: ignore[union-attr]


def test_fixed_camera_is_the_same_at_any_joints(tmp_path: Path) -> None:
    text = BASE.replace(
        "    robot: arm1\n    flange_T_camera: {xyz: [0, 0.06, 0.02], rpy: [0, 0, 1.5707963267948966]}",
        "    world_T_camera: {xyz: [1, 1, 1]}",
    )
    (tmp_path / "s.yaml").write_text(text)
    system = system_from_scenario(load_scenario(tmp_path / "s.yaml"))
    T = make_T(p=[1, 1, 1])
    assert np.array_equal(system.world_T_camera(np.ones(12)), T)
    assert system.camera is not None and system.camera.robot is None


@pytest.mark.parametrize(
    "include, mount",
    [
        ("system:\n  camera:\n    world_T_camera: {xyz: [2, 2, 2]}\n", {"world_T_camera"}),
        (
            "system:\n  camera:\n    robot: arm0\n    flange_T_camera: {xyz: [0, 0.05, 0.01]}\n",
            {"robot", "flange_T_camera"},
        ),
    ],
)
def test_an_included_mount_replaces_the_other(tmp_path: Path, include: str, mount: set) -> None:
    """A hand-eye result of either mode can be included whatever the scenario's mount was."""
    for base in (BASE, BASE.replace(
        "    robot: arm1\n    flange_T_camera: {xyz: [0, 0.06, 0.02], rpy: [0, 0, 1.5707963267948966]}",
        "    world_T_camera: {xyz: [1, 1, 1]}",
    )):  # fmt: skip
        (tmp_path / "cal.yaml").write_text(include + "report: {}\n")
        (tmp_path / "s.yaml").write_text(base + "include: [cal.yaml]\n")
        scn = load_scenario(tmp_path / "s.yaml")
        cam = scn.model.system.camera
        assert cam is not None
        assert {
            k for k in ("world_T_camera", "robot", "flange_T_camera") if getattr(cam, k)
        } == mount
        assert scn.camera_pose_file() == str(tmp_path / "cal.yaml")
        assert not scn.camera_is_nominal


def test_nominal_camera_pose_is_known(scn) -> None:
    assert scn.camera_is_nominal and scn.camera_pose_file() == scn.source


def test_half_a_flange_mount_in_an_include_is_located(tmp_path: Path) -> None:
    fixed = BASE.replace(
        "    robot: arm1\n    flange_T_camera: {xyz: [0, 0.06, 0.02], rpy: [0, 0, 1.5707963267948966]}",
        "    world_T_camera: {xyz: [1, 1, 1]}",
    )
    (tmp_path / "cal.yaml").write_text(
        "system:\n  camera:\n    flange_T_camera: {xyz: [0, 0, 0]}\n"
    )
    (tmp_path / "s.yaml").write_text(fixed + "include: [cal.yaml]\n")
    with pytest.raises(ScenarioError) as exc:
        load_scenario(tmp_path / "s.yaml")
    assert str(exc.value).startswith(f"{tmp_path / 's.yaml'}:10 system.camera.robot: missing")
