"""Supervised child processes for ``beamrelay up``: start, watch, restart, stop.

Each child runs in its own session (so a terminal's Ctrl-C reaches only the supervisor, which
then stops the children in order) and, on Linux, gets SIGTERM if the supervisor dies. Output
goes to ``<log_dir>/<name>.log``. A child that exits while the supervisor runs is restarted
after ``RESTART_DELAY`` seconds (doubling for each quick crash, at most ``MAX_DELAY``),
except children marked ``manual`` (drivers of real hardware): they stay down until
:meth:`Supervisor.restart` (the operator's acknowledgement). Every time is read from the
supervisor's ``clock`` (monotonic s; tests pass a fake one and step it).
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

RESTART_DELAY = 0.5  # s before the first restart
MAX_DELAY = 8.0  # s, cap of the doubling back-off
STABLE_AFTER = 10.0  # s of uptime after which the back-off resets


def _die_with_parent() -> None:  # pragma: no cover - runs in the child before exec
    """Ask Linux to send SIGTERM to this child when its parent dies (prctl PR_SET_PDEATHSIG)."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)


@dataclass
class Child:
    """One supervised process: ``argv`` (the program and its arguments), state and history."""

    name: str
    argv: list[str]
    proc: subprocess.Popen[bytes] | None = None
    restarts: int = 0
    started: float = 0.0
    last_exit: int | None = None
    next_start: float = 0.0
    delay: float = RESTART_DELAY
    manual: bool = False  # restart only on the operator's acknowledgement
    env: dict[str, str] = field(default_factory=dict)  # added to the inherited environment
    log: IO[bytes] | None = field(default=None, repr=False)

    @property
    def awaiting_operator(self) -> bool:
        """A manual child that exited and waits for :meth:`Supervisor.restart`."""
        return self.manual and self.proc is not None and not self.running

    @property
    def pid(self) -> int | None:
        return None if self.proc is None else self.proc.pid

    @property
    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def uptime(self, now: float) -> float:
        """Seconds it has run at ``now`` (monotonic s); 0 when it is not running."""
        return now - self.started if self.running else 0.0


class Supervisor:
    """Start children, restart the ones that exit, stop them all on :meth:`stop`.
    ``clock``: monotonic s, the time of every start and back-off."""

    def __init__(
        self,
        children: dict[str, list[str]],
        log_dir: Path,
        manual: tuple[str, ...] = (),
        clock: Callable[[], float] = time.monotonic,
        env: dict[str, dict[str, str]] | None = None,
    ) -> None:
        self.clock = clock
        env = env or {}
        self.children = {
            name: Child(name, argv, manual=name in manual, env=env.get(name, {}))
            for name, argv in children.items()
        }
        self.log_dir = Path(log_dir)
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.stopping = False

    def _spawn(self, child: Child) -> None:
        if child.log is None:
            child.log = (self.log_dir / f"{child.name}.log").open("ab")
        child.proc = subprocess.Popen(
            child.argv,
            stdin=subprocess.DEVNULL,
            stdout=child.log,
            stderr=subprocess.STDOUT,
            env={**os.environ, **child.env} if child.env else None,
            start_new_session=True,
            preexec_fn=_die_with_parent if sys.platform.startswith("linux") else None,
        )
        child.started = self.clock()

    def start(self) -> None:
        for child in self.children.values():
            self._spawn(child)

    def poll(self) -> list[str]:
        """Restart children that exited (after their back-off); the names restarted now."""
        restarted = []
        now = self.clock()
        for child in self.children.values():
            if self.stopping or child.proc is None or child.running:
                continue
            if child.manual:
                child.last_exit = child.proc.returncode
                continue
            if child.next_start == 0.0:  # just noticed the exit
                child.last_exit = child.proc.returncode
                if now - child.started > STABLE_AFTER:
                    child.delay = RESTART_DELAY
                child.next_start = now + child.delay
                child.delay = min(2 * child.delay, MAX_DELAY)
            elif now >= child.next_start:
                child.next_start = 0.0
                child.restarts += 1
                self._spawn(child)
                restarted.append(child.name)
        return restarted

    def restart(self, name: str) -> bool:
        """Start a manual child that exited (the operator acknowledged); whether it started."""
        child = self.children.get(name)
        if self.stopping or child is None or not child.awaiting_operator:
            return False
        child.restarts += 1
        self._spawn(child)
        return True

    def uptime(self, name: str) -> float:
        """Seconds child ``name`` has run (0 when it is not running)."""
        return self.children[name].uptime(self.clock())

    def kill(self, name: str, sig: int = signal.SIGKILL) -> None:
        """Send ``sig`` to one child (tests and fault drills)."""
        child = self.children[name]
        if child.running and child.proc is not None:
            child.proc.send_signal(sig)

    def stop(self, timeout: float = 5.0, order: list[str] | None = None) -> dict[str, int | None]:
        """SIGTERM every child (in ``order`` first), SIGKILL what is left after ``timeout``."""
        self.stopping = True
        names = [*(order or []), *(n for n in self.children if n not in (order or []))]
        for name in names:
            child = self.children[name]
            if child.running and child.proc is not None:
                child.proc.terminate()
        deadline = time.monotonic() + timeout
        for name in names:
            proc = self.children[name].proc
            if proc is None:
                continue
            try:
                proc.wait(max(deadline - time.monotonic(), 0.01))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        out = {}
        for name, child in self.children.items():
            out[name] = None if child.proc is None else child.proc.returncode
            if child.log is not None:
                child.log.close()
                child.log = None
        return out

    def __enter__(self) -> Supervisor:
        return self

    def __exit__(self, *exc: Any) -> None:
        if not self.stopping:
            self.stop()


class LogTail:
    """The lines the children append to their logs (``<log_dir>/<name>.log``) from now on,
    for ``up`` without a terminal: it prints the events every process logs."""

    def __init__(self, log_dir: Path, names: list[str]) -> None:
        self.paths = {n: Path(log_dir) / f"{n}.log" for n in names}
        self.offsets = {n: (p.stat().st_size if p.exists() else 0) for n, p in self.paths.items()}
        self.partial = dict.fromkeys(names, b"")

    def lines(self) -> list[tuple[str, str]]:
        """(child, line) of every complete line written since the last call."""
        out = []
        for name, path in self.paths.items():
            if not path.exists():
                continue
            with path.open("rb") as f:
                f.seek(self.offsets[name])
                data = f.read()
            self.offsets[name] += len(data)
            *done, self.partial[name] = (self.partial[name] + data).split(b"\n")
            out += [(name, line.decode(errors="replace")) for line in done if line.strip()]
        return out
