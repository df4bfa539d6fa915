"""``beamrelay bench ...``: each benchmark lives in ``planner/bench/<name>.py`` and exposes a
typer-annotated function ``command``; every one accepts ``--json`` and then prints its
figures as one JSON object on the last line of standard output."""

from __future__ import annotations

from planner.bench import (
    brakes,
    camera,
    corners,
    detectors,
    ik,
    marking,
    path,
    plan,
    preview,
    ros2,
    safety,
    service,
    servo,
    track,
)
from planner.cli.args import command_group

app = command_group(help="Benchmarks (figures printed, not asserted).", no_args_is_help=True)

BENCHMARKS = {
    "ik": ik,
    "path": path,
    "marking": marking,
    "corners": corners,
    "service": service,
    "plan": plan,
    "preview": preview,
    "safety": safety,
    "servo": servo,
    "track": track,
    "brakes": brakes,
    "camera": camera,
    "detectors": detectors,
    "ros2": ros2,
}
"""Command name -> benchmark module (its ``command`` is the sub-command)."""

for _name, _module in BENCHMARKS.items():
    app.command(_name)(_module.command)
