"""``beamrelay bench ...``: each benchmark lives in ``planner/bench/<name>.py`` and exposes a
typer-annotated function ``command``; every one accepts ``--json`` and then prints its
figures as one JSON object on the last line of standard output."""

from __future__ import annotations

import importlib
import importlib.util

import typer

app = typer.Typer(help="Benchmarks (figures printed, not asserted).", no_args_is_help=True)

for _name in ("ik", "path", "service", "plan", "safety"):
    if importlib.util.find_spec(_module := f"planner.bench.{_name}") is None:
        continue
    _mod = importlib.import_module(_module)
    app.command(_name)(_mod.command)
