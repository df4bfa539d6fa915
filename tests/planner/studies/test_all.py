"""``study all``: each study at its TRIALS, in order, and the index linking the reports."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from planner.studies import all as study_all


def test_all_runs_each_study_at_its_scale_and_links_them(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    calls: list[tuple[str, int, Path]] = []

    def fake(name: str, trials: int) -> SimpleNamespace:
        def main(t: int, seed: int, out: Path, w: Any, s: Any) -> dict:
            calls.append((name, t, out))
            return {"study": name}

        return SimpleNamespace(TRIALS=trials, main=main)

    trials = {"ik-grid": 7, "calibration": 100, "sensitivity": 5, "mirror-sweep": 3}
    trials |= {"coverage": 2, "experiments": 10, "online": 4}
    monkeypatch.setattr(study_all, "STUDIES", {k: fake(k, n) for k, n in trials.items()})
    figures = study_all.main(1, 0, tmp_path, 1, None)
    assert calls == [(name, trials[name], tmp_path / name) for name in study_all.ORDER]
    assert tuple(trials) == study_all.ORDER  # every study, in this order
    index = (tmp_path / "index.md").read_text()
    assert all(f"[{name}/report.md]({name}/report.md)" in index for name in trials)
    assert figures["seconds"]["experiments"] >= 0.0


def test_the_hand_chosen_calibration_error_study_is_gone() -> None:
    assert "tracking" not in study_all.STUDIES
    assert "experiments" in study_all.ORDER
