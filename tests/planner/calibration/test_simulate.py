"""Synthetic datasets: noise model figures, physically valid poses, visibility."""

from __future__ import annotations

import numpy as np

from planner.beam.graph import BeamModel
from planner.calibration.simulate import (
    BOARD_HALF,
    DepthNoise,
    aim_chain,
    board_grid,
    simulate_beam,
)
from planner.model.transforms import inv_T, transform_points

from .cal_systems import AIM, INTRINSICS, eye_to_hand_data, nominal_system, two_robot_system


def test_d435_depth_rms_formula_and_empirical_spread():
    noise = DepthNoise(lateral_px=0.0)
    assert noise.depth_rms(np.array(1.0)) == np.float64(1.0) * 0.08 / (430.0 * 0.050)
    assert np.isclose(noise.depth_rms(np.array(2.0)), 4 * 0.08 / 21.5)
    rng = np.random.default_rng(0)
    p = np.tile([0.0, 0.0, 1.5], (20000, 1))
    dz = noise.apply(p, rng)[:, 2] - 1.5
    assert abs(dz.std() / noise.depth_rms(np.array(1.5)) - 1.0) < 0.03
    out = DepthNoise(subpixel=0.0, lateral_px=0.0, outliers=0.1).apply(p, rng)
    frac = np.mean(np.linalg.norm(out - p, axis=1) > 0.0099)
    assert 0.08 < frac < 0.12


def test_board_grid_is_centred_and_spaced():
    g = board_grid(7, 5, 0.03)
    assert g.shape == (35, 3) and np.allclose(g.mean(axis=0), 0.0)
    assert np.isclose(np.ptp(g[:, 0]), 0.18) and np.isclose(np.ptp(g[:, 1]), 0.12)


def test_aim_chain_sends_beam_through_aim_point_n1_and_n2():
    for system, robot in ((nominal_system(), "arm0"), (two_robot_system(), "arm1")):
        q = aim_chain(system, robot, AIM)
        chain = type(system)(system.world_T_laser, system.robots[: len(q) // 6], system.camera)
        tr = BeamModel(chain).trace(q, AIM)
        assert tr.valid and tr.error < 1e-9


def test_beam_samples_are_valid_and_on_their_boards():
    system = nominal_system()
    data = simulate_beam(system, "arm0", 6, 3, aim_world=AIM, rng=np.random.default_rng(1))
    model = BeamModel(system)
    assert np.bincount(data.boards).tolist() == [6, 6, 6]
    for q, spot in zip(data.q, data.spots_world, strict=True):
        assert np.all(q >= system.lower) and np.all(q <= system.upper)
        tr = model.trace(q, spot)
        assert tr.valid and tr.error < 1e-12  # exact data: the spot lies on the true beam
    # boards are squares of side 2*BOARD_HALF: spots of one board lie within its diagonal
    for b in range(3):
        s = data.spots_world[data.boards == b]
        assert np.max(np.linalg.norm(s - s.mean(axis=0), axis=1)) < 2 * np.sqrt(2) * BOARD_HALF


def test_handeye_samples_are_visible_and_consistent():
    system = nominal_system()
    data, cam, board = eye_to_hand_data(system, 8, np.random.default_rng(2))
    r = system.robots[0]
    k = INTRINSICS
    for q, pts in zip(data.q, data.points_camera, strict=True):
        expect = transform_points(inv_T(cam) @ r.kinematics.fk(q) @ board, data.board_points)
        assert np.allclose(pts, expect, atol=1e-12)
        u = k.fx * pts[:, 0] / pts[:, 2] + k.cx
        v = k.fy * pts[:, 1] / pts[:, 2] + k.cy
        assert np.all((u >= 0) & (u < k.width) & (v >= 0) & (v < k.height) & (pts[:, 2] > 0))
        # the board faces the camera: its +z points back toward the camera centre
        c_T_b = inv_T(cam) @ r.kinematics.fk(q) @ board
        assert c_T_b[:3, 2] @ (-c_T_b[:3, 3]) > 0
