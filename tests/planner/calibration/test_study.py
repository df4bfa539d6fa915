"""``study calibration``: trial functions on exact data, the summary and the written report.

(Kept here rather than under tests/planner/studies/ so this area owns all its test files.)
"""

from __future__ import annotations

import json

import numpy as np

from planner.studies import calibration as study


def test_exact_trials_meet_paper_bounds():
    he = study.handeye_trial(seed=0, trial=0, n_poses=20, noisy=False)
    bm = study.beam_trial(seed=0, trial=0, n_poses=16, noisy=False)
    for row in (he, bm):
        assert max(row["pos_err_mm"], row["aux_pos_err_mm"]) < 1e-6  # paper: < 1e-5 mm
        assert max(row["rot_err_deg"], row["aux_rot_err_deg"]) < 1e-7  # paper: < 1e-6 deg
        assert row["residual_mean_mm"] < 1e-9
    assert bm["spot_err_mm"] < 1e-6


def test_beam_calibration_converges_from_the_papers_5_deg():
    """The default perturbation is the paper's 5 deg (truths tilted beyond what 2 deg per
    axis can give, sqrt(2) * 2 deg), and the noise-free fit still recovers them exactly."""
    assert study.PERTURB_DEG == 5.0
    rows = [study.beam_trial(seed=1, trial=t, n_poses=16, noisy=False) for t in range(4)]
    assert max(r["true_tilt_deg"] for r in rows) > np.sqrt(2) * 2.0
    for r in rows:
        assert r["converged"] and r["perturb_deg"] == 5.0
        assert max(r["pos_err_mm"], r["aux_pos_err_mm"]) < 1e-6  # paper: < 1e-5 mm
        assert max(r["rot_err_deg"], r["aux_rot_err_deg"]) < 1e-7  # paper: < 1e-6 deg
    low = study.beam_trial(seed=1, trial=0, n_poses=16, noisy=False, deg=2.0)
    assert low["true_tilt_deg"] < np.sqrt(2) * 2.0 + 1e-9 and low["pos_err_mm"] < 1e-6


def test_angle_helpers_are_accurate_near_zero():
    from planner.model.transforms import axis_angle_to_matrix

    assert np.isclose(
        study._angle(axis_angle_to_matrix([1e-10, 0, 0])), np.rad2deg(1e-10), rtol=1e-6
    )
    assert np.isclose(
        study._between(np.array([1.0, 0, 0]), np.array([np.cos(1e-11), np.sin(1e-11), 0])),
        1e-11,
        rtol=1e-6,
    )


def test_command_writes_csv_png_report_and_json(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(study, "SWEEP", {"handeye": (10,), "beam": (8,)})
    monkeypatch.setattr(study, "EXACT_POSES", {"handeye": 10, "beam": 8})
    study.command(trials=1, seed=3, out=tmp_path, workers=1, dask_scheduler=None, json_out=True)
    figures = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert figures["handeye"]["exact_max_pos_err_mm"] < 1e-6
    assert figures["beam"]["d435_residual_mean_mm"] > 0.1  # D435 noise at ~1 m is mm-level
    for name in ("calibration.csv", "calibration_vs_poses.png", "report.md"):
        assert (tmp_path / name).stat().st_size > 0
    text = (tmp_path / "report.md").read_text()
    assert "1.13 ± 0.50" in text and "±5 deg" in text and "±2 deg" in text
    assert figures["beam"]["perturb_deg"] == 5.0 and figures["beam"]["also"]["perturb_deg"] == 2.0
