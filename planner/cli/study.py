"""``beamrelay study NAME``: each study lives in ``planner/studies/<name>.py`` (``-`` in the
command name is ``_`` in the module) and exposes a typer-annotated function ``command``
taking at least ``--trials``, ``--seed``, ``-o/--out``, ``--workers`` and ``--json``."""

from __future__ import annotations

import importlib
import importlib.util

import typer

app = typer.Typer(help="Studies: paper reproductions and reports.", no_args_is_help=True)

STUDIES = ("ik-grid", "calibration", "sensitivity", "mirror-sweep", "coverage", "tracking", "all")

for _name in STUDIES:
    if importlib.util.find_spec(_module := f"planner.studies.{_name.replace('-', '_')}") is None:
        continue
    _mod = importlib.import_module(_module)
    app.command(_name)(_mod.command)
