"""Trajectory intake: parse and check received trajectories in a worker *process*, so the
robot's control loop never waits on message parsing.

Why a process. Decoding and validating a JointTrajectory is Python work that holds the GIL
for as long as it runs: about 0.5 s for an 8900-sample (3.5 MB) body with pydantic, which
stalled the 500 Hz loop for 60-118 ms at a time when it ran in the Zenoh callback. A
thread would not help (same GIL). Running the control loop itself in another process would
mean moving the backend (RTDE connections, the follower) and its state across a process
boundary; instead the loop stays where it is and only the costly, state-free part moves:
one worker process (``ProcessPoolExecutor(max_workers=1)``, ``spawn`` context, so it never
inherits the Zenoh threads) receives the raw bytes and returns either the ready numpy
arrays (:class:`drivers.trajectory_check.Parsed`; pickling them is a memcpy, ~1 ms for
3.5 MB) or the rejection reason. What stays in the driver process is short: copying the
payload out of Zenoh, handing it to the pool, unpickling the result.

Bounds (only the newest trajectory matters):

- bodies over :data:`planner.bus.MAX_PAYLOAD_BYTES` (4 MiB) are rejected before anything
  else (no copy, no parse);
- at most one body is being parsed and at most one waits; a newer arrival replaces the
  waiting one, which is rejected as superseded (its id is unknown: it was never parsed);
- the results wait in :meth:`TrajectoryIntake.take`'s list until the control loop swaps
  it out (one lock, held for a pointer swap). Rejections carry no arrays, and a parsed
  result exists only for a body that was in flight, so the list stays small.

A worker that dies (killed, out of memory) rejects its body and is replaced; a worker whose
driver died (even by SIGKILL) exits within :data:`ORPHAN_POLL` s.
"""

from __future__ import annotations

import os
import threading
import time
from concurrent.futures import Future, ProcessPoolExecutor
from multiprocessing import get_context
from typing import Any, NamedTuple

import numpy as np

from drivers.follower import Reference
from drivers.trajectory_check import DEFAULT_PERIOD, check_message
from planner.bus import MAX_PAYLOAD_BYTES
from planner.system import Limits

MAX_REASON = 400  # characters of an unexpected error's text kept in a rejection
ORPHAN_POLL = 0.5  # s: how often the worker checks that the driver still runs


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
    """Worker side: ``("ok", id, session, t, q, qd, qdd)`` or ``("rejected", id, reason)``.

    Never raises: any error of any payload becomes a rejection (plain tuples, so nothing
    but numpy arrays and strings crosses the process boundary)."""
    from planner.bus import decode
    from planner.errors import InputError
    from schemas.messages import JointTrajectory

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
    return ("ok", p.id, p.session, r.t, r.q, r.qd, r.qdd)


def _init_worker(parent: int) -> None:
    """Worker start: ignore Ctrl-C (it reaches the whole process group; the driver stops
    the worker) and exit when the driver is gone (a SIGKILLed driver closes no pipe the
    worker would notice: it holds both ends of its call queue)."""
    import os
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(ORPHAN_POLL)
        os._exit(0)

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


def _warm() -> bool:
    """Imports the worker needs, done once at start so the first trajectory is not slow."""
    import schemas.messages  # noqa: F401

    return True


class TrajectoryIntake:
    """Feeds raw trajectory bodies to the worker and collects :class:`Verdict` objects."""

    def __init__(
        self, robot: str, names: tuple[str, ...], limits: Limits, period: float = DEFAULT_PERIOD
    ) -> None:
        self._args = (robot, tuple(names), limits, float(period))
        self._lock = threading.Lock()
        self._done: list[Verdict] = []
        self._busy = False
        self._waiting: tuple[bytes, float] | None = None
        self._pool: ProcessPoolExecutor | None = None
        self._broken = False
        self.n_superseded = 0
        self.n_oversized = 0

    def start(self) -> TrajectoryIntake:
        self._pool = self._new_pool()
        self._pool.submit(_warm).result(timeout=60)
        return self

    def close(self) -> None:
        with self._lock:
            pool, self._pool = self._pool, None
            self._waiting = None
        if pool is not None:
            pool.shutdown(wait=False, cancel_futures=True)

    @staticmethod
    def _new_pool() -> ProcessPoolExecutor:
        return ProcessPoolExecutor(
            max_workers=1,
            mp_context=get_context("spawn"),
            initializer=_init_worker,
            initargs=(os.getpid(),),
        )

    # -- producer side (Zenoh callback thread) ----------------------------------------------
    def submit(self, payload: Any) -> None:
        """Take one received payload (``zenoh.ZBytes`` or bytes); never blocks on parsing."""
        received = time.monotonic()
        size = len(payload)
        if size > MAX_PAYLOAD_BYTES:
            self.n_oversized += 1
            reason = f"body: payload of {size} bytes exceeds {MAX_PAYLOAD_BYTES} bytes"
            self._push(Verdict(received, None, None, None, reason))
            return
        body = payload if isinstance(payload, bytes) else payload.to_bytes()
        with self._lock:
            if self._pool is None:
                return
            if self._busy:
                if self._waiting is not None:
                    self.n_superseded += 1
                    reason = "body: superseded by a newer trajectory before it was checked"
                    self._done.append(Verdict(self._waiting[1], None, None, None, reason))
                self._waiting = (body, received)
                return
            self._busy = True
        self._launch(body, received)

    def _launch(self, body: bytes, received: float) -> None:
        with self._lock:
            if self._broken and self._pool is not None:  # replace a dead worker
                self._pool.shutdown(wait=False, cancel_futures=True)
                self._pool, self._broken = self._new_pool(), False
            pool = self._pool
        if pool is None:
            return
        try:
            fut = pool.submit(parse_in_worker, body, *self._args)
        except RuntimeError:  # pool broken or shut down
            self._finished(Verdict(received, None, None, None, "body: parse worker unavailable"))
            return
        fut.add_done_callback(lambda f: self._on_result(f, received))

    def _on_result(self, fut: Future[tuple[Any, ...]], received: float) -> None:
        try:
            res = fut.result()
        except Exception as exc:  # the worker died (BrokenProcessPool) or was cancelled
            res = ("rejected", None, f"body: parse worker failed: {type(exc).__name__}")
            self._broken = True
        if res[0] == "ok":
            _, msg_id, session, t, q, qd, qdd = res
            ref = Reference(*(np.asarray(a, dtype=float) for a in (t, q, qd, qdd)))
            self._finished(Verdict(received, msg_id, session, ref, None))
        else:
            self._finished(Verdict(received, res[1], None, None, res[2]))

    def _finished(self, verdict: Verdict) -> None:
        with self._lock:
            self._done.append(verdict)
            nxt, self._waiting = self._waiting, None
            self._busy = nxt is not None
        if nxt is not None:
            self._launch(*nxt)

    def _push(self, verdict: Verdict) -> None:
        with self._lock:
            self._done.append(verdict)

    # -- consumer side (control loop) -------------------------------------------------------
    def take(self) -> list[Verdict]:
        """The verdicts since the last call, oldest first (a pointer swap under the lock)."""
        if not self._done:  # unlocked peek: a list's truth value is atomic
            return []
        with self._lock:
            out, self._done = self._done, []
        return out

    @property
    def idle(self) -> bool:
        """Nothing being parsed or waiting (tests and benches)."""
        with self._lock:
            return not self._busy and self._waiting is None
