"""The ``beamrelay`` command line run in-process, as its console entry point runs it.

``planner.cli.main(argv)`` is called with standard output and error captured; a
``SystemExit`` becomes the exit status, anything else that escapes ``main`` propagates and
fails the test (in a terminal it would be a traceback). About 0.1 s a call instead of the
0.7-1.5 s of a fresh interpreter under load; the few behaviours only a real process shows
(no-args help, ``--version``, a closed stdout, ``plan | head``) keep their subprocess tests in
``tests/planner/cli/test_cli_usage.py``.
"""

from __future__ import annotations

import contextlib
import io
import logging
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

from planner.cli import main
from tests.paths import REPO


@dataclass(frozen=True)
class Ran:
    """What one command left behind: the exit status and the two streams' text."""

    returncode: int
    stdout: str
    stderr: str


@contextlib.contextmanager
def _unconfigured_logging() -> Iterator[None]:
    """Logging as in a fresh interpreter: the root logger without handlers and the
    ``beamrelay`` logger not configured (an earlier in-process command may have called
    :func:`planner.bus.events.configure`, which sends its records to the standard error
    of that time), so a warning reaches this call's standard error through logging's
    last-resort handler (pytest's capture handlers would take it instead). Both are put back
    afterwards, and a writer this call configured is stopped."""
    from planner.bus import events

    root, ours = logging.getLogger(), logging.getLogger("beamrelay")
    saved = root.handlers[:], ours.handlers[:], ours.propagate, ours.level, events._listener
    root.handlers.clear()
    ours.handlers.clear()
    ours.propagate, events._listener = True, None
    ours.setLevel(logging.NOTSET)
    try:
        yield
    finally:
        events.stop()
        root.handlers[:], ours.handlers[:] = saved[0], saved[1]
        ours.propagate, events._listener = saved[2], saved[4]
        ours.setLevel(saved[3])


def beamrelay(*args: str | Path, cwd: Path = REPO) -> Ran:
    """``beamrelay ARGS...`` run in-process from ``cwd`` (the repository by default)."""
    out, err = io.StringIO(), io.StringIO()
    status = 0
    with (
        contextlib.chdir(cwd),
        contextlib.redirect_stdout(out),
        contextlib.redirect_stderr(err),
        _unconfigured_logging(),
    ):
        try:
            main([str(a) for a in args])
        except SystemExit as exc:
            status = exc.code if isinstance(exc.code, int) else 1
    return Ran(status, out.getvalue(), err.getvalue())


class Finished(Protocol):
    """A finished command: a ``Ran`` or a ``subprocess.CompletedProcess[str]``."""

    @property
    def returncode(self) -> int: ...
    @property
    def stdout(self) -> str: ...
    @property
    def stderr(self) -> str: ...


def assert_usage_error(ran: Finished, *words: str) -> None:
    """Exit status 2 and exactly one line on stderr, ``error: ...`` naming every word."""
    lines = ran.stderr.strip().splitlines()
    assert ran.returncode == 2, (ran.returncode, ran.stdout, ran.stderr)
    assert "Traceback" not in ran.stderr and len(lines) == 1, ran.stderr
    assert lines[0].startswith("error: "), lines
    for word in words:
        assert word in lines[0], (word, lines[0])
