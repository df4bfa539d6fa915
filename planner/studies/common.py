"""Shared plumbing of every study: the common command options, a seeded per-trial RNG, a
parallel map whose results do not depend on the executor, CSV / markdown / figure output and
the standard ``report.md`` + ``--json`` ending (the report stamped with its provenance,
:mod:`planner.studies.provenance`).

Reproducibility: a job is a pure function of its arguments (a trial draws from
``trial_rng(seed, trial)``, i.e. ``SeedSequence([seed, trial])``, or from its own documented
seed tuple), and results come back in input order, so serial, process-pool and Dask runs give
identical numbers.
"""

from __future__ import annotations

import csv
import json
import os
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import typer

from planner.errors import InputError
from planner.studies.provenance import stamp

Rows = Sequence[Mapping[str, Any]]

# the common options of every study command (typer ``Annotated`` aliases)
Trials = Annotated[int, typer.Option("--trials", min=1, help="Random trials.")]
Seed = Annotated[int, typer.Option("--seed", min=0, help="Seed of every random draw.")]
Out = Annotated[Path, typer.Option("-o", "--out", help="Output folder.")]
Workers = Annotated[
    int | None, typer.Option("--workers", min=1, help="Local processes (default: all cores).")
]
Scheduler = Annotated[
    str | None,
    typer.Option("--dask-scheduler", help="Run on a Dask cluster, e.g. tcp://host:8786."),
]
JsonOut = Annotated[bool, typer.Option("--json", help="Print the figures as JSON, last line.")]


def out_dir(path: Path) -> Path:
    """Create (if needed) and return a study's output folder; InputError if impossible."""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create output directory: {exc.strerror}", str(path)) from exc
    return path


def trial_rng(seed: int, trial: int) -> np.random.Generator:
    """The RNG of one trial: independent of how many trials run and where."""
    return np.random.default_rng(np.random.SeedSequence([seed, trial]))


def default_workers() -> int:
    """All local cores."""
    return max(1, os.cpu_count() or 1)


def _call(fn_args: tuple[Callable[..., Any], tuple[Any, ...]]) -> Any:
    fn, args = fn_args
    return fn(*args)


def parallel_map(
    fn: Callable[..., Any],
    jobs: Sequence[tuple[Any, ...]],
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    label: str = "trials",
) -> list[Any]:
    """``[fn(*job) for job in jobs]`` with a rich progress bar, in input order.

    ``scheduler`` (``tcp://host:8786``, or a ``LocalCluster``'s address) runs the jobs on a
    Dask cluster; otherwise ``workers`` local processes (None: all cores; 1: in this
    process). ``fn`` must be a module-level function. InputError for ``workers < 1`` or an
    unreachable scheduler.
    """
    from rich.progress import Progress

    n = len(jobs)
    results: list[Any] = [None] * n
    with Progress(transient=True) as progress:
        task = progress.add_task(label, total=n)
        if scheduler:
            from dask.distributed import Client, as_completed

            try:
                client = Client(scheduler, timeout="10s")
            except OSError as exc:
                raise InputError(f"cannot reach the Dask scheduler: {exc}", scheduler) from exc
            try:
                futures = [client.submit(fn, *job, pure=False) for job in jobs]
                index = {f.key: i for i, f in enumerate(futures)}
                for fut in as_completed(futures):
                    results[index[fut.key]] = fut.result()
                    progress.advance(task)
            finally:
                client.close()
            return results
        nworkers = default_workers() if workers is None else workers
        if nworkers < 1:
            raise InputError(f"--workers must be >= 1, got {nworkers}")
        if nworkers == 1 or n <= 1:
            for i, job in enumerate(jobs):
                results[i] = fn(*job)
                progress.advance(task)
            return results
        from concurrent.futures import ProcessPoolExecutor
        from concurrent.futures import as_completed as done

        with ProcessPoolExecutor(max_workers=min(nworkers, n)) as pool:
            fmap = {pool.submit(_call, (fn, job)): i for i, job in enumerate(jobs)}
            for f in done(fmap):
                results[fmap[f]] = f.result()
                progress.advance(task)
    return results


def write_csv(path: Path, rows: Rows) -> None:
    """Rows of equal keys to a CSV file with a header (empty file for no rows)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        if not rows:
            return
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def table_lines(header: Sequence[str], rows: Iterable[Mapping[str, Any]], row: str) -> list[str]:
    """Lines of a GitHub markdown table: the header, the rule, then each of ``rows`` through
    ``row``, a ``str.format`` template of the cells separated by `` | ``."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return lines + ["| " + row.format(**r) + " |" for r in rows]


def markdown_table(rows: Rows, fmt: str = ".3g") -> str:
    """A GitHub markdown table of rows of equal keys (floats formatted with ``fmt``)."""
    if not rows:
        return "(no rows)\n"
    keys = list(rows[0])

    def cell(v: Any) -> str:
        return format(v, fmt) if isinstance(v, float) else str(v)

    lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    lines += ["| " + " | ".join(cell(r[k]) for k in keys) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def pyplot() -> Any:
    """matplotlib.pyplot on the Agg backend (imported on first use)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig: Any, path: Path, dpi: int = 90) -> None:
    """Tight layout, save as PNG at ``dpi`` and close the figure."""
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    pyplot().close(fig)


def write_report(
    out: Path,
    lines: Sequence[str],
    tables: Mapping[str, Rows],
    image: tuple[str, str] | None = None,
) -> Path:
    """``out/report.md`` from ``lines`` (then ``image`` = (alt text, PNG file in ``out``)
    if given) and each table as ``out/<name>`` CSV; returns the report's path."""
    folder = out_dir(out)
    for name, rows in tables.items():
        write_csv(folder / name, rows)
    text = list(lines) + ([f"![{image[0]}]({image[1]})", ""] if image else [])
    report = folder / "report.md"
    report.write_text("\n".join(text))
    return report


def finish(
    out: Path, figures: Mapping[str, Any], json_out: bool, report: str = "report.md"
) -> None:
    """Say where the report is; with ``--json`` print the figures as one JSON line last."""
    typer.echo(f"report: {out / report}")
    if json_out:
        typer.echo(json.dumps(figures, default=float))


#: a study's whole run: (trials, seed, out, workers, scheduler) -> its ``--json`` figures
StudyMain = Callable[[int, int, Path, int | None, str | None], Mapping[str, Any]]


def study_command(
    main: StudyMain, trials: int, out: Path, report: str = "report.md"
) -> Callable[..., None]:
    """The typer command of a study, its help = ``main``'s docstring: the common options
    (``--trials`` defaulting to ``trials``, ``--seed``, ``-o`` defaulting to ``out``,
    ``--workers``, ``--dask-scheduler``, ``--json``), then ``main`` and :func:`finish`
    (which names ``out/report``)."""
    default_trials, default_out = trials, out

    def command(
        trials: Trials = default_trials,
        seed: Seed = 0,
        out: Out = default_out,
        workers: Workers = None,
        dask_scheduler: Scheduler = None,
        json_out: JsonOut = False,
    ) -> None:
        t0 = time.perf_counter()
        figures = main(trials, seed, out, workers, dask_scheduler)
        name = main.__module__.rsplit(".", 1)[-1].replace("_", "-")
        stamp(out / report, f"beamrelay study {name} --trials {trials} --seed {seed} -o {out}",
              trials, seed, time.perf_counter() - t0)  # fmt: skip
        finish(out, figures, json_out, report)

    command.__doc__ = main.__doc__
    return command
