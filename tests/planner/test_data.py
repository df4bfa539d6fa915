"""Shipped files are found through the package, not through the source tree's layout."""

from __future__ import annotations

import pytest

from planner.data import scenarios_dir, shipped_scenario
from tests.paths import SCENARIOS


def test_shipped_scenarios_are_the_repository_ones() -> None:
    assert scenarios_dir().resolve() == SCENARIOS.resolve()
    assert (
        shipped_scenario("paper_n1.yaml").read_text() == (SCENARIOS / "paper_n1.yaml").read_text()
    )


def test_unknown_scenario_names_the_shipped_ones() -> None:
    with pytest.raises(FileNotFoundError, match=r"paper_n1\.yaml"):
        shipped_scenario("paper_n2.yaml")
