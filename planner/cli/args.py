"""Parsers of command-line values shared by the CLI modules (light: no heavy imports)."""

from __future__ import annotations

import signal
import threading
from typing import Any

import typer

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


MAX_DOMAIN = 232  # ROS_DOMAIN_ID range (REP 2005 / the ROS 2 domain id docs)


def check_domain(domain: int) -> int:
    """``--ros-domain``: a ROS_DOMAIN_ID (0-232), else InputError."""
    if not 0 <= domain <= MAX_DOMAIN:
        raise InputError(f"--ros-domain {domain}: expected 0-{MAX_DOMAIN}")
    return domain


def stop_on_signals() -> threading.Event:
    """An event that SIGINT (Ctrl-C) and SIGTERM set: what a command that runs until stopped
    waits on (install from the main thread)."""
    stop = threading.Event()

    def on_signal(signum: int, frame: Any) -> None:
        stop.set()

    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, on_signal)
    return stop


def wait_until_set(stop: threading.Event, poll: float = 0.2) -> None:
    """Block until ``stop`` is set, waking every ``poll`` s (so signal handlers run)."""
    while not stop.wait(poll):
        pass


def command_group(**settings: Any) -> typer.Typer:
    """A command group of ``beamrelay`` (``typer.Typer(**settings)``) with click's plain help
    formatter: paragraphs re-wrapped to the terminal, flags shown without a type, no boxes."""
    return typer.Typer(rich_markup_mode=None, **settings)
