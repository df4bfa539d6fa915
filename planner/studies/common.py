"""Shared study helpers: output directory, per-trial seeded RNG, CSV and report.md writing,
and a parallel map over trials whose results do not depend on the executor.

Each trial gets its own ``numpy.random.Generator`` from ``SeedSequence([seed, trial])``, so
serial, process-pool and dask runs give identical numbers.
"""

from __future__ import annotations

import csv
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from planner.errors import InputError


def out_dir(path: Path) -> Path:
    """Create (if needed) and return the study output directory."""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create output directory: {exc.strerror}", str(path)) from exc
    return path


def trial_rng(seed: int, trial: int) -> np.random.Generator:
    """The RNG of one trial: independent of how many trials run and where."""
    return np.random.default_rng(np.random.SeedSequence([seed, trial]))


def write_csv(path: Path, rows: Sequence[dict[str, Any]]) -> None:
    """Rows of equal keys to a CSV file (header from the first row)."""
    if not rows:
        path.write_text("")
        return
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def markdown_table(rows: Sequence[dict[str, Any]], fmt: str = ".3g") -> str:
    """A GitHub markdown table of rows (numbers formatted with ``fmt``)."""
    if not rows:
        return "(no rows)\n"
    keys = list(rows[0])

    def cell(v: Any) -> str:
        return format(v, fmt) if isinstance(v, float) else str(v)

    lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    lines += ["| " + " | ".join(cell(r[k]) for k in keys) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def _call(fn_args: tuple[Callable[..., Any], tuple[Any, ...]]) -> Any:
    fn, args = fn_args
    return fn(*args)


def parallel_map(
    fn: Callable[..., Any],
    jobs: Sequence[tuple[Any, ...]],
    *,
    workers: int | None = 1,
    scheduler: str | None = None,
    label: str = "trials",
) -> list[Any]:
    """``[fn(*job) for job in jobs]`` in input order, with a rich progress bar: in this
    process (``workers`` 1), over a process pool, or on a dask.distributed scheduler
    (``tcp://host:8786``). ``fn`` must be a module-level function; results do not depend on
    the executor (same signature as :func:`planner.studies.runtime.parallel_map`)."""
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
        if workers is None or workers > 1:
            from concurrent.futures import ProcessPoolExecutor
            from concurrent.futures import as_completed as done

            with ProcessPoolExecutor(max_workers=workers) as pool:
                fmap = {pool.submit(_call, (fn, job)): i for i, job in enumerate(jobs)}
                for f in done(fmap):
                    results[fmap[f]] = f.result()
                    progress.advance(task)
            return results
        for i, job in enumerate(jobs):
            results[i] = fn(*job)
            progress.advance(task)
    return results
