"""``study moving-target``: tracking with the true arm off the model and servo lag."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from planner.studies import moving_target as mt
from schemas.defaults import SERVOJ_LOOKAHEAD_S
from tests.cli_run import beamrelay


def _run(case: str, cond: str, seed: int, on: float | None, every: float) -> dict:
    return {"case": case, "condition": cond, "seed": seed, "rms_laser_on_mm": on,
            "rms_all_mm": every, "laser_on_fraction": 0.0 if on is None else 0.5,
            "stopped": False}  # fmt: skip


def test_summary_counts_never_lit_trials_apart_and_averages_the_lit_ones() -> None:
    runs = [_run("linear", "servo lag", 0, None, 2.0), _run("linear", "servo lag", 1, 1.0, 3.0),
            _run("linear", "servo lag", 2, 3.0, 4.0), _run("face", "servo lag", 0, 0.5, 0.5)]  # fmt: skip
    rows = mt.summarize(runs)
    assert [(r["case"], r["condition"]) for r in rows] == [("linear", "servo lag"),
                                                           ("face", "servo lag")]  # fmt: skip
    lin = rows[0]
    assert (lin["trials"], lin["never_lit"]) == (3, 1)
    assert lin["rms_laser_on_mm"] == pytest.approx(2.0)  # mean of the two lit trials
    # Student t, 1 degree of freedom: t_0.975 = 12.706; s = sqrt(2)
    assert lin["rms_laser_on_ci_mm"] == pytest.approx(12.706 * np.sqrt(2) / np.sqrt(2), rel=1e-3)
    assert lin["rms_all_mm"] == pytest.approx(3.0)
    assert lin["laser_on_pct"] == pytest.approx(100 * 1.0 / 3)


def test_the_lag_trail_is_speed_times_lookahead() -> None:
    assert mt.lag_trail_mm() == pytest.approx(1e3 * 0.02 * SERVOJ_LOOKAHEAD_S)
    assert mt.lag_trail_mm(0.03) == pytest.approx(0.6)


def test_a_short_lookahead_trails_less_than_the_drivers(monkeypatch: pytest.MonkeyPatch) -> None:
    """The 20 mm/s phantom behind servoJ: all-sample error near speed x lookahead for the
    driver's lookahead, and less with servoJ's shortest one."""
    monkeypatch.setattr(mt, "SECONDS", 3.0)
    long = mt.run_one("linear", "servo lag", 0)
    short = mt.run_one("linear", "servo lag, lookahead 0.03 s", 0)
    assert long["rms_laser_on_mm"] is None  # never lit: the trail exceeds the tolerance
    assert long["rms_all_mm"] == pytest.approx(mt.lag_trail_mm(), rel=0.15)
    assert short["rms_all_mm"] < 0.6 * long["rms_all_mm"]
    assert short["laser_on_fraction"] > 0.0


def test_the_report_has_a_row_per_case_and_condition(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(mt, "SECONDS", 2.0)
    monkeypatch.setattr(mt, "CONDITIONS", {k: mt.CONDITIONS[k] for k in ("model = truth",
                                                                          "servo lag")})  # fmt: skip
    figures = mt.main(1, 3, tmp_path, 1, None)
    assert len(figures["rows"]) == 3 * 2  # three cases, two conditions
    text = (tmp_path / "report.md").read_text()
    assert "| face | servo lag |" in text and "Lag check" in text
    assert (tmp_path / "tracking.png").stat().st_size > 0


def test_a_misspelt_option_is_one_line_and_exit_2() -> None:
    ran = beamrelay("study", "moving-target", "--trails", "2")
    assert ran.returncode == 2
    assert "Traceback" not in ran.stderr
