"""``bench track`` in-process: the spot stays on the moving target with the laser on."""

from __future__ import annotations

import pytest

from planner.bench.track import CASES, run_case


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
