"""The planner node's guards: a job queue bounded in count and bytes, the worker thread that
serves it, the worker's progress watchdog, and the heartbeat thread (no Zenoh imports: the
publisher and the reply are passed in).

The heartbeat (:class:`~schemas.messages.Heartbeat` ``{t, session, seq}``, default 100 Hz)
is what robot drivers follow while they move: when it stops for 100 ms they brake. It stops
when the process stops (killed, SIGSTOPped) and also when the worker has been busy on one
request beyond its allowance (:class:`Progress`): a wedged planner must not keep arms moving.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from planner.bus.session import MAX_PAYLOAD_BYTES, encode
from planner.errors import BeamrelayError, InputError
from schemas import defaults
from schemas.messages import Heartbeat as HeartbeatMessage

log = logging.getLogger("beamrelay.node")

#: requests waiting for the worker beyond this many get a "busy" error reply
QUEUE_SIZE = 64
#: ... or beyond this many bytes of request bodies in total
QUEUE_BYTES = 32 * 1024 * 1024
#: a request may keep the worker busy this long (s) ...
WORKER_TIMEOUT = 30.0
#: ... plus this long per target (s), before the planner counts as wedged
WORKER_TIMEOUT_PER_TARGET = 0.02


@dataclass(frozen=True)
class Job:
    """One request body to serve: ``kind`` is ``query`` (reply to ``query``) or ``topic``."""

    kind: str
    query: Any
    payload: bytes


class JobQueue:
    """FIFO of :class:`Job` bounded by count and by total payload bytes; thread safe."""

    def __init__(self, max_jobs: int = QUEUE_SIZE, max_bytes: int = QUEUE_BYTES) -> None:
        self.max_jobs = max_jobs
        self.max_bytes = max_bytes
        self._jobs: deque[Job | None] = deque()
        self._bytes = 0
        self._cond = threading.Condition()

    def put(self, job: Job) -> str | None:
        """Queue ``job``; None, or why it was refused (the queue is full)."""
        with self._cond:
            if len(self._jobs) >= self.max_jobs:
                return f"{len(self._jobs)} requests waiting"
            if self._bytes + len(job.payload) > self.max_bytes:
                return (
                    f"{self._bytes} bytes of requests waiting, {len(job.payload)} more "
                    f"would exceed {self.max_bytes}"
                )
            self._jobs.append(job)
            self._bytes += len(job.payload)
            self._cond.notify()
        return None

    def close(self) -> None:
        """Wake the consumer with the end marker (after the jobs already queued)."""
        with self._cond:
            self._jobs.append(None)
            self._cond.notify()

    def get(self) -> Job | None:
        """The next job (blocks); None once closed."""
        with self._cond:
            while not self._jobs:
                self._cond.wait()
            job = self._jobs.popleft()
            if job is not None:
                self._bytes -= len(job.payload)
            return job

    @property
    def nbytes(self) -> int:
        with self._cond:
            return self._bytes


class Worker:
    """The one thread that serves the node's jobs in order: ``serve(payload)`` -> the reply
    body, sent with ``respond(job, body, None)``; any Exception becomes an error reply
    (``respond(job, None, exc)``); ``progress`` spans each job. ``first()``, when given,
    runs on the thread before the first job (jobs queue meanwhile), spanned by ``progress``
    as a job is. ``on_exit()`` is called
    when the thread ends, whether by :meth:`close` or not."""

    def __init__(
        self,
        serve: Callable[[bytes], bytes],
        respond: Callable[[Job, bytes | None, Exception | None], None],
        progress: Progress,
        on_exit: Callable[[], None],
        first: Callable[[], None] | None = None,
    ) -> None:
        self.serve, self.respond, self.progress, self.on_exit = serve, respond, progress, on_exit
        self.first = first
        self.jobs = JobQueue()
        self._thread = threading.Thread(target=self._work, name="planner-worker", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def is_alive(self) -> bool:
        return self._thread.is_alive()

    def close(self, timeout: float) -> None:
        """Serve the jobs already queued, then end (wait at most ``timeout`` s)."""
        self.jobs.close()
        self._thread.join(timeout=timeout)

    def take(self, kind: str, query: Any, payload: Any) -> None:
        """Queue the body ``payload`` (Zenoh bytes, or None: empty) of a ``query`` or of a
        sample (``kind`` ``topic``); one over ``MAX_PAYLOAD_BYTES`` is refused before it is
        copied out of Zenoh."""
        size = 0 if payload is None else len(payload)
        if size > MAX_PAYLOAD_BYTES:
            self.refuse(Job(kind, query, b""), InputError(f"body of {size} bytes exceeds the "
                        f"limit of {MAX_PAYLOAD_BYTES} bytes (not read)", "body"))  # fmt: skip
            return
        self.submit(Job(kind, query, b"" if payload is None else payload.to_bytes()))

    def submit(self, job: Job) -> None:
        """Queue ``job``, or refuse it with a "busy" error when the queue is full."""
        full = self.jobs.put(job)
        if full is not None:
            self.refuse(job, InputError(f"planner busy ({full}), retry later", "body"))

    def refuse(self, job: Job, exc: Exception) -> None:
        """Reply to ``job`` with the error ``exc`` (from a Zenoh callback: never raises)."""
        try:
            self.respond(job, None, exc)
        except Exception:  # a vanished querier must not break the Zenoh callback
            log.exception("could not send an error reply")

    def _work(self) -> None:
        try:
            if self.first is not None:
                self.progress.begin()  # a wedged warm-up is a wedged worker, as a job's is
                try:
                    self.first()
                except Exception:  # a warm-up must not kill the node
                    log.exception("the worker's first task failed")
                finally:
                    self.progress.end()
            while (job := self.jobs.get()) is not None:
                self._run(job)
        finally:
            self.on_exit()

    def _run(self, job: Job) -> None:
        """Serve one job and reply; any Exception becomes an error reply."""
        self.progress.begin()
        try:
            body: bytes | None = None
            err: Exception | None = None
            try:
                body = self.serve(job.payload)
            except BeamrelayError as exc:
                err = exc
            except Exception as exc:  # a bug must not kill the node: report it, keep serving
                log.exception("request failed")
                err = exc
            try:
                self.respond(job, body, err)
            except Exception:  # the querier left, the session closes: nothing to reply to
                log.exception("could not send the reply")
        finally:
            self.progress.end()


class Progress:
    """The worker's progress watchdog: when the current job started and its allowance (s,
    on ``clock``, monotonic)."""

    def __init__(
        self,
        timeout: float = WORKER_TIMEOUT,
        per_target: float = WORKER_TIMEOUT_PER_TARGET,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.clock = clock
        self.timeout = timeout
        self.per_target = per_target
        self._since: float | None = None
        self._allowance = 0.0
        self._lock = threading.Lock()

    def begin(self) -> None:
        with self._lock:
            self._since, self._allowance = self.clock(), self.timeout

    def targets(self, n: int) -> None:
        """The current job plans ``n`` targets: extend its allowance accordingly."""
        with self._lock:
            self._allowance = self.timeout + self.per_target * n

    def tick(self) -> None:
        """The current job made progress (a closed-loop execution moved or measured): its
        allowance starts again from now (a long execution is not a wedge; one that stops
        ticking for the allowance still is)."""
        with self._lock:
            if self._since is not None:
                self._since = self.clock()

    def end(self) -> None:
        with self._lock:
            self._since = None

    def overdue(self) -> str | None:
        """Why the worker counts as wedged, or None."""
        with self._lock:
            since, allowance = self._since, self._allowance
        if since is None:
            return None
        busy = self.clock() - since
        if busy <= allowance:
            return None
        return f"worker busy on one request for {busy:.1f} s (allowed {allowance:.1f} s)"


class Heartbeat:
    """Publishes ``{t, session, seq}`` at ``rate`` Hz from its own thread until stopped, or
    until ``progress`` reports a wedged worker: then it stops beating and calls
    ``on_wedged(reason)`` once. Beats are scheduled on ``clock`` (monotonic s) and the thread
    waits with ``wait(s)`` (True: stop now; default: the stop event's wait)."""

    def __init__(
        self,
        put: Callable[[bytes], None],
        session_id: str,
        progress: Progress,
        on_wedged: Callable[[str], None],
        rate: float = defaults.HEARTBEAT_RATE_HZ,
        clock: Callable[[], float] = time.monotonic,
        wait: Callable[[float], bool] | None = None,
    ) -> None:
        self.put = put
        self.clock = clock
        self.session_id = session_id
        self.progress = progress
        self.on_wedged = on_wedged
        self.period = 1.0 / rate
        self.seq = 0
        self._stop = threading.Event()
        self.wait = self._stop.wait if wait is None else wait
        self._thread = threading.Thread(target=self._run, name="planner-heartbeat", daemon=True)

    def start(self) -> Heartbeat:
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop beating (idempotent, callable from any thread)."""
        self._stop.set()
        if threading.current_thread() is not self._thread and self._thread.is_alive():
            self._thread.join(timeout=2)

    def _run(self) -> None:

        next_t = self.clock()
        while not self._stop.is_set():
            reason = self.progress.overdue()
            if reason is not None:
                self._stop.set()
                self.on_wedged(reason)
                return
            msg = HeartbeatMessage(t=time.time(), session=self.session_id, seq=self.seq)
            try:
                self.put(encode(msg))
            except Exception:  # a closed publisher while shutting down: stop quietly
                log.exception("heartbeat publish failed")
                return
            self.seq += 1
            next_t += self.period
            now = self.clock()
            if next_t < now - self.period:
                next_t = now  # fell behind (a loaded machine): do not burst to catch up
            if self.wait(max(0.0, next_t - now)):
                return
