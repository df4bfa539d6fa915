"""Study plumbing: per-trial RNG, executor-independent parallel map (local, processes, Dask),
CSV / markdown / report output and the generated typer command."""

from __future__ import annotations

import inspect
import json
from pathlib import Path

import numpy as np
import pytest

from planner.errors import InputError
from planner.studies import common
from planner.studies import sensitivity as sens
from planner.studies.common import markdown_table, parallel_map, trial_rng, write_csv


def draw(seed: int, trial: int) -> float:
    return float(trial_rng(seed, trial).uniform())


def _square_plus(x: int, seed: int) -> float:
    return float(x * x + np.random.default_rng([seed, x]).uniform())


def test_trial_rng_depends_only_on_seed_and_trial() -> None:
    expect = np.random.default_rng(np.random.SeedSequence([7, 3])).uniform()
    assert draw(7, 3) == expect
    assert draw(7, 3) != draw(7, 4)


def test_parallel_map_same_results_serial_and_processes() -> None:
    jobs = [(5, t) for t in range(6)]
    serial = parallel_map(draw, jobs, workers=1)
    pooled = parallel_map(draw, jobs, workers=2)
    assert serial == pooled == [draw(5, t) for t in range(6)]


def test_process_pool_keeps_order_and_values() -> None:
    jobs = [(i, 5) for i in range(7)]
    expected = [_square_plus(*j) for j in jobs]
    assert parallel_map(_square_plus, jobs, workers=2) == expected
    assert parallel_map(_square_plus, jobs, workers=1) == expected


def test_bad_workers_is_an_input_error() -> None:
    with pytest.raises(InputError):
        parallel_map(_square_plus, [(1, 0), (2, 0)], workers=0)


def test_dask_local_cluster_gives_identical_study_results() -> None:
    from dask.distributed import LocalCluster

    _, local = sens.run(trials=2, seed=3, workers=1)
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False) as cluster:
        _, remote = sens.run(trials=2, seed=3, scheduler=cluster.scheduler_address)
    assert [r["error_mm"] for r in remote] == [r["error_mm"] for r in local]
    assert [r["predicted_mm"] for r in remote] == [r["predicted_mm"] for r in local]


def test_csv_and_markdown(tmp_path: Path) -> None:
    rows = [{"a": 1, "b": 0.5}, {"a": 2, "b": 0.25}]
    write_csv(tmp_path / "x.csv", rows)
    assert (tmp_path / "x.csv").read_text().splitlines() == ["a,b", "1,0.5", "2,0.25"]
    assert markdown_table(rows).splitlines()[2] == "| 1 | 0.5 |"
    write_csv(tmp_path / "sub" / "empty.csv", [])
    assert (tmp_path / "sub" / "empty.csv").read_text() == ""


def test_write_report_writes_lines_and_tables(tmp_path: Path) -> None:
    path = common.write_report(
        tmp_path / "r", ["# t", ""], {"a.csv": [{"k": 3}]}, ("plot", "p.png")
    )
    assert path == tmp_path / "r" / "report.md"
    assert path.read_text() == "# t\n\n![plot](p.png)\n"
    assert (tmp_path / "r" / "a.csv").read_text().splitlines() == ["k", "3"]


def test_out_dir_under_a_file_is_an_input_error(tmp_path: Path) -> None:
    (tmp_path / "f").write_text("")
    with pytest.raises(InputError):
        common.out_dir(tmp_path / "f" / "sub")


def _fake_main(trials: int, seed: int, out: Path, workers: int | None, sched: str | None) -> dict:
    """Fake study."""
    return {"trials": trials, "seed": seed, "out": str(out), "workers": workers, "s": sched}


def test_study_command_options_and_json(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    cmd = common.study_command(_fake_main, 7, tmp_path)
    params = inspect.signature(cmd).parameters
    assert list(params) == ["trials", "seed", "out", "workers", "dask_scheduler", "json_out"]
    assert params["trials"].default == 7 and params["out"].default == tmp_path
    assert cmd.__doc__ == "Fake study."
    cmd(json_out=True)
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0] == f"report: {tmp_path / 'report.md'}"
    assert json.loads(lines[-1]) == {
        "trials": 7,
        "seed": 0,
        "out": str(tmp_path),
        "workers": None,
        "s": None,
    }


def test_study_command_through_typer(tmp_path: Path) -> None:
    import typer
    from typer.testing import CliRunner

    app = typer.Typer()
    app.command("fake")(common.study_command(_fake_main, 7, tmp_path))
    app.command("other")(lambda: None)
    res = CliRunner().invoke(
        app, ["fake", "--trials", "3", "--seed", "9", "--workers", "2", "--json"]
    )
    assert res.exit_code == 0, res.output
    figures = json.loads(res.output.strip().splitlines()[-1])
    assert (figures["trials"], figures["seed"], figures["workers"]) == (3, 9, 2)
    bad = CliRunner().invoke(app, ["fake", "--workers", "0"])
    assert bad.exit_code == 2
