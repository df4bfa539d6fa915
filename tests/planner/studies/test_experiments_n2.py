"""``study experiments-n2``: the chained calibration, the relay's sensitivity and the command."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace
from typing import Any

import numpy as np
import pytest
from scipy import stats

from planner.beam.graph import BeamModel
from planner.calibration.beam import BeamData, calibrate_beam, calibrate_chain
from planner.model import d435
from planner.model.system import System
from planner.studies import n2_sensitivity as sens
from planner.studies import n2_setup as setup
from tests.paths import REPO

SILENT = d435.D435Noise(subpixel=0.0, lateral_px=0.0)


def _truth(seed: int) -> Any:
    return setup.draw_truth(
        setup.nominal_system(), setup.RelayUnknowns(), np.random.default_rng(seed)
    )


def _collector(truth: System, rng: np.random.Generator, sigma: float = 0.0) -> Any:
    """``collect(system, robot)`` for :func:`calibrate_chain`: the planned poses of each
    board, the TRUE chain up to ``robot`` traced onto the board's plane (no camera), plus
    isotropic Gaussian noise of ``sigma`` (m)."""
    from planner.calibration.collect import beam_plan

    def collect(plan: System, robot: str) -> BeamData:
        k = truth.robot_names.index(robot) + 1
        model = BeamModel(replace(truth, robots=truth.robots[:k]))
        qs, spots, labels = [], [], []
        for b, (aim, _) in enumerate(setup.calibration_boards(plan, robot)):
            for q in beam_plan(plan, robot, 16, aim, rng)[0]:
                tr = model.trace(q, aim, np.array([0.0, 0.0, 1.0]))
                if tr.valid:
                    qs.append(q)
                    spots.append(tr.spot + rng.normal(0.0, sigma, 3))
                    labels.append(b)
        return BeamData(robot, np.array(qs), np.array(spots), np.array(labels))

    return collect


def _with_true_base(nominal: System, truth: System) -> System:
    """The nominal relay with arm1's true placement (a perfect hand-eye of arm1)."""
    return nominal.with_params(world_T_base={"arm1": truth.robots[1].world_T_base})


def _plane(system: System, i: int, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(unit normal, centre) of mirror ``i`` in the world at robot ``i``'s joints ``q``."""
    r = system.robots[i]
    T = r.world_T_base @ r.kinematics.fk(q) @ r.mirror.flange_T_mirror
    return T[:3, 2], T[:3, 3]


def _beam_errors(cal: System, truth: System) -> dict[str, float]:
    """Independently of the study's code: laser direction angle (rad) and the true origin's
    distance from the calibrated line (m); per mirror at home, the normals' angle (rad) and
    the true centre's distance from the calibrated plane (m)."""
    d, dt = cal.world_T_laser[:3, 2], truth.world_T_laser[:3, 2]
    off = truth.world_T_laser[:3, 3] - cal.world_T_laser[:3, 3]
    out = {"laser_rad": float(np.arccos(np.clip(d @ dt, -1, 1))),
           "laser_m": float(np.linalg.norm(off - d * (d @ off)))}  # fmt: skip
    for i, r in enumerate(truth.robots):
        (nc, cc), (nt, ct) = _plane(cal, i, r.home), _plane(truth, i, r.home)
        out[f"mirror{i + 1}_rad"] = float(np.linalg.norm(np.cross(nc, nt)))
        out[f"mirror{i + 1}_m"] = abs(float(nc @ (ct - cc)))
    return out


def test_an_imperfect_truth_keeps_the_kind_draws_and_perturbs_both_arms() -> None:
    from planner.studies.experiments_n2 import IMPERFECT

    nominal = setup.nominal_system()
    kind = setup.draw_truth(nominal, setup.RelayUnknowns(), np.random.default_rng(9))
    real = setup.draw_truth(
        nominal, setup.RelayUnknowns(), np.random.default_rng(9), IMPERFECT, [9]
    )
    assert kind.depth_errors is None and real.depth_errors is not None
    assert np.array_equal(kind.system.world_T_laser, real.system.world_T_laser)
    for k, r, n in zip(kind.system.robots, real.system.robots, nominal.robots, strict=True):
        assert np.array_equal(k.mirror.flange_T_mirror, r.mirror.flange_T_mirror)
        assert np.array_equal(k.kinematics.fk(n.home), n.kinematics.fk(n.home))
        moved = r.kinematics.fk(n.home)[:3, 3] - n.kinematics.fk(n.home)[:3, 3]
        assert 1e-5 < np.linalg.norm(moved) < 0.01  # factory spread: sub-millimetre to mm


# --- chained calibration --------------------------------------------------------------------
def test_chained_calibration_recovers_the_truth_from_exact_spots() -> None:
    truth = _truth(3)
    start = _with_true_base(setup.nominal_system(), truth.system)
    before = _beam_errors(start, truth.system)
    assert min(before.values()) > 1e-4  # the truth is well off the nominal relay everywhere
    cal, results = calibrate_chain(start, _collector(truth.system, np.random.default_rng(0)))
    assert [r.robot for r in results] == ["arm0", "arm1"]
    assert results[0].world_T_laser is not None and results[1].world_T_laser is None
    assert all(r.converged and np.max(r.residuals) < 1e-9 for r in results)
    after = _beam_errors(cal, truth.system)
    assert max(after.values()) < 1e-6, after
    # the study's own figures agree with the independent ones
    fig = setup.calibration_errors(cal, truth.system)
    for part in ("laser", "mirror1", "mirror2"):
        assert fig[f"{part}_mm"] == pytest.approx(1e3 * after[f"{part}_m"], abs=1e-6)
        assert np.radians(fig[f"{part}_deg"]) == pytest.approx(after[f"{part}_rad"], abs=1e-9)


def _sigma_bound(std: dict[str, float], names: tuple[str, ...], p: float = 1e-3) -> float:
    """The radius a 2D (or 1D) Gaussian error with the fit's standard deviations (the larger
    one for each axis, conservatively) exceeds with probability ``p``."""
    s = max(std[n] for n in names)
    return float(s * np.sqrt(stats.chi2.ppf(1 - p, len(names))))


def test_each_stage_is_within_its_noise() -> None:
    """Spots with 0.2 mm noise: mirror 1 and the laser within their fit's 99.9 % bound;
    mirror 2, with the laser and mirror 1 held at the truth, within its own."""
    truth, sigma = _truth(5), 2e-4  # m: the D435 spot noise at ~0.9 m (planner.model.d435)
    start = _with_true_base(setup.nominal_system(), truth.system)
    rng = np.random.default_rng(1)
    collect = _collector(truth.system, rng, sigma)
    first = calibrate_beam(collect(start, "arm0"), start)
    assert first.sigma == pytest.approx(sigma, rel=0.25)
    held = start.with_params(world_T_laser=truth.system.world_T_laser,
                             flange_T_mirror={"arm0": truth.system.robots[0].mirror.flange_T_mirror})  # fmt: skip
    second = calibrate_beam(collect(held, "arm1"), held)
    cal = held.with_params(flange_T_mirror={"arm1": second.flange_T_mirror})
    cal1 = start.with_params(world_T_laser=first.world_T_laser,
                             flange_T_mirror={"arm0": first.flange_T_mirror})  # fmt: skip
    e1, e2 = _beam_errors(cal1, truth.system), _beam_errors(cal, truth.system)
    s1, s2 = first.std, second.std
    assert e1["laser_rad"] < _sigma_bound(s1, ("laser.rx", "laser.ry"))
    assert e1["laser_m"] < _sigma_bound(s1, ("laser.tx", "laser.ty"))
    assert e1["mirror1_rad"] < _sigma_bound(s1, ("mirror.rx", "mirror.ry"))
    assert e1["mirror1_m"] < _sigma_bound(s1, ("mirror.tz",))
    assert e2["mirror2_rad"] < _sigma_bound(s2, ("mirror.rx", "mirror.ry"))
    assert e2["mirror2_m"] < _sigma_bound(s2, ("mirror.tz",))
    # the bounds are tight enough to mean something: well under the unknowns
    assert (
        _sigma_bound(s2, ("mirror.rx", "mirror.ry")) < 0.1 * setup.RelayUnknowns().shared.mirror_rot
    )


def test_calibration_on_the_silent_cell_recovers_the_truth(monkeypatch: pytest.MonkeyPatch) -> None:
    """The whole cell procedure (two hand-eyes, both mirrors) with a noiseless camera
    recovers the truth drawn at the full unknowns (5-30 mm / 0.5-2 deg)."""
    monkeypatch.setattr(d435, "SPOT", SILENT)
    monkeypatch.setattr(d435, "CORNER", SILENT)
    rng = np.random.default_rng(7)
    truth = setup.draw_truth(setup.nominal_system(), setup.RelayUnknowns(), rng)
    cal = setup.calibrate_relay(setup.nominal_system(), truth, rng)
    assert np.max(cal.beam_residuals) < 1e-9
    e = _beam_errors(cal.system, truth.system)
    assert max(e.values()) < 1e-6, e
    base = cal.system.robots[1].world_T_base[:3, 3] - truth.system.robots[1].world_T_base[:3, 3]
    assert np.linalg.norm(base) < 1e-6


def test_the_camera_sees_the_calibration_spots_past_the_screen() -> None:
    """On the nominal relay as the truth, most planned spots land where the camera sees
    them with the screen in the cell (no board hidden behind it)."""
    from planner.studies.experiments_cell import collect_beam_cell
    from planner.studies.experiments_setup import NOMINAL_BOARD, Truth

    nominal = setup.nominal_system()
    assert nominal.camera is not None
    truth, rng = Truth(nominal, NOMINAL_BOARD), np.random.default_rng(4)
    for robot, least in (("arm0", 40), ("arm1", 20)):  # of 48 planned
        boards = setup.calibration_boards(nominal, robot)
        data = collect_beam_cell(nominal, truth, nominal.camera.world_T_camera, rng, robot,
                                 boards, (setup.screen(),))  # fmt: skip
        assert len(data.q) >= least, (robot, len(data.q))
        assert set(data.boards.tolist()) == {0, 1, 2}  # every board has spots


def test_the_servo_moves_both_arms_to_correct_a_model_millimetres_off(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The product's servo on the relay: planned on the nominal model of a truth 0.1 deg /
    1 mm off per component, the chessboard's spots are ~2 mm off; closed loop brings each
    within the servo's tolerance (noiseless camera: the measured error is the true one)."""
    from planner.ik import BeamIK
    from planner.plan.scenario_planner import ik_options
    from planner.studies import experiments_setup as n1
    from planner.studies.experiments_cell import Calibrated
    from planner.studies.experiments_trial import ClosedLoop, run_experiment
    from schemas.defaults import SERVO_TOLERANCE_M

    monkeypatch.setattr(d435, "SPOT", SILENT)
    monkeypatch.setattr(d435, "CORNER", SILENT)
    nominal = setup.nominal_system()
    small = n1.Unknowns(np.radians(0.1), 0.001, np.radians(0.1), 0.001, 0.0, 0.0, 0.0, 0.0)
    truth = setup.draw_truth(
        nominal, setup.RelayUnknowns(small, 0.0, 0.0), np.random.default_rng(3)
    )
    cal = Calibrated(nominal, np.zeros(1), np.zeros(1), 0)
    ik = BeamIK(nominal, ik_options(setup.scenario_model().model.solver))
    rows = run_experiment(setup.chessboard(), cal, truth, ik, ClosedLoop(cal), 0)
    assert all(r["status"] == "ok" for r in rows)
    assert np.mean([r["open_mm"] for r in rows]) > 1.0
    assert max(r["closed_mm"] for r in rows) <= 1e3 * SERVO_TOLERANCE_M
    assert max(r["servo_iterations"] for r in rows) >= 1


# --- sensitivity ----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def nominal() -> Any:
    return sens.solve_nominal()


def test_first_order_prediction_matches_the_trace_at_small_errors(nominal: Any) -> None:
    rng = np.random.default_rng(2)
    assert nominal.solved.sum() == len(nominal.targets) == 32
    for group, (kind, robot, cols) in sens.GROUPS.items():
        level = 1e-5  # rad or m: far inside the linear range (errors ~1e-5 relative)
        for k in rng.choice(np.flatnonzero(nominal.solved), 4, replace=False):
            delta = rng.uniform(-1, 1, 3) * level
            traced = BeamModel(sens.n1.perturb(nominal.system, kind, delta, robot))
            e = traced.trace(nominal.q[k], nominal.targets[k]).error
            pred = np.linalg.norm(nominal.J[k][:, cols] @ delta)
            assert e > 1e-9  # every group moves the spot
            assert pred == pytest.approx(e, rel=1e-3), (group, k)


def test_a_tilt_of_the_last_mirror_turns_the_beam_twice_as_far(nominal: Any) -> None:
    """Independent of the graph: a tilt delta of mirror 2 about an axis in its plane
    turns the reflected ray by 2 delta, so the spot moves ~2 delta x the distance to the
    target (to first order, times 1 / cos of the angle between the ray and that axis)."""
    k = int(np.flatnonzero(nominal.solved)[0])
    tr = BeamModel(nominal.system).trace(nominal.q[k], nominal.targets[k])
    dist = float(np.linalg.norm(nominal.targets[k] - tr.hits[-1]))
    M = nominal.system.robots[1].mirror.flange_T_mirror
    for axis in range(2):  # the mirror's own x and y, in its plane
        delta = np.zeros(3)
        delta[axis] = 1e-5
        moved = np.linalg.norm(nominal.J[k][:, 12:15] @ delta)
        assert 2e-5 * dist * 0.5 < moved < 2e-5 * dist * 2.0
    assert np.allclose(M[:3, :3], np.eye(3))  # nominal mount: the mirror frame is the flange's


def test_summary_per_unit_is_the_predicted_rms_over_the_level(nominal: Any) -> None:
    rows = sens.trial_rows(nominal, 0, 0) + sens.trial_rows(nominal, 1, 0)
    summary = sens.summarize(nominal, rows)
    assert len(summary) == 18
    for s in summary:
        lvl = float(s["level"].split()[0])
        assert s["per_unit"] == pytest.approx(s["pred_rms_mm"] / lvl)
        J = nominal.J[nominal.solved][:, :, sens.GROUPS[s["group"]][2]]
        si = np.radians(lvl) if s["unit"] == "deg" else lvl / 1e3
        expect = 1e3 * si * np.sqrt(np.mean(np.sum(J**2, axis=(1, 2))) / 3)
        assert s["pred_rms_mm"] == pytest.approx(expect)
    text = sens.verdict(summary, 0.5, 3.0)
    per = {s["group"]: s["per_unit"] for s in summary}
    assert f"mirror 2 {0.5 * per['mirror2_rot']:.2f} mm from its tilt" in text


# --- the command, as a stranger drives it ----------------------------------------------------
def test_a_typo_in_an_option_is_one_line_and_exit_2() -> None:
    cmd = [sys.executable, "-m", "planner.cli", "study", "experiments-n2", "--trails", "2"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120, cwd=REPO)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "--trails" in lines[0], proc.stderr
    assert "Traceback" not in proc.stderr


def test_a_bad_trial_count_is_one_line_and_exit_2() -> None:
    cmd = [sys.executable, "-m", "planner.cli", "study", "experiments-n2", "--trials", "0"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120, cwd=REPO)
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1, proc.stderr


@pytest.mark.slow
def test_study_experiments_n2_one_trial_json(tmp_path: Any) -> None:
    import json

    cmd = [sys.executable, "-m", "planner.cli", "study", "experiments-n2", "--trials", "1",
           "--workers", "1", "-o", str(tmp_path), "--json"]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    fig = json.loads(proc.stdout.strip().splitlines()[-1])
    assert fig["study"] == "experiments-n2" and fig["trials"] == 1 and not fig["imperfect"]
    by = {a["experiment"]: a for a in fig["accuracy"]}
    assert set(by) == {"chessboard", "curve"}
    for a in by.values():
        assert a["measured"] == a["targets"] > 0
        assert 0.0 < a["open_mm"] < 2.0 and 0.0 < a["closed_mm"] < 2.0
    cal = {c["key"]: c["mean"] for c in fig["calibration"]}
    assert cal["mirror1_deg"] < 0.1 and cal["mirror2_deg"] < 0.1  # unknowns: 0.5 deg
    assert len(fig["sensitivity"]) == 18
    for f in ("report.md", "experiments_n2.png", "experiments_n2.csv", "calibration.csv",
              "sensitivity.csv", "sensitivity_summary.csv"):  # fmt: skip
        assert (tmp_path / f).is_file()
    assert "<!-- provenance" in (tmp_path / "report.md").read_text()
