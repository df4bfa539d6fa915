"""``study experiments``: metrics against hand values, geometry, the pipeline with known answers."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from planner.model import d435
from planner.studies import experiments_report as rep
from planner.studies import experiments_setup as setup
from planner.studies.experiments_cell import Calibrated, calibrate_cell
from planner.studies.experiments_metrics import (
    closest_point_error,
    holm,
    mean_ci,
    paired_t,
    point_error,
    two_sample_t,
)
from planner.studies.experiments_trial import run_experiment

SILENT = d435.D435Noise(subpixel=0.0, lateral_px=0.0)


# --- metrics --------------------------------------------------------------------------------
def test_point_error_is_the_distance() -> None:
    assert point_error([1.0, 2.0, 2.0], [0.0, 0.0, 0.0]) == pytest.approx(3.0)


def test_closest_point_error_against_hand_values() -> None:
    line = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [2.0, 2.0, 0.0]])
    assert closest_point_error([1.0, 0.5, 0.0], line) == pytest.approx(0.5)  # first segment
    assert closest_point_error([3.0, 1.0, 0.0], line) == pytest.approx(1.0)  # second segment
    assert closest_point_error([-3.0, 4.0, 0.0], line) == pytest.approx(5.0)  # the end vertex
    with_gap = np.vstack([line[:1], [np.nan] * 3, line[1:]])
    assert closest_point_error([1.0, 0.5, 0.0], with_gap) == pytest.approx(0.5)
    assert closest_point_error([0.0, 0.0, 1.0], line[:1]) == pytest.approx(1.0)
    assert np.isnan(closest_point_error([0.0, 0.0, 0.0], np.full((2, 3), np.nan)))


def test_mean_ci_is_the_student_interval() -> None:
    ci = mean_ci([1.0, 2.0, 3.0, 4.0, np.nan])
    s = np.sqrt(5.0 / 3.0)  # sample std of 1..4
    assert (ci.mean, ci.n) == (2.5, 4)
    assert ci.std == pytest.approx(s)
    assert ci.half_width == pytest.approx(3.182446305284263 * s / 2.0)  # t_{0.975, 3}
    assert np.isnan(mean_ci([1.0]).half_width) and mean_ci([]).n == 0


def test_two_sample_t_against_scipy_and_the_formula() -> None:
    a, b = np.array([1.0, 2.0, 3.0, 4.0]), np.array([3.0, 4.0, 5.0, 6.0, 7.0])
    t = two_sample_t(a, b)
    ref = stats.ttest_ind(a, b)
    assert (t.t, t.p, t.dof) == (pytest.approx(ref.statistic), pytest.approx(ref.pvalue), 7)
    sp2 = (3 * a.var(ddof=1) + 4 * b.var(ddof=1)) / 7
    assert t.t == pytest.approx((a.mean() - b.mean()) / np.sqrt(sp2 * (1 / 4 + 1 / 5)))
    assert np.isnan(two_sample_t([1.0], b).p)


def test_holm_on_the_textbook_example() -> None:
    """Four hypotheses, p = 0.01, 0.04, 0.03, 0.005 at alpha 0.05 (the Holm-Bonferroni
    article's example): H4 and H1 rejected, then 0.03 > 0.05 / 2 stops the procedure."""
    adjusted = holm([0.01, 0.04, 0.03, 0.005])
    assert adjusted == pytest.approx([0.03, 0.06, 0.06, 0.02])  # 4x.005 3x.01 2x.03 (1x.04 < .06)
    assert list(adjusted <= 0.05) == [True, False, False, True]
    assert holm([0.5, np.nan, 0.4]) == pytest.approx([0.8, np.nan, 0.8], nan_ok=True)  # m = 2
    assert holm([0.9, 0.8]) == pytest.approx([1.0, 1.0])  # capped


def _step_down(p: np.ndarray, alpha: float) -> np.ndarray:
    """Holm's procedure as he stated it: walk the ordered p values, reject while
    p_(i) <= alpha / (m - i + 1), stop at the first that is not."""
    reject = np.zeros(len(p), dtype=bool)
    for i, k in enumerate(np.argsort(p)):
        if p[k] > alpha / (len(p) - i):
            break
        reject[k] = True
    return reject


def test_holm_adjusted_p_is_the_smallest_level_that_rejects() -> None:
    rng = np.random.default_rng(3)
    for _ in range(50):
        p = rng.uniform(0.0, 0.1, size=rng.integers(1, 9)) ** rng.uniform(0.5, 2.0)
        adjusted = holm(p)
        below_one = adjusted[adjusted < 1.0]  # just above and below each adjusted p
        for alpha in [*(below_one * (1 + 1e-9)), *(below_one * (1 - 1e-9)), 0.01, 0.05]:
            assert np.array_equal(adjusted <= alpha, _step_down(p, alpha))


def test_paired_t_is_the_t_of_the_differences() -> None:
    a = {0: 1.0, 1: 2.5, 2: 2.0, 3: 4.0, 4: np.nan}
    b = {0: 0.5, 1: 2.0, 2: 2.2, 3: 3.0, 9: 1.0}  # pairs: trials 0-3
    d = np.array([0.5, 0.5, -0.2, 1.0])
    t = paired_t(a, b)
    t_hand = d.mean() / (d.std(ddof=1) / 2.0)
    assert (t.n, t.dof) == (4, 3)
    assert t.t == pytest.approx(t_hand)
    assert t.p == pytest.approx(2 * stats.t.sf(abs(t_hand), 3))
    assert t.diff.mean == pytest.approx(d.mean())
    assert np.isnan(paired_t({0: 1.0}, {0: 2.0}).p)
    assert np.isnan(paired_t({0: 1.0, 1: 2.0}, {0: 0.0, 1: 1.0}).p)  # no variance


def _rows(trial: int, key: str, open_mm: list[float], closed_mm: list[float]) -> list[dict]:
    group, _, placement = key.partition(" ")
    return [{"trial": trial, "group": group, "experiment": key if placement else group,
             "status": "ok", "open_mm": o, "closed_mm": c, "true_open_mm": o,
             "true_closed_mm": c, "servo_iterations": 1, "ik_time_s": 0.01}
            for o, c in zip(open_mm, closed_mm, strict=True)]  # fmt: skip


def test_comparisons_are_paired_on_per_trial_means_and_holm_adjusted() -> None:
    """Trials of very different sizes: the test weighs each trial once, whatever its number
    of targets, pairs on the trial, and the family's p values are Holm's of the raw ones."""
    rng = np.random.default_rng(7)
    rows: list[dict] = []
    means: dict[str, list[float]] = {k: [] for k in ("A", "B", "finger open", "finger closed")}
    for t in range(5):
        calib = rng.normal(0.0, 0.3)  # the trial's calibration, shared by its targets
        for p, shift in zip(setup.CHESSBOARD, (0.1, 0.0, 0.05), strict=True):
            e = list(1.0 + calib + shift + rng.normal(0.0, 0.05, size=3 + 40 * t))
            rows += _rows(t, f"chessboard {p}", e, [x / 2 for x in e])
            if p in "AB":
                means[p].append(float(np.mean(e)))
        fo, fc = list(2.0 + calib + rng.normal(0, 1, 4)), list(0.3 + rng.normal(0, 0.1, 4))
        lost = {**_rows(t, "finger", [99.0], [99.0])[0], "status": "lost"}
        rows += [*_rows(t, "finger", fo, fc), lost]
        means["finger open"].append(float(np.mean(fo)))
        means["finger closed"].append(float(np.mean(fc)))
    tests = {c["comparison"]: c for c in rep.comparisons(rows)}
    d = np.subtract(means["A"], means["B"])
    t_hand = d.mean() / (d.std(ddof=1) / np.sqrt(5))
    ab = tests["chessboard A - B, open loop"]
    assert (ab["t"], ab["dof"], ab["diff_mm"]) == (
        pytest.approx(t_hand),
        4,
        pytest.approx(d.mean()),
    )
    assert ab["p"] == pytest.approx(2 * stats.t.sf(abs(t_hand), 4))
    board = {p: [r["open_mm"] for r in rows if r["experiment"] == f"chessboard {p}"] for p in "AB"}
    pooled = stats.ttest_ind(board["A"], board["B"])  # every target as if independent
    assert ab["pooled_p"] == pytest.approx(pooled.pvalue)
    f = np.subtract(means["finger open"], means["finger closed"])  # the lost rows left out
    assert tests["finger: open - closed loop"]["diff_mm"] == pytest.approx(f.mean())
    assert len(tests) == 6 + 4
    p = np.array([c["p"] for c in tests.values()])
    assert np.allclose([c["p_holm"] for c in tests.values()], holm(p), equal_nan=True)
    # the experiments' means are the means over the per-trial means, with their CI
    s = rep.summarize([{"trial": t, "rows": [r for r in rows if r["trial"] == t],
                        "handeye_residual_mm": 1.0, "beam_residual_mm": 2.0} for t in range(5)])  # fmt: skip
    a = next(e for e in s["experiments"] if e["experiment"] == "chessboard A")["open"]
    ci = stats.t.ppf(0.975, 4) * np.std(means["A"], ddof=1) / np.sqrt(5)
    assert (a["mean_mm"], a["ci95_mm"]) == (pytest.approx(np.mean(means["A"])), pytest.approx(ci))


# --- geometry -------------------------------------------------------------------------------
def test_shipped_face_phantom_is_the_procedural_mesh() -> None:
    import open3d as o3d

    mesh = o3d.io.read_triangle_mesh(str(setup.scenarios_dir() / setup.FACE_PLY))  # type: ignore[arg-type]
    v, t = setup.face_mesh()
    assert np.allclose(np.asarray(mesh.vertices), v, atol=1e-9)
    assert np.array_equal(np.asarray(mesh.triangles), t)


def test_targets_lie_on_their_objects() -> None:
    rng = np.random.default_rng(4)
    fin = setup.finger(rng)
    axis_T = fin.items[0].world_T_object  # cylinder z = the finger's axis
    rel = (fin.points - axis_T[:3, 3]) @ axis_T[:3, :3]
    assert np.allclose(np.hypot(rel[:, 0], rel[:, 1]), setup.FINGER_R, atol=1e-12)
    assert np.allclose(np.linalg.norm(fin.normals, axis=1), 1.0)
    board = setup.chessboard("B")
    T = setup.CHESSBOARD["B"]
    assert np.allclose((board.points - T[:3, 3]) @ T[:3, 2], 0.0, atol=1e-12)
    assert board.normals[0] @ setup.BEAM_DIR < -0.9  # tilted toward the mirror
    face = setup.face()
    local = face.points - setup.FACE_BASE[:3, 3]
    assert np.allclose(local[:, 2], setup.face_height(local[:, 0], local[:, 1]))


def test_no_unknowns_keep_the_nominal_geometry() -> None:
    nominal = setup.nominal_system()
    truth = setup.draw_truth(nominal, setup.NONE, np.random.default_rng(0))
    assert np.array_equal(truth.system.world_T_laser, nominal.world_T_laser)
    assert truth.system.camera is not None and nominal.camera is not None
    assert np.array_equal(truth.system.camera.world_T_camera, nominal.camera.world_T_camera)
    assert np.array_equal(truth.flange_T_board, setup.NOMINAL_BOARD)


def test_unknown_levels_bound_the_truth() -> None:
    nominal, u = setup.nominal_system(), setup.Unknowns()
    for seed in range(20):
        truth = setup.draw_truth(nominal, u, np.random.default_rng(seed))
        d = truth.system.world_T_laser[:3, 3] - nominal.world_T_laser[:3, 3]
        assert np.all(np.abs(nominal.world_T_laser[:3, :3].T @ d) <= u.laser_pos + 1e-15)


# --- the pipeline with known answers ---------------------------------------------------------
@pytest.fixture
def silent_camera(monkeypatch: pytest.MonkeyPatch) -> None:
    """The D435 without noise (spots and corners)."""
    monkeypatch.setattr(d435, "SPOT", SILENT)
    monkeypatch.setattr(d435, "CORNER", SILENT)


def _ik(system: object) -> object:
    from planner.ik import BeamIK
    from planner.plan.scenario_planner import ik_options

    return BeamIK(system, ik_options(setup.solver_settings()))  # type: ignore[arg-type]


def test_nominal_truth_and_model_without_noise_give_zero_error(silent_camera: None) -> None:
    nominal = setup.nominal_system()
    truth = setup.Truth(nominal, setup.NOMINAL_BOARD)
    cal = Calibrated(nominal, np.zeros(1), np.zeros(1), 0)
    for exp in (setup.chessboard("A"), setup.curve()):
        rows = run_experiment(exp, cal, truth, _ik(nominal), None, 0)
        ok = [r for r in rows if r["status"] == "ok"]
        assert len(ok) == len(rows)
        # open3d raycasts in float32: ~0.1 um at 1 m
        assert max(r["open_mm"] for r in ok) < 1e-3
        assert max(r["true_open_mm"] for r in ok) < 1e-3


def test_noise_free_calibration_of_a_perturbed_cell_recovers_zero_error(
    silent_camera: None,
) -> None:
    """The truth is off by the full unknowns; exact calibration data make the plan exact."""
    nominal = setup.nominal_system()
    rng = np.random.default_rng(11)
    truth = setup.draw_truth(nominal, setup.Unknowns(), rng)
    cal = calibrate_cell(nominal, truth, rng)
    assert np.max(cal.handeye_residuals) < 1e-8 and np.max(cal.beam_residuals) < 1e-8
    rows = run_experiment(setup.chessboard("B"), cal, truth, _ik(cal.system), None, 1)
    ok = [r for r in rows if r["status"] == "ok"]
    assert len(ok) == len(rows)
    assert max(r["open_mm"] for r in ok) < 1e-3
    # without calibration the same truth puts the spots millimetres off
    nominal_cal = Calibrated(nominal, np.zeros(1), np.zeros(1), 0)
    raw = run_experiment(setup.chessboard("B"), nominal_cal, truth, _ik(nominal), None, 1)
    assert np.nanmedian([r["true_open_mm"] for r in raw]) > 1.0


@pytest.mark.slow
def test_study_experiments_one_trial_json(tmp_path: Path) -> None:
    cmd = [sys.executable, "-m", "planner.cli", "study", "experiments", "--trials", "1",
           "--workers", "1", "-o", str(tmp_path), "--json"]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    fig = json.loads(proc.stdout.strip().splitlines()[-1])
    assert fig["study"] == "experiments" and fig["trials"] == 1
    by = {e["experiment"]: e for e in fig["experiments"]}
    assert set(setup.GROUPS) <= set(by)
    for name in setup.GROUPS:
        assert by[name]["open"]["n"] > 0 and by[name]["closed"]["n"] > 0
        assert 0.0 < by[name]["open"]["mean_mm"] < 20.0
    assert len(fig["comparisons"]) == 10
    assert all(np.isnan(c["p"]) and np.isnan(c["p_holm"]) for c in fig["comparisons"])  # 1 trial
    assert fig["ik_time_s"]["n"] == fig["status"]["ok"] + fig["status"]["lost"]
    for f in ("report.md", "experiments.png", "experiments.csv", "calibration.csv"):
        assert (tmp_path / f).is_file()
