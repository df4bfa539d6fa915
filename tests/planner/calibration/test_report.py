"""Calibration YAML: statistics, schema validity, and the round trip through ``include:``."""

from __future__ import annotations

import numpy as np
import pytest

from planner.beam.graph import BeamModel
from planner.calibration.beam import apply_gauge, calibrate_beam
from planner.calibration.handeye import calibrate_handeye
from planner.calibration.report import (
    beam_document,
    handeye_document,
    pose_dict,
    residual_stats,
    summary_lines,
    write_calibration,
)
from planner.calibration.simulate import default_handeye_truth, simulate_beam, simulate_handeye
from planner.io.scenario import load_scenario, system_from_scenario
from planner.model.transforms import quat_to_matrix

from .cal_systems import AIM, write_scenario


def test_residual_stats_and_pose_dict():
    s = residual_stats(np.array([0.001, 0.003, np.nan]))
    assert s == {"mean": 0.002, "std": 0.001, "max": 0.003, "n": 2}
    rng = np.random.default_rng(0)
    from .cal_systems import perturbation

    T = perturbation(rng, 2.0, 1.0)
    d = pose_dict(T)
    assert np.allclose(quat_to_matrix(d["quat"]), T[:3, :3], atol=1e-15)
    assert d["xyz"] == T[:3, 3].tolist()


def test_beam_calibration_round_trips_into_scenario_include(tmp_path):
    scn_path = tmp_path / "scn.yaml"
    write_scenario(scn_path)
    scn = load_scenario(scn_path)
    nominal, truth = system_from_scenario(scn), system_from_scenario(scn, truth=True)
    data = simulate_beam(truth, "arm0", 10, 3, aim_world=AIM, rng=np.random.default_rng(1))
    result = calibrate_beam(data, nominal)
    doc = beam_document(result, "data.json")
    write_calibration(tmp_path / "calibration.yaml", doc)

    text = scn_path.read_text().replace("targets:", "include: [calibration.yaml]\ntargets:", 1)
    (tmp_path / "scn_cal.yaml").write_text(text)
    calibrated = system_from_scenario(load_scenario(tmp_path / "scn_cal.yaml"))
    assert np.allclose(calibrated.world_T_laser, result.world_T_laser, atol=1e-14)
    M = calibrated.robots[0].mirror.flange_T_mirror
    assert np.allclose(M, result.flange_T_mirror, atol=1e-14)
    assert calibrated.robots[0].mirror.size == nominal.robots[0].mirror.size  # merged key by key
    # the included geometry changes the beam: nominal misses the true spots, calibrated hits them
    q, spot = data.q[0], data.spots_world[0]
    assert BeamModel(nominal).trace(q, spot).error > 1e-4
    assert BeamModel(calibrated).trace(q, spot).error < 1e-9
    L_t, M_t = apply_gauge(
        truth.world_T_laser,
        truth.robots[0].mirror.flange_T_mirror,
        nominal.world_T_laser,
        nominal.robots[0].mirror.flange_T_mirror,
    )
    assert np.allclose(calibrated.world_T_laser, L_t, atol=1e-9) and np.allclose(M, M_t, atol=1e-9)
    lines = summary_lines(doc)
    assert "2.04" in lines[0] and any("not calibrated: laser.tz" in x for x in lines)


def test_handeye_calibration_round_trips_camera_pose(tmp_path):
    scn_path = tmp_path / "scn.yaml"
    write_scenario(scn_path, truth=False)
    nominal = system_from_scenario(load_scenario(scn_path))
    cam, board = default_handeye_truth(nominal, "arm0", "eye_to_hand")
    from .cal_systems import perturbation

    cam = cam @ perturbation(np.random.default_rng(3))
    data = simulate_handeye(
        nominal,
        "arm0",
        "eye_to_hand",
        10,
        camera_pose=cam,
        board_pose=board,
        rng=np.random.default_rng(4),
    )
    doc = handeye_document(calibrate_handeye(data, nominal), "arm0")
    assert doc["report"]["auxiliary"]["flange_T_board"]["xyz"] == pytest.approx(
        board[:3, 3].tolist(), abs=1e-9
    )
    write_calibration(tmp_path / "he.yaml", doc)
    (tmp_path / "s2.yaml").write_text(scn_path.read_text() + "include: [he.yaml]\n")
    calibrated = system_from_scenario(load_scenario(tmp_path / "s2.yaml"))
    assert calibrated.camera is not None and nominal.camera is not None
    assert np.allclose(calibrated.camera.world_T_camera, cam, atol=1e-9)
    assert not np.allclose(nominal.camera.world_T_camera, cam, atol=1e-4)
    assert calibrated.camera.intrinsics == nominal.camera.intrinsics
