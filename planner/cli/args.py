"""Parsers of command-line values shared by the CLI modules (light: no heavy imports)."""

from __future__ import annotations

from planner.errors import InputError


def parse_xyz(text: str, option: str) -> list[float]:
    """``X,Y,Z`` (three numbers, e.g. metres) given to ``option``; InputError naming the
    option and the text otherwise."""
    try:
        v = [float(x) for x in text.split(",")]
    except ValueError as exc:
        raise InputError(f"{option} {text!r}: expected X,Y,Z numbers") from exc
    if len(v) != 3:
        raise InputError(f"{option} {text!r}: expected X,Y,Z (3 numbers), got {len(v)}")
    return v
