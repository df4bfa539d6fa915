"""Trajectory intake: parse and check received trajectories in a worker *process*, so the
robot's control loop never waits on message parsing.

Why a process. Decoding and validating a JointTrajectory is Python work that holds the GIL
for as long as it runs: about 0.5 s for an 8900-sample (3.6 MB) body with pydantic. Done
in the Zenoh callback it stalled the 500 Hz loop for 60-145 ms at a time; a thread would
not help (same GIL). Running the control loop itself in another process would mean moving
the backend (RTDE connections, the follower) and its state across a process boundary;
instead the loop stays where it is and only the costly, state-free part moves out.

How. One worker process (``python -c 'from drivers.robot.intake import worker_main; ...'``, its
own session so Ctrl-C goes to the driver only, at nice :data:`WORKER_NICE`: below the
control loop, which runs at real-time priority or a lower nice value, and above the
machine's ordinary work, so a busy machine does not hold a verdict past the planner's
wait) reads length-prefixed bodies on its stdin and answers each with a pickled tuple
on its stdout: the ready numpy arrays of a :class:`drivers.robot.trajectory_check.Parsed`
(unpickling them is a memcpy, ~1 ms for 3.6 MB) or the rejection reason. A feeder thread
of the driver writes the body and waits for the answer; both block in system calls, which
release the GIL. The Zenoh callback only copies the payload and hands it over. The worker
exits when its stdin closes, i.e. when the driver exits or dies (even by SIGKILL); a
worker that dies rejects its body and is restarted.

Bounds (only the newest trajectory matters):

- bodies over :data:`planner.bus.session.MAX_PAYLOAD_BYTES` (4 MiB) are rejected before anything
  else (no copy, no parse);
- at most one body is being parsed and at most one waits; a newer arrival replaces the
  waiting one, which is rejected as superseded (its id is unknown: it was never parsed);
- the results wait in :meth:`TrajectoryIntake.take`'s list until the control loop swaps
  it out (one lock, held for a pointer swap). A parsed result exists only for a body that
  was in flight, so the list stays small.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import IO, Any, NamedTuple

import numpy as np

import schemas.messages  # noqa: F401  (imports done before "ready")
from drivers.robot.follower import Reference
from drivers.robot.outbox import Outbox
from drivers.robot.trajectory_check import DEFAULT_PERIOD, check_message
from planner.bus.session import MAX_PAYLOAD_BYTES, decode
from planner.errors import InputError
from planner.model.system import Limits
from schemas.messages import JointTrajectory

MAX_REASON = 400  # characters of an unexpected error's text kept in a rejection
#: the parse worker's nice value (0 default, -20 highest; the control loop asks -10 when it
#: cannot have SCHED_FIFO); kept as it was when raising is not permitted
WORKER_NICE = -5
START_TIMEOUT = 60.0  # s: longest wait for the worker's first "ready"
_HEADER = struct.Struct("<Q")  # frame length, bytes


class Verdict(NamedTuple):
    """Outcome of the state-free checks of one received body.

    ``received`` is the monotonic time (s) the body reached the driver; ``reference`` is
    None when ``reason`` says why it was rejected."""

    received: float
    id: str | None
    session: str | None
    reference: Reference | None
    reason: str | None


def parse_in_worker(
    body: bytes, robot: str, names: tuple[str, ...], limits: Limits, period: float
) -> tuple[Any, ...]:
    """Worker side: ``("ok", id, session, t, q, qd, qdd, laser_on, aim_on)`` or ``("rejected", id,
    reason)``.

    Never raises: any error of any payload becomes a rejection (plain tuples of numpy
    arrays and strings cross the process boundary)."""

    msg_id: str | None = None
    try:
        msg = decode(body, JointTrajectory)
        msg_id = msg.id
        p = check_message(msg, robot, names, limits, period)
    except InputError as exc:
        return ("rejected", msg_id, str(exc))
    except Exception as exc:  # hostile payloads: 5000-digit integers, 1e400, ...
        return ("rejected", msg_id, f"body: {type(exc).__name__}: {str(exc)[:MAX_REASON]}")
    r = p.reference
    return ("ok", p.id, p.session, r.t, r.q, r.qd, r.qdd, r.laser_on, r.aim_on)


def _read_frame(stream: IO[bytes]) -> bytes | None:
    head = stream.read(_HEADER.size)
    if len(head) < _HEADER.size:
        return None
    (n,) = _HEADER.unpack(head)
    data = stream.read(n)
    return data if len(data) == n else None


def _write_frame(stream: IO[bytes], data: bytes) -> None:
    stream.write(_HEADER.pack(len(data)))
    stream.write(data)
    stream.flush()


def worker_main() -> None:
    """The worker process: first frame = pickled ``(robot, names, limits, period)``, then
    one answer per body frame, until stdin closes."""
    with contextlib.suppress(OSError):  # not permitted: run at the inherited nice value
        if os.getpriority(os.PRIO_PROCESS, 0) > WORKER_NICE:
            os.setpriority(os.PRIO_PROCESS, 0, WORKER_NICE)
    inp, out = sys.stdin.buffer, sys.stdout.buffer
    setup = _read_frame(inp)
    if setup is None:
        return
    args = pickle.loads(setup)

    _write_frame(out, b"ready")
    while (body := _read_frame(inp)) is not None:
        _write_frame(out, pickle.dumps(parse_in_worker(body, *args), protocol=5))


class _Worker:
    """One worker process and its pipes (used by the feeder thread only)."""

    def __init__(self, args: tuple[Any, ...]) -> None:
        root = str(Path(__file__).resolve().parents[1])
        path = os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH", "")) if p)
        self.proc = subprocess.Popen(
            [sys.executable, "-c", "from drivers.robot.intake import worker_main; worker_main()"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, start_new_session=True,
            env=dict(os.environ, PYTHONPATH=path),
        )  # fmt: skip
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.stdin, self.stdout = self.proc.stdin, self.proc.stdout
        _write_frame(self.stdin, pickle.dumps(args))
        if _read_frame(self.stdout) != b"ready":
            self.close()
            raise RuntimeError("the trajectory parse worker did not start")

    def parse(self, body: bytes) -> tuple[Any, ...]:
        """The worker's answer; OSError/EOFError when it died."""
        _write_frame(self.stdin, body)
        data = _read_frame(self.stdout)
        if data is None:
            raise EOFError("parse worker exited")
        res: tuple[Any, ...] = pickle.loads(data)
        return res

    def close(self) -> None:
        for s in (self.stdin, self.stdout):
            with contextlib.suppress(OSError):
                s.close()
        try:
            self.proc.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


class TrajectoryIntake:
    """Feeds raw trajectory bodies to the worker and collects :class:`Verdict` objects."""

    def __init__(
        self, robot: str, names: tuple[str, ...], limits: Limits, period: float = DEFAULT_PERIOD
    ) -> None:
        self._args = (robot, tuple(names), limits, float(period))
        self._lock = threading.Lock()
        self._wake = threading.Condition(self._lock)
        self._done: Outbox[Verdict] = Outbox(self._lock)
        self._waiting: tuple[bytes, float] | None = None
        self._busy = False
        self._closed = False
        self._worker: _Worker | None = None
        self._thread = threading.Thread(target=self._feed, name="trajectory-intake", daemon=True)
        self.n_received = 0
        self.n_superseded = 0
        self.n_oversized = 0
        self.n_restarts = 0

    def start(self) -> TrajectoryIntake:
        self._worker = _Worker(self._args)
        self._thread.start()
        return self

    def close(self) -> None:
        with self._lock:
            self._closed = True
            self._waiting = None
            self._wake.notify_all()
        self._thread.join(timeout=5.0)
        if self._worker is not None:
            self._worker.close()

    # -- producer side (Zenoh callback thread) ----------------------------------------------
    def submit(self, payload: Any) -> None:
        """Take one received payload (``zenoh.ZBytes`` or bytes); never blocks on parsing."""
        received = time.monotonic()
        self.n_received += 1
        size = len(payload)
        if size > MAX_PAYLOAD_BYTES:
            self.n_oversized += 1
            reason = f"body: payload of {size} bytes exceeds {MAX_PAYLOAD_BYTES} bytes"
            with self._lock:
                self._done.items.append(Verdict(received, None, None, None, reason))
            return
        body = payload if isinstance(payload, bytes) else payload.to_bytes()
        with self._lock:
            if self._waiting is not None:
                self.n_superseded += 1
                reason = "body: superseded by a newer trajectory before it was checked"
                self._done.items.append(Verdict(self._waiting[1], None, None, None, reason))
            self._waiting = (body, received)
            self._wake.notify()

    # -- feeder thread ------------------------------------------------------------------------
    def _feed(self) -> None:
        while True:
            with self._lock:
                while self._waiting is None and not self._closed:
                    self._wake.wait()
                if self._closed:
                    return
                assert self._waiting is not None
                (body, received), self._waiting = self._waiting, None
                self._busy = True
            verdict = self._parse(body, received)
            with self._lock:
                self._done.items.append(verdict)
                self._busy = False

    def _parse(self, body: bytes, received: float) -> Verdict:
        try:
            if self._worker is None:  # it died on an earlier body: start a new one
                self._worker = _Worker(self._args)
                self.n_restarts += 1
            res = self._worker.parse(body)
        except (OSError, EOFError, RuntimeError, pickle.UnpicklingError) as exc:
            res = ("rejected", None, f"body: parse worker failed ({exc}); restarting it")
            if self._worker is not None:
                self._worker.close()
            self._worker = None
        if res[0] == "ok":
            _, msg_id, session, t, q, qd, qdd, laser, aim = res
            t, q, qd, qdd = (np.asarray(a, dtype=float) for a in (t, q, qd, qdd))
            gate, aim = (None if v is None else np.asarray(v, dtype=float) for v in (laser, aim))
            ref = Reference(t, q, qd, qdd, gate, aim)
            return Verdict(received, msg_id, session, ref, None)
        return Verdict(received, res[1], None, None, res[2])

    # -- consumer side (control loop) -------------------------------------------------------
    def take(self) -> list[Verdict]:
        """The verdicts since the last call, oldest first (:meth:`Outbox.take`)."""
        return self._done.take()

    @property
    def idle(self) -> bool:
        """Nothing being parsed or waiting (tests and benches)."""
        with self._lock:
            return not self._busy and self._waiting is None
