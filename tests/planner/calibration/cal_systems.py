"""Shared test systems for the calibration tests (no scenario file needed)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from planner.calibration.handeye import HandEyeData
from planner.calibration.simulate import DepthNoise, default_handeye_truth, simulate_handeye
from planner.model.build import build_system
from planner.model.system import Camera, Intrinsics, System
from planner.model.transforms import Array, axis_angle_to_matrix, look_at, make_T, rpy_to_matrix

AIM = np.array([0.45, 0.1, 0.0])
INTRINSICS = Intrinsics(848, 480, 430.0, 430.0, 424.0, 240.0)


def nominal_system() -> System:
    """N = 1: laser along -x into the UR5e's workspace, camera above the work area."""
    laser = make_T(rpy_to_matrix(np.deg2rad([0.0, -90.0, 0.0])), [0.9, -0.13, 0.5])
    return build_system(laser, camera=Camera(look_at([0.5, 0.8, 0.9], AIM), INTRINSICS))


def two_robot_system() -> System:
    """N = 2: arm0 as above, arm1 mounted 1 m along +y, its mirror receiving arm0's beam."""
    base = nominal_system()
    arm1 = replace(base.robots[0], name="arm1", world_T_base=make_T(p=[0.0, 0.9, 0.0]))
    return replace(base, robots=(base.robots[0], arm1))


def perturbation(rng: np.random.Generator, rad: float = 0.03, metres: float = 0.008) -> Array:
    """A random rigid perturbation: rotation vector U(-rad, rad), translation U(-m, m)."""
    return make_T(axis_angle_to_matrix(rng.uniform(-rad, rad, 3)), rng.uniform(-metres, metres, 3))


def eye_to_hand_data(
    system: System, n: int, rng: np.random.Generator, noise: DepthNoise | None = None
) -> tuple[HandEyeData, Array, Array]:
    """``n`` simulated eye_to_hand samples of arm0 at the default true poses:
    (data, world_T_camera, flange_T_board)."""
    cam, board = default_handeye_truth(system, "arm0", "eye_to_hand")
    data = simulate_handeye(system, "arm0", "eye_to_hand", n, camera_pose=cam,
                            board_pose=board, noise=noise, rng=rng)  # fmt: skip
    return data, cam, board


TRUE_CAMERA_ERROR = make_T(rpy_to_matrix(np.deg2rad([1.5, -1.0, 2.0])), [0.03, -0.02, 0.025])
"""The real fixed camera = nominal @ this (an uncalibrated camera is this far off)."""
TRUE_FLANGE_T_CAMERA = make_T(rpy_to_matrix([0.02, -0.03, np.pi / 2]), [0.004, 0.062, 0.021])
"""The real eye-in-hand camera pose on arm0's flange."""


def write_scenario(path, truth: bool = True, camera: str = "") -> None:
    """The :func:`nominal_system` as a scenario YAML (with a ``truth:`` section) at ``path``.

    ``camera``: ``"fixed"`` puts the real camera at nominal @ :data:`TRUE_CAMERA_ERROR`,
    ``"flange"`` on arm0's flange at :data:`TRUE_FLANGE_T_CAMERA` (truth only; the nominal
    camera stays the fixed one)."""
    from planner.model.transforms import matrix_to_quat

    cam = nominal_system().camera
    assert cam is not None
    T = cam.world_T_camera
    text = f"""name: calib-test
system:
  laser: {{world_T_laser: {{xyz: [0.9, -0.13, 0.5], rpy_deg: [0, -90, 0]}}}}
  robots:
    - name: arm0
      mirror: {{flange_T_mirror: {{xyz: [0, 0, 0.03]}}, size: [0.075, 0.075], roi_margin: 0.005}}
  camera:
    world_T_camera: {{xyz: {T[:3, 3].tolist()}, quat: {matrix_to_quat(T[:3, :3]).tolist()}}}
    intrinsics: {{width: 848, height: 480, fx: 430.0, fy: 430.0, cx: 424.0, cy: 240.0}}
targets:
  grid: {{center: {AIM.tolist()}, size: [0.1, 0.1, 0.1], n: [2, 2, 2]}}
"""
    if truth:
        text += """truth:
  system:
    laser: {world_T_laser: {xyz: [0.905, -0.127, 0.496], rpy_deg: [0.5, -89.0, 1.0]}}
    robots:
      - name: arm0
        mirror: {flange_T_mirror: {xyz: [0.002, -0.003, 0.034], rpy_deg: [1.0, -0.7, 2.0]}}
"""
    if truth and camera == "fixed":
        text += f"    camera: {{world_T_camera: {{matrix: {(T @ TRUE_CAMERA_ERROR).tolist()}}}}}\n"
    elif truth and camera == "flange":
        pose = f"{{matrix: {TRUE_FLANGE_T_CAMERA.tolist()}}}"
        text += f"    camera: {{robot: arm0, flange_T_camera: {pose}}}\n"
    path.write_text(text)
