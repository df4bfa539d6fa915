"""Study helpers: per-trial RNG and executor-independent parallel map."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from planner.studies.common import markdown_table, parallel_map, trial_rng, write_csv


def draw(seed: int, trial: int) -> float:
    return float(trial_rng(seed, trial).uniform())


def test_trial_rng_depends_only_on_seed_and_trial() -> None:
    expect = np.random.default_rng(np.random.SeedSequence([7, 3])).uniform()
    assert draw(7, 3) == expect
    assert draw(7, 3) != draw(7, 4)


def test_parallel_map_same_results_serial_and_processes() -> None:
    jobs = [(5, t) for t in range(6)]
    serial = parallel_map(draw, jobs, workers=1)
    pooled = parallel_map(draw, jobs, workers=2)
    assert serial == pooled == [draw(5, t) for t in range(6)]


def test_csv_and_markdown(tmp_path: Path) -> None:
    rows = [{"a": 1, "b": 0.5}, {"a": 2, "b": 0.25}]
    write_csv(tmp_path / "x.csv", rows)
    assert (tmp_path / "x.csv").read_text().splitlines() == ["a,b", "1,0.5", "2,0.25"]
    assert markdown_table(rows).splitlines()[2] == "| 1 | 0.5 |"
