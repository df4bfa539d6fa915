"""Plumbing of the sensitivity / mirror-sweep / coverage / tracking studies.

Delegates to the shared helpers of :mod:`planner.studies.common` when they exist and
keeps a small equivalent otherwise: a parallel map whose results do not depend on the
executor (each job is a pure function of its arguments; results come back in input order),
CSV writing, a lazily imported Agg pyplot, and the ``--json`` ending of a command.
"""

from __future__ import annotations

import csv
import json
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Annotated, Any

import typer

from planner.errors import InputError

# the common options of every study command (typer ``Annotated`` aliases)
Trials = Annotated[int, typer.Option("--trials", min=1, help="Random trials.")]
Seed = Annotated[int, typer.Option("--seed", help="Seed of every random draw.")]
Out = Annotated[Path, typer.Option("-o", "--out", help="Output folder.")]
Workers = Annotated[
    int | None, typer.Option("--workers", min=1, help="Local processes (default: all cores).")
]
Scheduler = Annotated[
    str | None,
    typer.Option("--dask-scheduler", help="Run on a Dask cluster, e.g. tcp://host:8786."),
]
JsonOut = Annotated[bool, typer.Option("--json", help="Print the figures as JSON, last line.")]


def _call(fn_args: tuple[Callable[..., Any], tuple[Any, ...]]) -> Any:
    fn, args = fn_args
    return fn(*args)


def default_workers() -> int:
    """All local cores."""
    return max(1, os.cpu_count() or 1)


def parallel_map(
    fn: Callable[..., Any],
    jobs: Sequence[tuple[Any, ...]],
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    label: str = "trials",
) -> list[Any]:
    """``[fn(*job) for job in jobs]`` with a progress bar, in input order.

    ``scheduler`` (``tcp://host:8786``, or a ``dask.distributed.Client``/``LocalCluster``
    address) runs the jobs on a Dask cluster; otherwise ``workers`` local processes
    (``1``: in this process). ``fn`` must be a module-level function.
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


def write_csv(path: Path, rows: Sequence[dict[str, Any]]) -> None:
    """Rows of dicts (same keys) as CSV with a header."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        if not rows:
            return
        w = csv.DictWriter(fh, fieldnames=list(rows[0].keys()))
        w.writeheader()
        w.writerows(rows)


def pyplot() -> Any:
    """matplotlib.pyplot on the Agg backend (imported on first use)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def finish(out: Path, figures: dict[str, Any], json_out: bool) -> None:
    """Say where the report is; with ``--json`` print the figures as one JSON line last."""
    typer.echo(f"report: {out / 'report.md'}")
    if json_out:
        typer.echo(json.dumps(figures, default=float))
