"""The simulated camera's depth errors on a wall square to the optical axis: the mean error is
the bias of the camera's disparity offset, the noise of neighbouring pixels is correlated as
the census window makes it, the spot carries the same bias."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.camera.sim import SimCamera, depth_sigma
from planner.model import d435
from planner.model.scene import SceneItem
from planner.model.transforms import make_T
from planner.studies import experiments_setup as setup

Z_WALL = 0.87  # m from the camera, along its optical axis
OFFSET = -0.15  # px: a camera that measures long


def wall_camera(errors: d435.DepthErrors | None, stride: int = 1, seed: int = 4) -> SimCamera:
    """The paper_n1 camera facing a 3 m square wall (its near face Z_WALL ahead)."""
    system = setup.nominal_system()
    assert system.camera is not None
    T = system.camera.world_T_camera @ make_T(p=[0.0, 0.0, Z_WALL + 0.005])
    wall = SceneItem("wall", "box", T, extents=np.array([3.0, 3.0, 0.01]))
    return SimCamera(system, [wall], stride=stride, seed=seed, depth_errors=errors)


def test_cloud_depth_error_mean_is_the_bias_and_its_spread_the_pixel_rms() -> None:
    cam = wall_camera(d435.DepthErrors(correlated=True, disparity_offset_px=OFFSET))
    pts, _ = cam.points()
    assert len(pts) == 848 * 480
    err = pts[:, 2].astype(float) - Z_WALL
    bias = Z_WALL / (1 + Z_WALL * OFFSET / (430.0 * 0.05)) - Z_WALL  # triangulation, by hand
    sigma = float(depth_sigma(Z_WALL, 430.0))
    n_eff = len(err) / d435.CENSUS_PX**2  # independent boxes in the image, roughly
    assert np.mean(err) == pytest.approx(bias, abs=4 * sigma / np.sqrt(n_eff))
    assert bias > 0.003  # a real offset: the test would see a missing bias
    assert np.std(err) == pytest.approx(sigma, rel=0.03)


@pytest.mark.parametrize("axis", [0, 1])
def test_neighbouring_pixels_are_correlated_over_the_census_window(axis: int) -> None:
    cam = wall_camera(d435.DepthErrors(correlated=True))
    pts, _ = cam.points()
    e = ((pts[:, 2].astype(float) - Z_WALL) / float(depth_sigma(Z_WALL, 430.0))).reshape(480, 848)
    e = e if axis == 1 else e.T
    for lag in (1, 3, 6, 9, 12):
        rho = np.mean(e[:, :-lag] * e[:, lag:]) / np.mean(e * e)
        assert rho == pytest.approx(max(0.0, 1 - lag / d435.CENSUS_PX), abs=0.03), lag


def test_without_errors_the_pixels_are_independent_and_unbiased() -> None:
    cam = wall_camera(None)
    pts, _ = cam.points()
    e = (pts[:, 2].astype(float) - Z_WALL).reshape(480, 848)
    assert abs(np.mean(e)) < 3 * float(depth_sigma(Z_WALL, 430.0)) / np.sqrt(e.size)
    assert abs(np.mean(e[:, :-1] * e[:, 1:]) / np.mean(e * e)) < 0.01


def test_a_strided_cloud_samples_the_same_field() -> None:
    cam = wall_camera(d435.DepthErrors(correlated=True), stride=4)
    pts, _ = cam.points()
    assert len(pts) == 212 * 120
    e = ((pts[:, 2].astype(float) - Z_WALL) / float(depth_sigma(Z_WALL, 430.0))).reshape(120, 212)
    rho = np.mean(e[:, :-1] * e[:, 1:]) / np.mean(e * e)  # 4 px apart
    assert rho == pytest.approx(1 - 4 / d435.CENSUS_PX, abs=0.04)


def test_spot_and_markers_carry_the_bias() -> None:
    errors = d435.DepthErrors(correlated=True, disparity_offset_px=OFFSET)
    cam = wall_camera(errors)
    p_c = np.array([0.03, -0.02, Z_WALL])  # a spot on the wall, camera frame
    assert cam.system.camera is not None
    world_T_camera = cam.system.camera.world_T_camera
    spot_w = world_T_camera[:3, :3] @ p_c + world_T_camera[:3, 3]
    normal = -world_T_camera[:3, 2]
    cam.true_spot_world = lambda: (spot_w, -normal, normal)  # type: ignore[method-assign]
    got = np.array([cam.spot().p_camera for _ in range(20000)])  # type: ignore[union-attr]
    spot = d435.SPOT.with_focal(430.0).with_errors(errors, median=True)
    bias = float(d435.biased_depth(Z_WALL, OFFSET, 430.0)) - Z_WALL
    assert np.mean(got[:, 2]) - Z_WALL == pytest.approx(bias, abs=4 * spot.depth_rms(Z_WALL) / 141)
    assert np.std(got[:, 2]) == pytest.approx(float(spot.depth_rms(Z_WALL)), rel=0.03)
    # the camera's own markers: same bias (no correlation draw needed for a mean)
    cam.on_joint_state("arm0", cam.system.robots[0].home)
    board = np.zeros((1, 3))
    pose = np.linalg.inv(cam.system.robots[0].kinematics.fk(cam.system.robots[0].home))
    pose = pose @ world_T_camera @ make_T(p=[0.0, 0.0, Z_WALL])
    req = {"board_points": board.tolist(), "board_pose": pose.tolist(), "robot": "arm0"}
    z = np.array([cam.markers(req)[0, 2] for _ in range(4000)])
    corner = d435.CORNER.with_focal(430.0).with_errors(errors)
    assert np.mean(z) - Z_WALL == pytest.approx(bias, abs=4 * corner.depth_rms(Z_WALL) / 63)
