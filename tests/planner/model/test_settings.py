"""Typed trajectory settings: built once from the scenario, defaults from one place."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from planner.errors import InputError
from planner.io.scenario import load_scenario, trajectory_settings
from planner.model.settings import TrajectorySettings
from schemas import defaults
from tests.paths import REPO


def test_defaults_are_the_documented_values() -> None:
    s = TrajectorySettings()
    # the contract's numbers, written out here independently of schemas.defaults
    assert (s.spot_speed, s.dwell, s.rate, s.path_tolerance) == (0.02, 0.0, 500.0, 5e-5)
    assert s.period == pytest.approx(0.002)
    assert s.order is None


def test_scenario_section_becomes_typed_settings(tmp_path: Path) -> None:
    lines = (REPO / "scenarios/paper_n1.yaml").read_text().splitlines()
    kept = [line for line in lines if not line.startswith("trajectory:")]
    assert len(kept) == len(lines) - 1
    path = tmp_path / "s.yaml"
    path.write_text("\n".join([*kept, "trajectory: {spot_speed: 0.01, dwell: 0.25, rate: 250}"]))
    s = trajectory_settings(load_scenario(path))
    assert (s.spot_speed, s.dwell, s.rate) == (0.01, 0.25, 250.0)
    assert s.path_tolerance == defaults.PATH_TOLERANCE_M
    path.write_text("\n".join(kept))  # no section: every default
    assert trajectory_settings(load_scenario(path)) == TrajectorySettings()


@pytest.mark.parametrize(
    ("kwargs", "words"),
    [
        ({"rate": 0.0}, "rate: must be a positive number of Hz"),
        ({"rate": math.nan}, "rate: must be a positive number of Hz"),
        ({"spot_speed": -0.02}, "spot_speed: must be a positive number of m/s"),
        ({"dwell": -1.0}, "dwell: must be a non-negative number of s"),
        ({"path_tolerance": math.inf}, "path_tolerance: must be a positive number of m"),
        ({"order": "fastest"}, "order: must be one of optimal, optimized, given"),
    ],
)
def test_bad_settings_are_input_errors(kwargs: dict[str, object], words: str) -> None:
    with pytest.raises(InputError) as info:
        TrajectorySettings(**kwargs)  # type: ignore[arg-type]
    assert words in str(info.value)


def test_from_mapping_ignores_unknown_and_missing_keys() -> None:
    s = TrajectorySettings.from_mapping({"rate": 100, "dwell": None, "future_key": 3})
    assert s == TrajectorySettings(rate=100.0)
    assert TrajectorySettings.from_mapping(None) == TrajectorySettings()
