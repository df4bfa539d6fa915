"""``beamrelay study NAME``: each study lives in ``planner/studies/<name>.py`` (``-`` in the
command name is ``_`` in the module) and exposes a typer-annotated function ``command``
taking at least ``--trials``, ``--seed``, ``-o/--out``, ``--workers`` and ``--json``."""

from __future__ import annotations

from planner.cli.args import command_group
from planner.studies import all as all_studies
from planner.studies import index as study_index

app = command_group(help="Studies: paper reproductions and reports.", no_args_is_help=True)

STUDIES = {**all_studies.STUDIES, "all": all_studies}
"""Command name -> study module (its ``command`` is the sub-command)."""

for _name, _module in STUDIES.items():
    app.command(_name)(_module.command)
app.command("index")(study_index.command)
