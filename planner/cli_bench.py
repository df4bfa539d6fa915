"""``beamrelay bench ...``: each benchmark lives in ``planner/bench/<name>.py`` and exposes a
typer-annotated function ``command``; every one accepts ``--json`` and then prints its
figures as one JSON object on the last line of standard output."""

from __future__ import annotations

import importlib

import typer

app = typer.Typer(help="Benchmarks (figures printed, not asserted).", no_args_is_help=True)

for _name in ("ik", "path", "service"):
    try:
        _mod = importlib.import_module(f"planner.bench.{_name}")
    except ImportError:
        continue
    app.command(_name)(_mod.command)
