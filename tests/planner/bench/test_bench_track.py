"""``bench track`` in-process: the spot stays on the moving target with the laser on."""

from __future__ import annotations

import pytest

from planner.simcell.tracking import CASES, run_case


@pytest.mark.serial
@pytest.mark.slow
def test_breathing_spot_error_with_the_laser_on_is_under_a_millimetre() -> None:
    scenario, motion = CASES["breathing"]
    f = run_case(motion, seconds=3.0, seed=1, scenario=scenario)
    assert f["stopped"] is None
    assert f["laser_on_fraction"] > 0.9
    assert f["rms_laser_on_m"] < 1e-3 and f["p95_laser_on_m"] < 1e-3
    assert f["frames"] == 90  # 30 Hz for 3 s (received up to 20 ms late)


@pytest.mark.serial
@pytest.mark.slow
def test_a_turning_face_with_attached_eyes_is_followed_and_every_setpoint_checked() -> None:
    scenario, motion = CASES["face"]
    f = run_case(motion, seconds=3.0, seed=1, scenario=scenario)
    assert f["stopped"] is None
    assert f["laser_on_fraction"] > 0.5
    assert f["rms_laser_on_m"] < 1e-3
    assert f["checked"] >= 3.0 * 500 - 10  # every setpoint (the first frame's wait aside)
    assert 0 < f["check_p50_s"] <= f["check_p99_s"] and f["checks_per_cpu_s"] > 0


def test_servo_lag_trails_a_moving_target_by_the_lookahead_and_keeps_the_laser_off() -> None:
    """servoJ's lookahead: an arm following a phantom that moves at 20 mm/s trails it by
    speed x lookahead (2 mm at the UR driver's 0.1 s); the follower sees the lagging joints
    and never switches the laser on that far from the target."""
    from schemas.defaults import SERVOJ_LOOKAHEAD_S

    scenario, motion = CASES["linear"]
    f = run_case(motion, seconds=3.0, seed=1, scenario=scenario, servo_lag=True)
    assert f["stopped"] is None and f["laser_on_fraction"] == 0.0
    assert f["rms_all_m"] == pytest.approx(0.02 * SERVOJ_LOOKAHEAD_S, rel=0.15)
    plain = run_case(motion, seconds=3.0, seed=1, scenario=scenario)
    assert plain["laser_on_fraction"] > 0.9 and plain["rms_all_m"] < 0.3 * f["rms_all_m"]


def test_a_true_arm_off_the_model_puts_the_spot_off_by_its_static_offset() -> None:
    """The follower keeps the nominal UR5e while the camera sees a true arm with a factory
    calibration's DH error: the tracked spot is off the target by what that arm's error
    does to the beam at the tracking joints, traced on its own at the start pose."""
    from planner.beam.graph import BeamModel
    from planner.data import shipped_scenario
    from planner.ik import BeamIK
    from planner.io.scenario import load_scenario, system_from_scenario, targets_from_scenario
    from planner.plan.scenario_planner import ik_options
    from planner.safety.model import Safety
    from planner.simcell.tracking import true_arm

    scenario, motion = CASES["breathing"]
    f = run_case(motion, seconds=3.0, seed=1, scenario=scenario, robot_error="factory")
    scn = load_scenario(shipped_scenario(scenario))
    system = system_from_scenario(scn)
    p = targets_from_scenario(scn, system).points[0]
    q0 = BeamIK(system, ik_options(scn.model.solver), Safety.from_scenario(scn, system)).solve(p).q
    truth = true_arm(system_from_scenario(scn, truth=True), "factory", seed=1)
    offset = BeamModel(truth).trace(q0, p).error
    assert offset > 1e-3  # a factory-calibrated arm's error is millimetres at the spot
    assert f["laser_on_fraction"] > 0.9
    assert f["rms_laser_on_m"] == pytest.approx(offset, rel=0.2)


def test_the_command_says_never_lit_and_refuses_an_unknown_error_level() -> None:
    from tests import cli_run

    done = cli_run.beamrelay("bench", "track", "--seconds", "2", "--servo-lag")
    assert done.returncode == 0, done.stderr
    assert "linear     never lit" in done.stdout  # 20 mm/s behind a 0.1 s lookahead
    cli_run.assert_usage_error(cli_run.beamrelay("bench", "track", "--robot-error", "factroy"),
                               "--robot-error", "factroy")  # fmt: skip
