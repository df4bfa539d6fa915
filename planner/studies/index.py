"""``beamrelay study index -o reports``: rewrite ``reports/index.md`` from the reports' own
provenance stamps (:mod:`planner.studies.provenance`), without running any study; what
``beamrelay study all`` does last."""

from __future__ import annotations

from pathlib import Path

import typer

from planner.studies import common
from planner.studies.all import ORDER
from planner.studies.provenance import write_index


def command(out: common.Out = Path("reports")) -> None:
    """Rewrite OUT/index.md from the stamps of OUT/<study>/report.md (no study is run)."""
    if not out.is_dir():
        from planner.errors import InputError

        raise InputError("no such reports folder", str(out))
    typer.echo(f"index: {write_index(out, ORDER)}")
