"""``study all``: each study at its TRIALS, in order, and the index linking the reports."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from planner.studies import all as study_all
from planner.studies import provenance
from planner.studies.provenance import PACKAGES, Provenance, read_stamp


def test_all_runs_each_study_at_its_scale_and_links_them(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    calls: list[tuple[str, int, Path]] = []
    options: dict[str, dict[str, Any]] = {}

    def fake(name: str, trials: int) -> SimpleNamespace:
        def main(t: int, seed: int, out: Path, w: Any, s: Any, **kw: Any) -> dict:
            calls.append((name, t, out))
            options[name] = kw
            return {"study": name}

        return SimpleNamespace(TRIALS=trials, main=main)

    trials = {"ik-grid": 7, "calibration": 100, "sensitivity": 5, "mirror-sweep": 3}
    trials |= {
        "coverage": 2,
        "experiments": 10,
        "experiments-n2": 6,
        "online": 4,
        "moving-target": 5,
    }
    monkeypatch.setattr(study_all, "STUDIES", {k: fake(k, n) for k, n in trials.items()})
    figures = study_all.main(1, 0, tmp_path, 1, None)
    assert calls == [(name, trials[name], tmp_path / name) for name in study_all.ORDER]
    assert tuple(trials) == study_all.ORDER  # every study, in this order
    index = (tmp_path / "index.md").read_text()
    assert all(f"[{name}/report.md]({name}/report.md)" in index for name in trials)
    assert figures["seconds"]["experiments"] >= 0.0
    # the committed experiments carry their error budget, and their stamp says so
    assert options["experiments"] == {"ablate": True} and options["online"] == {}


def test_the_hand_chosen_calibration_error_study_is_gone() -> None:
    assert "tracking" not in study_all.STUDIES
    assert "experiments" in study_all.ORDER


def _describe() -> str:
    """The checkout's commit as the reports should state it, asked of git here: describe,
    and -dirty when a tracked file outside reports/ differs from HEAD (git diff)."""
    import subprocess

    from tests.paths import REPO

    head = subprocess.run(["git", "describe", "--always", "--abbrev=12"], cwd=REPO,
                          capture_output=True, text=True, check=True).stdout.strip()  # fmt: skip
    diff = subprocess.run(["git", "diff", "--quiet", "HEAD", "--", ".", ":!reports"], cwd=REPO)
    return head + ("-dirty" if diff.returncode else "")


def test_every_report_states_its_command_commit_versions_seed_and_wall_time(
    tmp_path: Path,
) -> None:
    """A study run as a stranger would (the CLI, in-process): its report ends with the
    provenance, for the reader and as the machine line. The commit is the checkout's own
    (asked of git here), the package versions are the installed ones (importlib.metadata),
    the seed and trials as given."""
    from importlib import metadata

    from tests.cli_run import beamrelay

    ran = beamrelay("study", "sensitivity", "--trials", "1", "--seed", "3", "-o", tmp_path)
    assert ran.returncode == 0, ran.stderr
    text = (tmp_path / "report.md").read_text()
    prov = text[text.index("## Provenance") :]
    assert f"- commit: {_describe()}" in prov
    assert "`beamrelay study sensitivity --trials 1 --seed 3 -o " in prov
    assert "- seed 3 (every random draw derives from it), trials 1, wall time " in prov
    for name in PACKAGES:
        assert f"{name} {metadata.version(name)}" in prov
    stamp = read_stamp(tmp_path / "report.md")
    assert stamp is not None
    assert (stamp.commit, stamp.seed, stamp.trials) == (_describe(), 3, 1)
    assert dict(stamp.packages) == {n: metadata.version(n) for n in PACKAGES}
    assert 0.0 < stamp.seconds < 600.0


def _fake_studies() -> dict[str, SimpleNamespace]:
    def fake(name: str) -> SimpleNamespace:
        def main(t: int, seed: int, out: Path, w: Any, s: Any, **kw: Any) -> dict:
            out.mkdir(parents=True, exist_ok=True)
            (out / "report.md").write_text(f"# {name}\n")
            return {"study": name}

        return SimpleNamespace(TRIALS=2 + len(name), main=main)

    return {k: fake(k) for k in study_all.ORDER}


def test_study_all_stamps_each_report_and_indexes_the_stamps(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(study_all, "STUDIES", _fake_studies())
    (tmp_path / "online").mkdir()
    (tmp_path / "online" / "stale.csv").write_text("from an older version\n")
    (tmp_path / "online" / "notes.txt").write_text("not an output\n")
    study_all.main(1, 5, tmp_path, 1, None)
    assert sorted(f.name for f in (tmp_path / "online").iterdir()) == ["notes.txt", "report.md"]
    index = (tmp_path / "index.md").read_text()
    commit = _describe()
    for name in study_all.ORDER:
        report = (tmp_path / name / "report.md").read_text()
        trials = 2 + len(name)
        assert report.startswith(f"# {name}\n") and "## Provenance" in report
        flags = study_all.OPTIONS.get(name, ({}, ""))[1]  # the experiments: " --ablate"
        assert (f"`beamrelay study {name} --trials {trials} --seed 5 -o {tmp_path / name}{flags}`"
                in report)  # fmt: skip
        assert f"- seed 5 (every random draw derives from it), trials {trials}" in report
        row = next(ln for ln in index.splitlines() if ln.startswith(f"| {name} |"))
        assert row.split(" | ")[2:5] == [commit, "5", str(trials)]


def _prov(commit: str, seed: int, trials: int, seconds: float, numpy: str = "2.0") -> Provenance:
    return Provenance(f"beamrelay study x --trials {trials}", commit, seed, trials, seconds, 2,
                      "3.11.7", (("numpy", numpy), ("scipy", "1.17.1")))  # fmt: skip


def _write(folder: Path, prov: Provenance | None, body: str = "# a report\n") -> None:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "report.md").write_text(body + ("\n".join(prov.lines()) if prov else ""))


def _rows(index: str) -> dict[str, list[str]]:
    return {ln.split(" | ")[0][2:]: ln.strip("| ").split(" | ")
            for ln in index.splitlines() if ln.startswith("| ") and "/report.md" in ln}  # fmt: skip


def test_the_index_is_built_from_the_reports_stamps_alone(tmp_path: Path) -> None:
    """Reports stamped by hand with different facts: the index lists each report's own
    stamp (commit, seed, trials, wall time, cores, command), whatever else the report says,
    and calls a mix of commits, a dirty tree, other packages or a missing stamp out."""
    stamps = {"a": _prov("abc123", 0, 10, 96.4), "b": _prov("abc123", 7, 3, 1.2)}
    for name, p in stamps.items():
        _write(tmp_path / name, p, body="# a\n\n- commit: fake, seed 99, trials 99\n")
    index = "\n".join(provenance.index_lines(tmp_path, ["a", "b"]))
    rows = _rows(index)
    for name, p in stamps.items():
        assert rows[name] == [name, f"[{name}/report.md]({name}/report.md)", p.commit,
                              str(p.seed), str(p.trials), f"{p.seconds:.0f}", str(p.cores),
                              f"`{p.command}`"]  # fmt: skip
    assert "Every report comes from commit abc123, with the same packages: numpy 2.0" in index
    assert "do not come from one clean run" not in index
    # a report from another commit, a dirty tree, other packages, no stamp at all
    for other in (_prov("def456", 0, 1, 1.0), _prov("abc123-dirty", 0, 1, 1.0),
                  _prov("abc123", 0, 1, 1.0, numpy="1.26"), None):  # fmt: skip
        _write(tmp_path / "c", other)
        index = "\n".join(provenance.index_lines(tmp_path, ["a", "b", "c"]))
        assert "**The reports do not come from one clean run:**" in index
        assert "Every report comes from" not in index
        if other is None:
            assert "without a stamp: c" in index and _rows(index)["c"][2] == "no stamp"
        else:
            assert _rows(index)["c"][2] == other.commit


def test_a_stamp_reads_back_what_was_written(tmp_path: Path) -> None:
    p = _prov("v1.0-3-gabc-dirty", 4, 2, 0.5)
    odd = Provenance("beamrelay study x -o 'a-->b'", *list(p.__dict__.values())[1:])
    _write(tmp_path, odd)
    assert read_stamp(tmp_path / "report.md") == odd
    (tmp_path / "report.md").write_text("# no stamp\n<!-- provenance {broken -->\n")
    assert read_stamp(tmp_path / "report.md") is None


def test_study_index_rewrites_the_index_from_the_stamps(tmp_path: Path) -> None:
    from tests.cli_run import beamrelay

    _write(tmp_path / "online", _prov("abc123", 1, 2, 3.0))
    (tmp_path / "index.md").write_text("edited by hand\n")
    ran = beamrelay("study", "index", "-o", tmp_path)
    assert ran.returncode == 0, ran.stderr
    index = (tmp_path / "index.md").read_text()
    assert index == "\n".join(provenance.index_lines(tmp_path, study_all.ORDER))
    assert _rows(index)["online"][2:5] == ["abc123", "1", "2"]
    assert _rows(index)["ik-grid"][2] == "no stamp"
    assert beamrelay("study", "index", "-o", tmp_path / "none").returncode == 2


@pytest.mark.parametrize(
    ("name", "module"), [("ik-grid", "ik_grid"), ("experiments", "experiments")]
)
def test_the_studies_with_their_own_command_stamp_their_report(
    name: str, module: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """ik-grid and experiments have options of their own (not common.study_command): run
    from the command line alone they stamp their report too."""
    import importlib

    from tests.cli_run import beamrelay

    def main(trials: int, seed: int, out: Path, *rest: Any) -> dict:
        out.mkdir(parents=True, exist_ok=True)
        (out / "report.md").write_text(f"# {name}\n")
        return {"study": name}

    monkeypatch.setattr(importlib.import_module(f"planner.studies.{module}"), "main", main)
    ran = beamrelay("study", name, "--trials", "2", "--seed", "4", "-o", tmp_path)
    assert ran.returncode == 0, ran.stderr
    stamp = read_stamp(tmp_path / "report.md")
    assert stamp is not None and (stamp.seed, stamp.trials, stamp.commit) == (4, 2, _describe())
    assert stamp.command == f"beamrelay study {name} --trials 2 --seed 4 -o {tmp_path}"
