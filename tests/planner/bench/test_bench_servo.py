"""``beamrelay bench servo``: its JSON figures on a few targets (in-process, CliRunner)."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from planner.cli.bench import app


def test_bench_servo_figures_meet_the_goal_on_a_few_targets() -> None:
    out = CliRunner().invoke(app, ["servo", "--targets", "3", "--seed", "4", "--json"])
    assert out.exit_code == 0, out.output
    doc = json.loads(out.output.strip().splitlines()[-1])
    t, p = doc["targets"], doc["path"]
    assert t["targets"] == t["converged"] == 3
    assert 3e-3 < t["before_median"] <= t["before_max"] < 8e-3  # the truth offsets, open loop
    assert t["after_max"] <= 0.3e-3 and t["true_after_max"] <= 0.3e-3  # confirmed: truth within too
    assert 1 <= t["iterations_median"] <= t["iterations_max"] and t["frames_max"] <= 30
    assert t["goal_met"] is (t["after_max"] <= 0.5e-3 and t["frames_max"] <= 30)
    assert t["execution_median"] > 0.0 and "goal met" in out.output
    assert p["deviation_before_max"] > 3e-3 and p["deviation_after_max"] <= 0.5e-3
    assert p["refused_samples"] == 0 and p["frames"] == 21
    assert doc["truth"] == {"laser_deg": 0.4, "mount_m": 0.003}
