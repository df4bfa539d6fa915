"""Laser line + mirror plane: exact recovery of the observable parameters, gauge, errors."""

from __future__ import annotations

import numpy as np
import pytest

from planner.beam.graph import BeamModel
from planner.calibration.beam import BeamData, apply_gauge, calibrate_beam, calibrate_chain
from planner.calibration.simulate import DepthNoise, simulate_beam
from planner.errors import CalibrationError, DatasetError

from .cal_systems import AIM, nominal_system, perturbation, two_robot_system


def _truth(system, rng, robot="arm0", laser=True):
    i = system.robot_names.index(robot)
    M = system.robots[i].mirror.flange_T_mirror @ perturbation(rng)
    L = system.world_T_laser @ perturbation(rng) if laser else None
    return system.with_params(world_T_laser=L, flange_T_mirror={robot: M})


def test_exact_spots_recover_line_and_plane():
    system = nominal_system()
    rng = np.random.default_rng(0)
    truth = _truth(system, rng)
    data = simulate_beam(truth, "arm0", 10, 3, aim_world=AIM, rng=rng)
    res = calibrate_beam(data, system)
    L_t, M_t = apply_gauge(
        truth.world_T_laser,
        truth.robots[0].mirror.flange_T_mirror,
        system.world_T_laser,
        system.robots[0].mirror.flange_T_mirror,
    )
    assert np.abs(res.world_T_laser - L_t).max() <= 1e-9
    assert np.abs(res.flange_T_mirror - M_t).max() <= 1e-9
    assert res.residuals.max() < 1e-9
    # the calibrated model predicts the true spots exactly, although origin/centre differ
    model = BeamModel(
        system.with_params(
            world_T_laser=res.world_T_laser, flange_T_mirror={"arm0": res.flange_T_mirror}
        )
    )
    assert (
        max(model.trace(q, p).error for q, p in zip(data.q, data.spots_world, strict=True)) < 1e-9
    )
    # five unobservable directions found from the Jacobian, the four gauge statements reported
    assert len(res.detected) == 5
    assert {u["direction"] for u in res.unobservable} == {
        "laser.rz",
        "laser.tz",
        "mirror.rz",
        "mirror.txy",
    }


def test_gauge_keeps_line_and_plane_and_puts_origin_nearest_nominal():
    rng = np.random.default_rng(1)
    L0, M0 = perturbation(rng, 1.0, 0.5), perturbation(rng, 1.0, 0.1)
    L, M = L0 @ perturbation(rng), M0 @ perturbation(rng)
    Lg, Mg = apply_gauge(L, M, L0, M0)
    d = L[:3, 2]
    assert np.allclose(Lg[:3, 2], d, atol=1e-14)
    off = Lg[:3, 3] - L[:3, 3]
    assert np.linalg.norm(off - d * (d @ off)) < 1e-14  # still on the line
    assert abs(d @ (L0[:3, 3] - Lg[:3, 3])) < 1e-14  # nearest point to the nominal origin
    n = M[:3, 2]
    assert np.allclose(Mg[:3, 2], n, atol=1e-14)
    assert abs(n @ (Mg[:3, 3] - M[:3, 3])) < 1e-14  # centre on the plane
    centre = np.array([0.01, 0.0, 0.03])
    _, Mc = apply_gauge(None, M, L0, M0, mirror_centre=centre)
    assert np.allclose(Mc[:3, 3], centre - n * (n @ (centre - M[:3, 3])), atol=1e-15)


def test_second_robot_mirror_only():
    system = two_robot_system()
    rng = np.random.default_rng(2)
    truth = _truth(system, rng, "arm1", laser=False)
    data = simulate_beam(truth, "arm1", 8, 3, aim_world=AIM, rng=rng)
    res = calibrate_beam(data, system)
    assert res.world_T_laser is None
    _, M_t = apply_gauge(
        None,
        truth.robots[1].mirror.flange_T_mirror,
        system.world_T_laser,
        system.robots[1].mirror.flange_T_mirror,
    )
    assert np.abs(res.flange_T_mirror - M_t).max() <= 1e-9
    assert set(res.std) == {"mirror.rx", "mirror.ry", "mirror.tz"}


def test_noisy_plane_offset_within_three_sigma():
    system = nominal_system()
    z = []
    for seed in range(6):
        rng = np.random.default_rng(50 + seed)
        truth = _truth(system, rng)
        data = simulate_beam(truth, "arm0", 16, 3, aim_world=AIM, noise=DepthNoise(), rng=rng)
        res = calibrate_beam(data, system, starts=1)
        _, M_t = apply_gauge(
            None,
            truth.robots[0].mirror.flange_T_mirror,
            system.world_T_laser,
            system.robots[0].mirror.flange_T_mirror,
        )
        n_t, n = M_t[:3, 2], res.flange_T_mirror[:3, 2]
        z.append((n @ res.flange_T_mirror[:3, 3] - n_t @ M_t[:3, 3]) / res.std["mirror.tz"])
        # normal tilt error against the two tilt std devs (small-angle, mirror axes)
        R = res.flange_T_mirror[:3, :3]
        tilt = np.cross(n, n_t) @ R
        z.append(tilt[0] / res.std["mirror.rx"])
        z.append(tilt[1] / res.std["mirror.ry"])
    z = np.abs(np.array(z))
    assert np.all(z <= 3.5) and np.mean(z <= 3.0) >= 0.9


def test_same_pose_for_every_spot_is_unobservable_and_named():
    system = nominal_system()
    rng = np.random.default_rng(3)
    data = simulate_beam(system, "arm0", 6, 2, aim_world=AIM, rng=rng)
    model = BeamModel(system)
    q = np.repeat(data.q[:1], 8, axis=0)
    tr = model.trace(q[0])
    spots = tr.hits[-1] + np.outer(np.linspace(0.3, 0.8, 8), tr.dirs[-1])
    with pytest.raises(CalibrationError, match="unobservable") as info:
        calibrate_beam(BeamData("arm0", q, spots, np.arange(8) % 2), system, starts=1)
    assert info.value.directions


def test_insufficient_and_malformed_data():
    system = nominal_system()
    rng = np.random.default_rng(4)
    data = simulate_beam(system, "arm0", 3, 1, aim_world=AIM, rng=rng)
    with pytest.raises(DatasetError, match="need at least 4 spots"):
        calibrate_beam(data, system)
    with pytest.raises(DatasetError, match="unknown robot"):
        calibrate_beam(BeamData("arm9", data.q, data.spots_world, data.boards), system)
    with pytest.raises(DatasetError, match="expected 6 joints"):
        calibrate_beam(BeamData("arm0", data.q[:, :5], data.spots_world, data.boards), system)


def test_single_board_placement_is_flagged():
    system = nominal_system()
    rng = np.random.default_rng(5)
    data = simulate_beam(_truth(system, rng), "arm0", 12, 1, aim_world=AIM, rng=rng)
    res = calibrate_beam(data, system, starts=1)
    assert any("single board" in w for w in res.warnings)


def test_chain_calibrates_each_mirror_holding_the_ones_before():
    system = two_robot_system()
    rng = np.random.default_rng(4)
    truth = _truth(_truth(system, rng), rng, "arm1", laser=False)
    seen = []

    def collect(current, robot):
        seen.append((robot, current.world_T_laser.copy()))
        return simulate_beam(truth, robot, 8, 3, aim_world=AIM, rng=rng)

    cal, results = calibrate_chain(system, collect)
    assert [r.robot for r in results] == ["arm0", "arm1"]
    # arm1's spots were collected (and fitted) with the laser already calibrated
    assert np.array_equal(seen[0][1], system.world_T_laser)
    assert np.array_equal(seen[1][1], results[0].world_T_laser)
    assert np.array_equal(cal.world_T_laser, results[0].world_T_laser)
    for i, name in enumerate(("arm0", "arm1")):
        L_t, M_t = apply_gauge(
            truth.world_T_laser,
            truth.robots[i].mirror.flange_T_mirror,
            system.world_T_laser,
            system.robots[i].mirror.flange_T_mirror,
        )
        assert np.abs(cal.robot(name).mirror.flange_T_mirror - M_t).max() <= 1e-9
        assert np.abs(cal.world_T_laser - L_t).max() <= 1e-9
    assert set(results[1].std) == {"mirror.rx", "mirror.ry", "mirror.tz"}


def test_chain_refuses_data_of_the_wrong_robot():
    system = two_robot_system()
    rng = np.random.default_rng(5)
    with pytest.raises(DatasetError, match="expected 'arm0'"):
        calibrate_chain(system, lambda s, r: simulate_beam(s, "arm1", 8, 3, aim_world=AIM, rng=rng))
