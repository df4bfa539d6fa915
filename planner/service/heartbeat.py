"""The planner's heartbeat, published by a small child process of the planner.

Why a process. The heartbeat (:class:`~schemas.messages.Heartbeat` ``{t, session, seq}``,
100 Hz on ``<prefix>/heartbeat``) is what robot drivers follow while they move: after
100 ms of silence they brake. Published from a thread of the planner, it waits for the GIL,
which the planner's solvers (CasADi/IPOPT) hold for up to a second on a long path: the
heartbeat then gaps for 100-190 ms and the drivers brake a moving arm although the planner
is fine. A child process does not share the GIL; it keeps the heartbeat's meaning, "the
planner is alive and not wedged", by beating only while

- its parent is alive: it exits when the parent dies (its stdin pipe closes, and
  ``os.getppid()`` changes), so no orphan keeps beating;
- its parent runs: while the parent is stopped (SIGSTOP, a debugger; Linux: state ``T``/``t``
  in ``/proc/<ppid>/stat``) it does not beat, and beats again once the parent continues;
- its parent responds and its worker is not wedged: the parent writes a tick byte every
  :data:`TICK_PERIOD` s from a watchdog thread that also checks the worker's progress
  (:class:`planner.service.guard.Progress`). Without a tick for :data:`PARENT_STALL` s
  (a C call holding the GIL for good) it does not beat; on a wedged worker or when the
  node stops, the parent writes a stop byte and the child exits at once.

The child opens its own Zenoh session (a Zenoh session cannot be shared across processes)
as a *client* of the bus endpoint with the planner's config file, hence with the planner's
identity where access control applies; the host routes its samples. It is started with
``python -m planner.service.heartbeat`` (no fork of the planner, no re-import of the
parent's main module) and prints ``ready`` after its first beat. The whole process (its
beat loop sleeps every period, Zenoh's threads wait for I/O) runs at real-time priority
where permitted (:func:`planner.bus.priority.raise_priority`) so that a loaded machine
does not delay its beats.
"""

from __future__ import annotations

import argparse
import contextlib
import fcntl
import functools
import json
import logging
import os
import select
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from planner.bus.priority import Policy, raise_priority
from planner.bus.session import _ENDPOINT, _HOST_PORT, JSON, _zenoh_message, urgent, zenoh_config
from planner.errors import BeamrelayError
from planner.service.guard import Heartbeat
from schemas import defaults

log = logging.getLogger("beamrelay.node")

#: heartbeat rate (Hz); drivers brake after 100 ms of silence
HEARTBEAT_RATE = defaults.HEARTBEAT_RATE_HZ
#: the parent's watchdog writes a tick byte this often (s)
TICK_PERIOD = 0.05
#: without a tick for this long (s) the parent counts as unresponsive: no beats
PARENT_STALL = 3.0
#: longest wait (s) for the child's first beat
READY_TIMEOUT = 60.0
#: how long (s) the child waits for the bus when its session opens
CONNECT_TIMEOUT = 20.0
TICK, STOP = b".", b"S"


class HeartbeatError(BeamrelayError):
    """The heartbeat process could not be started (``reason`` says why)."""


@dataclass(frozen=True)
class BusAddress:
    """Where the planner's session is: the bus ``endpoint`` (None: the default) and the
    Zenoh ``config_file`` it was opened with (None: the built-in loopback defaults)."""

    endpoint: str | None = None
    config_file: Path | None = None


def child_config(bus: BusAddress, connect_timeout: float = CONNECT_TIMEOUT) -> Any:
    """The heartbeat child's Zenoh config: the planner's (same endpoint, same config file,
    so the same identity), in *client* mode toward the bus, listening nowhere."""

    conf = zenoh_config(listen=False, endpoint=bus.endpoint, config_file=bus.config_file,
                        connect_timeout=connect_timeout)  # fmt: skip
    connect = json.loads(conf.get_json("connect/endpoints"))
    if isinstance(connect, dict):  # per-mode defaults of a file naming only where it listens
        connect = []
    if not connect:  # a config file naming its own listen endpoints: connect there instead
        listen = json.loads(conf.get_json("listen/endpoints"))
        for ep in listen if isinstance(listen, list) else []:
            m = _ENDPOINT.match(str(ep))
            hp = _HOST_PORT.match(m["addr"]) if m else None
            if m and hp:
                host = "127.0.0.1" if hp["host"] in ("0.0.0.0", "[::]") else hp["host"]
                connect.append(f"{m['proto']}/{host}:{hp['port']}")
        conf.insert_json5("connect/endpoints", json.dumps(connect))
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("access_control/enabled", "false")  # a client's own link: see bus.py
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("connect/timeout_ms", str(round(1e3 * connect_timeout)))
    return conf


def process_state(pid: int) -> str | None:
    """Linux process state letter of ``pid`` (``R``, ``S``, ``T`` stopped, ``t`` traced,
    ...) from ``/proc/<pid>/stat``; None when unknown (no /proc, process gone)."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            stat = f.read()
    except OSError:
        return None
    rest = stat[stat.rfind(b")") + 2 :]  # the command name may hold spaces and ')'
    return rest[:1].decode() if rest else None


class HeartbeatProcess:
    """Parent side: starts the child, feeds it ticks, stops it. ``start()``, ``stop()``.

    ``on_wedged(reason)`` is called once (from the watchdog thread) when ``progress``
    reports a wedged worker or the child died; the child stops beating first.
    """

    def __init__(
        self,
        bus: BusAddress,
        key: str,
        session_id: str,
        progress: Any,
        on_wedged: Callable[[str], None],
        rate: float = HEARTBEAT_RATE,
        stall: float = PARENT_STALL,
        connect_timeout: float = CONNECT_TIMEOUT,
    ) -> None:
        self.bus = bus
        self.connect_timeout = connect_timeout
        self.key = key
        self.session_id = session_id
        self.progress = progress
        self.on_wedged = on_wedged
        self.rate = rate
        self.stall = stall
        self.proc: subprocess.Popen[bytes] | None = None
        self._stop = threading.Event()
        self._pipe_lock = threading.Lock()  # no write into a closed (maybe reused) fd
        self._thread = threading.Thread(target=self._watch, name="planner-watchdog", daemon=True)

    @property
    def pid(self) -> int | None:
        return None if self.proc is None else self.proc.pid

    def argv(self) -> list[str]:
        argv = [sys.executable, "-m", "planner.service.heartbeat", "--key", self.key,
                "--session", self.session_id, "--parent", str(os.getpid()),
                "--rate", repr(self.rate), "--stall", repr(self.stall),
                "--connect-timeout", repr(self.connect_timeout)]  # fmt: skip
        if self.bus.endpoint is not None:
            argv += ["--endpoint", self.bus.endpoint]
        if self.bus.config_file is not None:
            argv += ["--zenoh-config", str(Path(self.bus.config_file).resolve())]
        return argv

    def start(self, timeout: float = READY_TIMEOUT) -> HeartbeatProcess:
        """Start the child and return once it has beaten (HeartbeatError if it cannot)."""
        self.proc = subprocess.Popen(
            self.argv(), stdin=subprocess.PIPE, stdout=subprocess.PIPE, close_fds=True
        )
        assert self.proc.stdin is not None and self.proc.stdout is not None
        fd = self.proc.stdin.fileno()
        fcntl.fcntl(fd, fcntl.F_SETFL, fcntl.fcntl(fd, fcntl.F_GETFL) | os.O_NONBLOCK)
        self._thread.start()  # ticks from now on: the child counts its stall from its start
        line = _read_line(self.proc.stdout, timeout)
        if line != b"ready":
            code = self.proc.poll()
            self.stop()
            why = f"exited with code {code}" if code is not None else f"silent for {timeout:g} s"
            raise HeartbeatError(f"the heartbeat process did not start: {why}")
        return self

    def stop(self) -> None:
        """Stop beating now (the child exits); idempotent, callable from any thread."""
        self._stop.set()
        proc = self.proc
        if proc is None:
            return
        self._send(STOP)
        with self._pipe_lock, contextlib.suppress(OSError):
            assert proc.stdin is not None
            proc.stdin.close()
        try:
            proc.wait(timeout=2)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        if proc.stdout is not None:
            proc.stdout.close()
        if threading.current_thread() is not self._thread and self._thread.is_alive():
            self._thread.join(timeout=2)

    @property
    def beating(self) -> bool:
        return self.proc is not None and self.proc.poll() is None and not self._stop.is_set()

    def _send(self, byte: bytes) -> bool:
        proc = self.proc
        with self._pipe_lock:
            if proc is None or proc.stdin is None or proc.stdin.closed:
                return False
            try:
                os.write(proc.stdin.fileno(), byte)
            except BlockingIOError:  # the child does not read (stopped): it stalls anyway
                return True
            except OSError:  # the child is gone
                return False
        return True

    def _watch(self) -> None:
        """Tick every TICK_PERIOD s; on a wedged worker or a dead child: stop, report."""
        while not self._stop.wait(TICK_PERIOD):
            reason = self.progress.overdue()
            if reason is None and self.proc is not None and self.proc.poll() is not None:
                reason = f"the heartbeat process exited with code {self.proc.returncode}"
            if reason is not None:
                self._send(STOP)
                self._stop.set()
                self.on_wedged(reason)
                return
            self._send(TICK)


def start_heartbeat(
    session: Any,
    key: str,
    session_id: str,
    progress: Any,
    on_wedged: Callable[[str], None],
    bus: BusAddress | None,
    rate: float | None = None,
) -> tuple[Any, Any]:
    """The planner node's heartbeat on ``key`` (``rate`` Hz, None: the default), started:
    from the child process when the node has its ``bus`` address, else from a thread of this
    process (:class:`planner.service.guard.Heartbeat`) publishing through ``session``. Returns
    it and the publisher this process declared for it (None with the child process)."""

    hz = HEARTBEAT_RATE if rate is None else rate
    if bus is not None:
        return HeartbeatProcess(bus, key, session_id, progress, on_wedged, hz).start(), None
    log.warning("heartbeat published from the planner process (no bus address given): "
                "long solver calls can delay it")  # fmt: skip
    pub = session.declare_publisher(key, **urgent())
    beat = Heartbeat(lambda body: pub.put(body, encoding=JSON), session_id, progress,
                     on_wedged, hz).start()  # fmt: skip
    return beat, pub


def _read_line(stream: Any, timeout: float) -> bytes | None:
    """One line from a pipe within ``timeout`` s (without the newline); None if none."""
    deadline = time.monotonic() + timeout
    data = b""
    fd = stream.fileno()
    while b"\n" not in data:
        left = deadline - time.monotonic()
        if left <= 0 or not select.select([fd], [], [], left)[0]:
            return None
        chunk = os.read(fd, 256)
        if not chunk:
            return None
        data += chunk
    return data.split(b"\n", 1)[0].strip()


# --- the child ---------------------------------------------------------------------------
def beat_loop(
    put: Callable[[bytes], None],
    session_id: str,
    parent: int,
    rate: float,
    stall: float,
    stdin_fd: int,
    on_first: Callable[[], None],
    *,
    clock: Callable[[], float] = time.monotonic,
    read: Callable[[float], bytes | None] | None = None,
    state: Callable[[int], str | None] = process_state,
) -> str:
    """Publish beats at ``rate`` Hz while the parent runs and ticks; return why it ended.
    Beats are scheduled on ``clock`` (monotonic s); ``read(timeout)`` waits at most
    ``timeout`` s for the parent's bytes (None: none came; b"": the pipe closed; default:
    ``stdin_fd``); ``state(pid)`` is the parent's process state letter."""
    read = read or functools.partial(_read_ready, stdin_fd)
    period = 1.0 / rate
    seq, last_tick = 0, clock()
    next_t = last_tick
    while True:
        data = read(max(0.0, next_t - clock()))
        if data is not None:
            if not data:
                return "the parent closed the pipe (exited)"
            if STOP in data:
                return "stopped by the parent"
            last_tick = clock()
        now = clock()
        if now < next_t:
            continue
        next_t = max(next_t + period, now - period)  # behind: do not burst to catch up
        if os.getppid() != parent:
            return "the parent died"
        if state(parent) in ("T", "t") or now - last_tick > stall:
            continue  # stopped or unresponsive parent: silence, until it runs again
        body = {"schema": "beamrelay.heartbeat/1", "t": time.time(), "session": session_id,
                "seq": seq}  # fmt: skip
        put(json.dumps(body).encode())
        if seq == 0:
            on_first()
        seq += 1


def _read_ready(fd: int, timeout: float) -> bytes | None:
    """What ``fd`` holds once readable within ``timeout`` s (b"" at its end), else None."""
    if not select.select([fd], [], [], timeout)[0]:
        return None
    return os.read(fd, 4096)


def main(argv: list[str] | None = None) -> int:
    """The child: ``python -m planner.service.heartbeat --key K --session S --parent PID``."""
    ap = argparse.ArgumentParser(prog="python -m planner.service.heartbeat")
    ap.add_argument("--key", required=True)
    ap.add_argument("--session", required=True)
    ap.add_argument("--parent", type=int, required=True)
    ap.add_argument("--rate", type=float, default=HEARTBEAT_RATE)
    ap.add_argument("--stall", type=float, default=PARENT_STALL)
    ap.add_argument("--connect-timeout", type=float, default=CONNECT_TIMEOUT)
    ap.add_argument("--endpoint")
    ap.add_argument("--zenoh-config", type=Path)
    args = ap.parse_args(argv)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the planner, which stops us
    got = raise_priority()  # before the session's threads start: they inherit it
    if got.policy is not Policy.FIFO:
        log.warning("heartbeat %s", got.note)
    import zenoh

    try:
        bus = BusAddress(args.endpoint, args.zenoh_config)
        session = zenoh.open(child_config(bus, args.connect_timeout))
    except Exception as exc:  # zenoh's ZError, or an InputError of the config
        print(f"heartbeat: cannot open the Zenoh session: {_zenoh_message(exc)}", file=sys.stderr)
        return 2
    pub = session.declare_publisher(args.key, encoding=JSON, **urgent())

    def ready() -> None:
        sys.stdout.write("ready\n")
        sys.stdout.flush()

    try:
        why = beat_loop(pub.put, args.session, args.parent, args.rate, args.stall,
                        sys.stdin.fileno(), ready)  # fmt: skip
    finally:
        pub.undeclare()
        session.close()
    log.info("heartbeat process ends: %s", why)
    return 0


if __name__ == "__main__":
    sys.exit(main())
