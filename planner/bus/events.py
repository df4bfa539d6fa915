"""The processes' event log: one line per event, with its UTC time, process and request id.

Every process of the running system (``serve``, ``driver robot|camera``) logs what an
operator needs after the fact -- requests, verdicts, faults, refits and stops -- as
``key=value`` lines on standard error::

    2026-12-02T15:04:05.123Z planner INFO verdict id=r1 solved=3/3 execution=accepted

``up`` keeps each child's standard error in ``<log-dir>/<name>.log`` and, without a
terminal, prints the same lines. Records are formatted and written by a background thread
(a :class:`logging.handlers.QueueListener`), so a control loop that logs only enqueues.
"""

from __future__ import annotations

import atexit
import json
import logging
import logging.handlers
import queue
import sys
import time
from collections.abc import Sequence
from typing import IO, Any, Protocol

from schemas.status import ServoStatus, Status

#: the strftime format of an event's time (UTC); milliseconds and ``Z`` are appended
TIME_FORMAT = "%Y-%m-%dT%H:%M:%S"

_listener: logging.handlers.QueueListener | None = None


class _Formatter(logging.Formatter):
    def formatTime(self, record: logging.LogRecord, datefmt: str | None = None) -> str:
        stamp = time.strftime(TIME_FORMAT, time.gmtime(record.created))
        return f"{stamp}.{int(record.msecs):03d}Z"


def configure(process: str, stream: IO[str] | None = None, level: int = logging.INFO) -> None:
    """Send every ``beamrelay.*`` record of this process, INFO and above, to ``stream``
    (default standard error) as one line: time, ``process``, level, message. Idempotent."""
    global _listener
    if _listener is not None:
        return
    handler = logging.StreamHandler(stream or sys.stderr)
    handler.setFormatter(_Formatter(f"%(asctime)s {process} %(levelname)s %(message)s"))
    records: queue.Queue[logging.LogRecord] = queue.Queue(-1)
    _listener = logging.handlers.QueueListener(records, handler)
    _listener.start()
    atexit.register(stop)
    root = logging.getLogger("beamrelay")
    root.addHandler(logging.handlers.QueueHandler(records))
    root.setLevel(level)
    root.propagate = False


def stop() -> None:
    """Write the queued records and stop the writer thread (at exit; idempotent)."""
    global _listener
    if _listener is not None:
        _listener.stop()
        _listener = None


def field(value: object) -> str:
    """One ``key=value`` value: numbers and plain words as they are, anything with spaces,
    quotes or ``=`` as a JSON string, None as ``-``."""
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return f"{value:.6g}"
    text = str(value)
    if not text or any(c in text for c in ' "=\n\t'):
        return json.dumps(text)
    return text


def event(log: logging.Logger, what: str, level: int = logging.INFO, /, **fields: object) -> None:
    """Log one event line ``what key=value ...`` (the request id as ``id=``)."""
    if log.isEnabledFor(level):
        log.log(level, "%s %s", what, " ".join(f"{k}={field(v)}" for k, v in fields.items()))


def request_fields(req: object) -> dict[str, object]:
    """The figures of a TargetRequest (:class:`schemas.messages.TargetRequest`) an event
    names: id, mode, number of targets, execute, closed loop, frame."""
    points = getattr(req, "points", None) or []
    return {"id": getattr(req, "id", None), "mode": getattr(req, "mode", None),
            "targets": len(points), "execute": getattr(req, "execute", False),
            "closed_loop": getattr(req, "closed_loop", False),
            "frame": getattr(req, "frame", None)}  # fmt: skip


class Planned(Protocol):
    """What :func:`verdict_fields` reads of a plan (:class:`planner.io.plan.Plan`, which the
    bus does not import): its request id, its solutions' ``status`` and ``reason``, the
    execution verdict and reason, the closed-loop report's rows' ``status``."""

    @property
    def id(self) -> str | None: ...
    @property
    def solutions(self) -> Sequence[Any]: ...
    @property
    def execution(self) -> str | None: ...
    @property
    def execution_reason(self) -> str | None: ...
    @property
    def closed_loop(self) -> Any: ...


def verdict_fields(plan: Planned) -> dict[str, object]:
    """The verdict of a planned (and maybe executed) request: id, solved/targets, failure
    reasons with counts, execution verdict and reason, closed-loop convergence."""
    sols = plan.solutions
    reasons: dict[str, int] = {}
    for s in sols:
        if s.status is not Status.OK:
            reasons[str(s.reason)] = reasons.get(str(s.reason), 0) + 1
    out: dict[str, object] = {"id": plan.id,
                              "solved": f"{len(sols) - sum(reasons.values())}/{len(sols)}"}  # fmt: skip
    if reasons:
        out["failed"] = ",".join(f"{k}:{n}" for k, n in sorted(reasons.items()))
    if plan.execution is not None:
        out["execution"] = plan.execution
        if plan.execution_reason:
            out["execution_reason"] = plan.execution_reason
    rows = () if plan.closed_loop is None else plan.closed_loop.targets
    if rows:
        converged = sum(r.status is ServoStatus.CONVERGED for r in rows)
        out["converged"] = f"{converged}/{len(rows)}"
    return out


def stop_fields(sample: object) -> dict[str, object]:
    """Who sent a ``<prefix>/stop`` sample and why (its StopMessage body, when it is one;
    a stop is obeyed whatever it carries)."""
    try:
        body = json.loads(sample.payload.to_bytes())  # type: ignore[attr-defined]
    except (AttributeError, ValueError, UnicodeDecodeError):
        body = None
    if not isinstance(body, dict):
        return {"source": None, "reason": "(no StopMessage body)"}
    return {"source": body.get("source"), "reason": body.get("reason")}
