"""``study experiments --ablate``: the servo lag on a swept path against the lookahead, the
error budget's arithmetic against hand values, the ladder and the command line."""

from __future__ import annotations

import itertools
from dataclasses import fields
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import stats

from drivers.robot.servo_lag import ServoSettings
from planner.beam.trace import trace_beam
from planner.errors import InputError
from planner.studies import experiments_ablation as abl
from planner.studies import experiments_setup as setup
from planner.studies.experiments_metrics import closest_point_error
from planner.studies.experiments_trial import plan_targets, swept_joints


def _ik(system: object) -> object:
    from planner.ik import BeamIK
    from planner.plan.scenario_planner import ik_options

    return BeamIK(system, ik_options(setup.solver_settings()))  # type: ignore[arg-type]


def test_a_swept_path_trails_its_samples_by_the_lookahead() -> None:
    """The curve planned exactly, swept at the scenario's spot speed: once the start
    transient is over, the true spot is lookahead x speed behind each sample along the path
    (and still on the path: the closest-point metric does not see the lag)."""
    nominal = setup.nominal_system()
    exp = setup.curve()
    sols = plan_targets(exp.metric, exp.points, exp.normals, nominal.home, _ik(nominal))
    speed = setup.spot_speed()
    lagged = swept_joints(exp, exp.points, sols, speed)
    behind, off_path = [], []
    for k in range(15, len(exp.points)):
        spot = trace_beam(nominal, lagged[k], exp.points[k], exp.normals[k]).spot
        behind.append(np.linalg.norm(spot - exp.points[k]))
        off_path.append(closest_point_error(spot, exp.points))
    lag_m = ServoSettings().lookahead_time * speed  # 2 mm at 0.1 s and 20 mm/s
    assert np.median(behind) == pytest.approx(lag_m, rel=0.1)
    assert max(off_path) < 0.25 * lag_m
    # without a stroke (chessboard points) the arm is where it was planned to be
    board = setup.chessboard("A")
    fake = [SimpleNamespace(q=np.full(6, float(k))) for k in range(len(board.points))]
    assert all(
        np.array_equal(q, s.q)
        for q, s in zip(swept_joints(board, board.points, fake, speed), fake, strict=True)
    )


def test_the_ladder_adds_one_effect_per_rung() -> None:
    rungs = abl.ladder("uncalibrated")
    assert rungs[0][1] == setup.Effects()
    for (_, a), (_, b) in itertools.pairwise(rungs):
        changed = [
            f.name for f in fields(setup.Effects) if getattr(a, f.name) != getattr(b, f.name)
        ]
        assert len(changed) == 1, changed
    last = setup.Effects(True, True, "uncalibrated", True, cloud_targets=True,
                         paper_calibration=True)  # fmt: skip
    assert rungs[-1][1] == last
    assert "paper" in rungs[-1][0] and rungs[-1][1].paper_calibration
    # the cloud's rung comes after the camera's depth errors and before the arm's
    names = [label for label, _ in rungs]
    cloud = next(i for i, (_, e) in enumerate(rungs) if e.cloud_targets)
    assert names[cloud - 1].startswith("+ depth bias")
    assert names[cloud + 1].startswith("+ robot kinematics")
    assert all(e.cloud_targets for _, e in rungs[cloud:])


def _trial(t: int, errors: dict[str, list[float]]) -> dict[str, object]:
    rows = [{"group": g, "status": "ok", "open_mm": e, "closed_mm": e / 2, "true_open_mm": e / 4,
             "true_closed_mm": e / 8} for g, es in errors.items() for e in es]  # fmt: skip
    rows.append({"group": "curve", "status": "lost", "open_mm": 99.0, "closed_mm": 99.0})
    return {"trial": t, "rows": rows, "handeye_residual_mm": 1.0 + t, "beam_residual_mm": 2.0}


def test_budget_steps_are_paired_per_trial_means() -> None:
    groups = {g: [1.0] for g in setup.GROUPS}
    a = [_trial(t, {**groups, "curve": [m, m + 2.0]}) for t, m in enumerate([1.0, 2.0, 3.0])]
    b = [_trial(t, {**groups, "curve": [m, m]}) for t, m in enumerate([3.0, 2.5, 6.0])]
    rows = abl.summarize([("a", a), ("b", b)])
    curve_a = next(r for r in rows if r["rung"] == "a" and r["experiment"] == "curve")
    curve_b = next(r for r in rows if r["rung"] == "b" and r["experiment"] == "curve")
    per_a, per_b = np.array([2.0, 3.0, 4.0]), np.array([3.0, 2.5, 6.0])  # per-trial means
    assert curve_a["open_mm"] == pytest.approx(per_a.mean())
    assert curve_a["open_step_mm"] is None
    assert curve_a["true_closed_mm"] == pytest.approx(per_a.mean() / 8)
    d = per_b - per_a
    half = stats.t.ppf(0.975, 2) * d.std(ddof=1) / np.sqrt(3)
    assert curve_b["open_step_mm"] == pytest.approx(d.mean())
    assert curve_b["open_step_ci_mm"] == pytest.approx(half)
    assert curve_b["closed_step_mm"] == pytest.approx(d.mean() / 2)
    # the paired t-test of the step by hand; the family: curve open and closed (the other
    # experiments do not change, so their steps have no variance and are no tests)
    p = 2 * stats.t.sf(abs(d.mean() / (d.std(ddof=1) / np.sqrt(3))), 2)
    assert curve_b["open_step_p"] == pytest.approx(p)
    assert curve_b["closed_step_p"] == pytest.approx(p)  # halved errors, same t
    assert curve_b["open_step_p_holm"] == pytest.approx(min(1.0, 2 * p))
    face_b = next(r for r in rows if r["rung"] == "b" and r["experiment"] == "face")
    assert np.isnan(face_b["open_step_p"]) and np.isnan(face_b["open_step_p_holm"])
    calib = abl.calibration([("a", a), ("b", b)])
    assert calib[0]["handeye_mm"] == pytest.approx(2.0) and calib[1]["beam_mm"] == 2.0
    lines = abl.report_lines(rows, 3, 0, calib)
    assert any("| b | curve |" in line and f"{d.mean():+.2f}" in line for line in lines)
    assert any(line.startswith("| a | 2.00 ± ") for line in lines)


def test_unknown_robot_error_level_is_a_usage_error(tmp_path: Path) -> None:
    import typer
    from typer.testing import CliRunner

    from planner.studies import experiments

    app = typer.Typer()
    app.command("experiments")(experiments.command)
    app.command("other")(lambda: None)
    res = CliRunner().invoke(
        app, ["experiments", "--ablate", "--robot-error", "perfect", "-o", str(tmp_path)]
    )
    assert res.exit_code == 2
    assert "perfect" in res.output and "uncalibrated" in res.output
    with pytest.raises(InputError, match="factory, uncalibrated"):
        experiments.main(1, 0, tmp_path, 1, None, ablate=True, robot_error="none")


def test_effects_make_the_true_cameras_errors() -> None:
    from planner.model import d435

    nominal = setup.nominal_system()
    assert setup.Effects().depth_errors(nominal, np.random.default_rng(0)) is None
    noise_only = setup.Effects(camera_noise=True).depth_errors(nominal, np.random.default_rng(0))
    assert noise_only == d435.DepthErrors(True, 0.0)
    bias = setup.Effects(depth_bias=True)
    a = bias.depth_errors(nominal, np.random.default_rng(5))
    b = bias.depth_errors(nominal, np.random.default_rng(5))
    assert a == b and a is not None and not a.correlated
    assert 0 < abs(a.disparity_offset_px) <= d435.max_disparity_offset(430.0)


def test_measurement_is_the_median_and_p90_of_the_seen_targets() -> None:
    rows = [{"group": "curve", "target_mm": float(v), "normal_deg": float(10 * v)}
            for v in range(1, 11)]  # fmt: skip
    rows.append({"group": "curve", "target_mm": np.nan, "normal_deg": np.nan})  # hidden
    rows.append({"group": "face", "target_mm": 2.0, "normal_deg": 0.0})
    meas = abl.measurement([("rung", [{"trial": 0, "rows": rows}])])
    curve = next(m for m in meas if m["experiment"] == "curve")
    assert curve["target_mm_median"] == pytest.approx(5.5)  # of 1..10
    assert curve["target_mm_p90"] == pytest.approx(9.1)  # linear between 9 and 10
    assert curve["normal_deg_median"] == pytest.approx(55.0)
    assert np.isnan(next(m for m in meas if m["experiment"] == "finger")["target_mm_median"])
    lines = abl.report_lines([], 1, 0, None, meas)
    # chessboard (none), curve, face: the table's row of the rung, a column per experiment
    row = "| rung | nan (nan) / nan (nan) | 5.50 (9.10) / 55.0 (91.0) | 2.00 (2.00) / 0.0 (0.0) |"
    assert any(line.startswith(row) for line in lines), lines
