"""The paper's calibration design on the simulated cell: random hand-eye poses, the laser
spot driven onto known fiducials, and the effect that switches the calibration to it."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from planner.beam.trace import trace_beam
from planner.calibration.beam import apply_gauge, calibrate_beam
from planner.calibration.collect import (
    condition,
    handeye_jacobian,
    handeye_plan,
    random_handeye_plan,
)
from planner.calibration.simulate import board_grid
from planner.model import d435
from planner.model.transforms import inv_T
from planner.studies import experiments_fiducials as fid
from planner.studies import experiments_setup as setup
from planner.studies.experiments_cell import board_cells

SILENT = d435.D435Noise(subpixel=0.0, lateral_px=0.0)


@pytest.fixture
def silent_camera(monkeypatch: pytest.MonkeyPatch) -> None:
    """The D435 without noise (spots and corners)."""
    monkeypatch.setattr(d435, "SPOT", SILENT)
    monkeypatch.setattr(d435, "CORNER", SILENT)


def _random_plan(seed: int) -> tuple[np.ndarray, float]:
    nominal = setup.nominal_system()
    return random_handeye_plan(nominal, "arm0", "eye_to_hand", 20, board_grid(),
                               setup.NOMINAL_BOARD, np.random.default_rng(seed))  # fmt: skip


def test_random_handeye_poses_are_reproducible_reachable_and_see_the_whole_board() -> None:
    nominal = setup.nominal_system()
    cam = nominal.camera
    assert cam is not None
    qs, cond = _random_plan(7)
    again, _ = _random_plan(7)
    other, _ = _random_plan(8)
    assert qs.shape == (20, 6) and np.array_equal(qs, again)
    assert not np.allclose(qs, other)
    r, k = nominal.robots[0], cam.intrinsics
    assert np.all(qs >= r.limits.lower) and np.all(qs <= r.limits.upper)
    board = board_grid()
    for q in qs:  # the board's every corner in front of the camera and inside the image
        T = inv_T(cam.world_T_camera) @ r.world_T_base @ r.kinematics.fk(q) @ setup.NOMINAL_BOARD
        p = board @ T[:3, :3].T + T[:3, 3]
        u, v = k.fx * p[:, 0] / p[:, 2] + k.cx, k.fy * p[:, 1] / p[:, 2] + k.cy
        assert np.all(p[:, 2] > 0.1)
        assert np.all((u >= 0) & (u < k.width) & (v >= 0) & (v < k.height))
    # the reported condition number is the poses' own; the conditioning search beats it
    J = handeye_jacobian(nominal, "arm0", "eye_to_hand", qs, board, cam.world_T_camera,
                         setup.NOMINAL_BOARD)  # fmt: skip
    assert cond == pytest.approx(condition(J), rel=1e-6)
    _, best = handeye_plan(nominal, "arm0", "eye_to_hand", 20, board, setup.NOMINAL_BOARD,
                           np.random.default_rng(7))  # fmt: skip
    assert best < cond


def test_fiducial_pairs_without_noise_recover_the_true_line_and_plane() -> None:
    """Joints that put the TRUE spot exactly on each fiducial (the truth's own IK), with
    the fiducials' true positions: the calibration gives the truth's line and plane."""
    from planner.ik import BeamIK
    from planner.plan.scenario_planner import ik_options

    nominal = setup.nominal_system()
    truth = setup.draw_truth(nominal, setup.Unknowns(), np.random.default_rng(3))
    ik = BeamIK(truth.system, ik_options(setup.solver_settings()))
    up = np.array([0.0, 0.0, 1.0])
    runs = []
    for z in setup.CALIBRATION_BOARDS:
        f = fid.board_fiducials(z)
        qs = np.array([ik.solve(p, up, nominal.home).q for p in f])
        for q, p in zip(qs, f, strict=True):  # the data are what they claim, independently
            assert np.linalg.norm(trace_beam(truth.system, q, p, up).spot - p) < 1e-9
        runs.append(fid.FiducialRuns(f, f, qs, np.zeros(len(f)), np.ones(len(f), bool)))
    data = fid.fiducial_beam_data("arm0", runs)
    assert len(data.q) == 48 and set(data.boards.tolist()) == {0, 1, 2}
    res = calibrate_beam(data, nominal)
    L_t, M_t = apply_gauge(truth.system.world_T_laser,
                           truth.system.robots[0].mirror.flange_T_mirror,
                           nominal.world_T_laser, nominal.robots[0].mirror.flange_T_mirror)  # fmt: skip
    assert res.world_T_laser is not None and L_t is not None
    assert np.max(res.residuals) < 1e-9
    assert np.max(np.abs(res.world_T_laser - L_t)) < 1e-6
    assert np.max(np.abs(res.flange_T_mirror - M_t)) < 1e-6
    # and the nominal geometry is far from it: the test can fail
    assert np.max(np.abs(nominal.world_T_laser - L_t)) > 1e-3


def test_the_servo_drives_the_true_spot_onto_the_true_fiducials(silent_camera: None) -> None:
    nominal = setup.nominal_system()
    rng = np.random.default_rng(5)
    truth = setup.draw_truth(nominal, setup.Unknowns(), rng)
    assert truth.system.camera is not None
    cam = truth.system.camera.world_T_camera  # an exact hand-eye calibration
    runs = fid.fiducial_runs(nominal, cam, board_cells(truth, rng))
    tol = 3e-4  # m, the servo's default tolerance (schemas.defaults.SERVO_TOLERANCE_M)
    up = np.array([0.0, 0.0, 1.0])
    for z, run in zip(setup.CALIBRATION_BOARDS, runs, strict=True):
        # located without noise: the known pattern where it truly is (open3d: float32)
        assert np.max(np.abs(run.located_world - fid.board_fiducials(z))) < 1e-5
        ok = run.converged
        assert ok.sum() >= 12 and np.all(np.isfinite(run.q[ok]))
        for q, p in zip(run.q[ok], run.true_world[ok], strict=True):
            assert np.linalg.norm(trace_beam(truth.system, q, p, up).spot - p) < tol + 1e-5
        assert np.max(run.error[ok]) < tol  # what the servo measured at the end
        # the runs that stopped short still left the spot near its fiducial (2 x tolerance:
        # the servo's noise floor, where it stops asking for improvement)
        kept = np.all(np.isfinite(run.q), axis=1)
        assert np.nanmax(run.error[kept]) < 2 * tol


def test_the_effect_switches_the_calibration_input_data(monkeypatch: pytest.MonkeyPatch) -> None:
    from planner.calibration import beam, handeye
    from planner.studies.experiments_cell import calibrate_cell

    seen: dict[str, list[Any]] = {"handeye": [], "beam": []}
    real_he, real_bm = handeye.calibrate_handeye, beam.calibrate_beam

    def he(data: Any, nominal: Any) -> Any:
        seen["handeye"].append(data)
        return real_he(data, nominal)

    def bm(data: Any, nominal: Any) -> Any:
        seen["beam"].append(data)
        return real_bm(data, nominal)

    monkeypatch.setattr(handeye, "calibrate_handeye", he)
    monkeypatch.setattr(beam, "calibrate_beam", bm)
    nominal = setup.nominal_system()
    truth = setup.draw_truth(nominal, setup.Unknowns(), np.random.default_rng(2))
    for paper in (False, True):
        calibrate_cell(nominal, truth, np.random.default_rng(9), paper=paper)
    ours, paper_he = seen["handeye"]
    assert len(ours.q) == len(paper_he.q) == 20 and not np.allclose(ours.q, paper_he.q)
    ours_b, paper_b = seen["beam"]
    grid = np.vstack([fid.board_fiducials(z) for z in setup.CALIBRATION_BOARDS])

    def to_grid(p: np.ndarray) -> np.ndarray:
        return np.min(np.linalg.norm(p[:, None] - grid[None], axis=2), axis=1)

    assert np.max(to_grid(paper_b.spots_world)) < 0.003  # fiducials, as the camera located them
    assert np.median(to_grid(ours_b.spots_world)) > 0.005  # spots wherever the poses sent them
