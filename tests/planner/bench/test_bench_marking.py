"""``beamrelay bench marking``: the figures of a path scenario end to end in a child process;
a scenario that is not a path, or missing, is one line and exit 2."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests import cli_run
from tests.paths import SCENARIOS


def beamrelay(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "planner.cli", *map(str, args)],
                          capture_output=True, text=True, timeout=600)  # fmt: skip


def test_s_curve_figures() -> None:
    done = beamrelay("bench", "marking", "--scenario", SCENARIOS / "s_curve.yaml", "--json")
    assert done.returncode == 0, done.stderr
    (row,) = json.loads(done.stdout.strip().splitlines()[-1])["rows"]
    assert row["scenario"] == "s_curve.yaml" and row["violations"] == 0
    assert row["strokes"] == 5 and row["sharp_corners"] == 4
    assert row["laser_on_deviation_max_m"] <= 5e-5 and row["polyline_deviation_max_m"] <= 5e-5
    assert 98 <= row["marked_speed_min_pct"] <= row["marked_speed_max_pct"] <= 102
    ratio = row["marked_speed_max_pct"] / row["marked_speed_min_pct"]  # both scaled by 100
    assert row["fluence_max_over_min"] == pytest.approx(ratio, rel=1e-12)
    # sky-writing costs a run-in, a run-out and a move per stroke: more time than marking
    # every stroke from rest to rest, and the path itself lasts length / speed
    assert row["duration_s"] > row["duration_without_skywriting_s"]
    assert abs(row["path_time_s"] - 0.12145 / 0.02) < 0.03


def test_bad_scenarios_are_one_line(tmp_path: Path) -> None:
    for arg, needle in ((SCENARIOS / "paper_n1.yaml", "path scenario"),
                        (tmp_path / "nope.yaml", "nope.yaml")):  # fmt: skip
        cli_run.assert_usage_error(cli_run.beamrelay("bench", "marking", "--scenario", arg), needle)
