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


def test_every_report_states_its_command_commit_versions_seed_and_wall_time(
    tmp_path: Path,
) -> None:
    """A study run as a stranger would (the CLI, in-process): its report ends with the
    provenance. The commit is the checkout's own (`git rev-parse`, asked here), the package
    versions are the installed ones (importlib.metadata), the seed and trials as given."""
    import subprocess
    from importlib import metadata

    from planner.studies.common import PROVENANCE_PACKAGES
    from tests.cli_run import beamrelay
    from tests.paths import REPO

    ran = beamrelay("study", "sensitivity", "--trials", "1", "--seed", "3", "-o", tmp_path)
    assert ran.returncode == 0, ran.stderr
    text = (tmp_path / "report.md").read_text()
    prov = text[text.index("## Provenance") :]
    head = subprocess.run(["git", "rev-parse", "--short=12", "HEAD"], cwd=REPO,
                          capture_output=True, text=True, check=True).stdout.strip()  # fmt: skip
    assert f"- commit: {head}" in prov
    assert "`beamrelay study sensitivity --trials 1 --seed 3 -o " in prov
    assert "- seed 3, trials 1, wall time " in prov
    for name in PROVENANCE_PACKAGES:
        assert f"{name} {metadata.version(name)}" in prov


def test_study_all_stamps_each_report_it_runs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def fake(name: str) -> SimpleNamespace:
        def main(t: int, seed: int, out: Path, w: Any, s: Any) -> dict:
            out.mkdir(parents=True, exist_ok=True)
            (out / "report.md").write_text(f"# {name}\n")
            return {"study": name}

        return SimpleNamespace(TRIALS=2, main=main)

    monkeypatch.setattr(study_all, "STUDIES", {k: fake(k) for k in study_all.ORDER})
    study_all.main(1, 5, tmp_path, 1, None)
    for name in study_all.ORDER:
        report = (tmp_path / name / "report.md").read_text()
        assert report.startswith(f"# {name}\n") and "## Provenance" in report
        assert f"({name}: --trials 2)" in report and "- seed 5, trials 2" in report
