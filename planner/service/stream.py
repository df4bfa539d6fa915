"""Executing a plan's trajectory on the robot drivers, in chunks when it is large (no Zenoh).

A message body may hold at most :data:`~planner.bus.session.MAX_PAYLOAD_BYTES` (4 MiB), about
13,000 samples of one robot: a long path or a large batch of targets makes a longer
trajectory (the 1000 targets of the paper's grid: 52,707 samples, 16.7 MB). It is split into
chunks of at most :data:`CHUNK_BYTES`, each a complete JointTrajectory whose first sample is
the previous chunk's last (times from 0 in each), with the id ``<request id>#<k>/<n>`` and the
planner's session. Chunks end where every robot rests (on a target): a driver joins a queued
trajectory with an approach from the state where the running one ended, which is no motion
only from rest; a trajectory that moves too long without a stop to fit is refused with the
figures. A driver queues at most one trajectory behind the one it plays (it must start
where that one ends, and starts when it ends), so the chunks are streamed: chunk 1, then
chunk 2 (queued), then chunk k + 1 once chunk k plays (halfway through it,
:data:`START_LEAD`, timed from the plan and the moment chunk 1 started), so that at most
one is ever queued.

:class:`Execution` does this for the planner node: the reply's ``execution`` is the verdict
on the first chunks (``accepted`` once chunk 1 and chunk 2 are accepted by every driver);
later chunks are sent from a thread, and a later rejection, or a driver's silence, is logged
and answered with a stop on the bus. While chunks remain to be sent (until the last one has
started), another execution is refused (it would replace the queued chunk).
"""

from __future__ import annotations

import itertools
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from planner.bus.bodies import encode_json
from planner.bus.ids import base_id, chunk_id
from planner.io.plan import Plan, Verdict
from planner.service.emission import emission_excess
from planner.service.execution import (
    AckBoard,
    ExecuteError,
    MotionTracks,
    execution_verdict,
)
from schemas.messages import TRAJECTORY_SCHEMA, JointTrajectory

log = logging.getLogger("beamrelay.node")

#: largest body (bytes) of one trajectory chunk: under the 4 MiB limit with room to spare
CHUNK_BYTES = 3 * 1024 * 1024
#: the next chunk is sent when this fraction of the running one has played (by the clock):
#: a driver that runs late or early by up to half a chunk (seconds, for a full chunk) still
#: finds it queued behind the chunk it plays
START_LEAD = 0.5
#: extra time (s per whole MiB of body) a driver may take for its verdict (it parses it)
PARSE_ALLOWANCE = 0.5


@dataclass(frozen=True)
class Chunk:
    """One JointTrajectory body per robot covering ``[t0, t0 + duration]`` s of the plan's
    trajectory; ``nbytes`` is its largest body."""

    id: str | None
    bodies: dict[str, bytes]
    t0: float
    duration: float

    @property
    def nbytes(self) -> int:
        return max(len(b) for b in self.bodies.values())


def split_trajectory(
    plan: Plan,
    request_id: str | None,
    session: str | None,
    max_bytes: int | None = CHUNK_BYTES,
    at_rest_only: bool = True,
) -> list[Chunk]:
    """The plan's ``trajectory`` as chunks of at most ``max_bytes`` per body (one chunk,
    id = the request id, when it fits or ``max_bytes`` is None). Chunk k + 1 starts with
    chunk k's last sample, chosen (``at_rest_only``) where every robot rests (qd = qdd = 0,
    e.g. on a target): a driver joins a queued trajectory by an approach from the state
    where the running one ends, which is no motion only from rest. ExecuteError when no
    such split keeps every chunk under ``max_bytes``."""
    t, rows = _samples(plan)
    make = _chunk_maker(plan, t, rows, session)
    whole = make(request_id, 0, len(t))
    if max_bytes is None or whole.nbytes <= max_bytes:
        return [whole]
    budget = int(0.97 * max_bytes * len(t) / whole.nbytes)  # samples per chunk, about
    rest = np.ones(len(t), dtype=bool)
    if at_rest_only:
        for r in rows.values():
            rest &= (np.abs(r["qd"]).max(axis=1) <= REST) & (np.abs(r["qdd"]).max(axis=1) <= REST)
    candidates = np.flatnonzero(rest[1:-1]) + 1
    while budget >= 2:
        edges = split_edges(candidates, len(t), budget)
        if edges is None:
            break
        n = len(edges) - 1
        chunks = [make(chunk_id(request_id or "trajectory", k + 1, n), a, b + 1)
                  for k, (a, b) in enumerate(itertools.pairwise(edges))]  # fmt: skip
        if all(c.nbytes <= max_bytes for c in chunks):
            return chunks
        budget = int(0.9 * budget)
    stops = np.concatenate([[0], candidates, [len(t) - 1]])
    longest = float(np.max(np.diff(t[stops])))
    raise ExecuteError(
        f"the trajectory ({whole.nbytes} bytes per robot, {t[-1] - t[0]:.1f} s) exceeds the "
        f"{max_bytes}-byte message size and cannot be split where the robots rest: they "
        f"move for {longest:.1f} s without a stop, a message holds about "
        f"{budget * (t[-1] - t[0]) / len(t):.1f} s; send shorter requests",
        list(rows),
    )


#: joint speed (rad/s) and acceleration (rad/s^2) below which a sample counts as at rest
REST = 1e-9


def trajectory_messages(
    plan: Plan, request_id: str | None = None, session: str | None = None
) -> dict[str, bytes]:
    """One JointTrajectory body per robot from a plan's ``trajectory`` (times from 0),
    carrying the request id and the planner session (the ``laser.gate`` robot also gets
    the ``laser_on`` intervals), whatever its size (see
    :func:`planner.service.stream.split_trajectory` for chunks under the body limit)."""
    return split_trajectory(plan, request_id, session, max_bytes=None)[0].bodies


def split_edges(candidates: Any, n_samples: int, budget: int) -> list[int] | None:
    """Sample indices ``[0, e1, ..., n_samples - 1]`` splitting ``n_samples`` samples into
    chunks of at most ``budget`` + 1 samples (consecutive chunks share their edge sample),
    edges taken from ``candidates`` (sorted) and as even as they allow; None if impossible."""
    last = n_samples - 1
    n_min = int(np.ceil(last / budget))
    for n in range(n_min, n_min + 8):  # balanced: each edge nearest its even share
        edges = [0]
        for i in range(1, n):
            near = candidates[(candidates > edges[-1]) & (candidates <= edges[-1] + budget)]
            if near.size == 0:
                break
            edges.append(int(near[np.argmin(np.abs(near - i * last / n))]))
        else:
            if last - edges[-1] <= budget:
                return [*edges, last]
    edges = [0]  # greedy: each chunk as long as it may be
    while last - edges[-1] > budget:
        near = candidates[(candidates > edges[-1]) & (candidates <= edges[-1] + budget)]
        if near.size == 0:
            return None
        edges.append(int(near[-1]))
    return [*edges, last]


def _samples(plan: Plan) -> tuple[Any, dict[str, dict[str, Any]]]:
    """The trajectory's times (s) and per robot q, qd, qdd rows, repeated times dropped."""
    traj = plan.trajectory
    if traj is None or not len(traj.t):
        raise ExecuteError("the plan has no trajectory to execute", list(plan.robots))
    t = traj.t
    keep = np.concatenate([[True], np.diff(t) > 0])  # drivers require increasing times
    rows = {robot: {"q": traj.q[robot][keep], "qd": traj.qd[robot][keep],
                    "qdd": traj.qdd[robot][keep]} for robot in plan.robots}  # fmt: skip
    return t[keep], rows


def _chunk_maker(
    plan: Plan, t: Any, rows: dict[str, dict[str, Any]], session: str | None
) -> Callable[[str | None, int, int], Chunk]:

    laser = plan.resolved.laser
    gate = None if laser is None else laser.gate
    assert plan.trajectory is not None  # _samples said so
    laser_on, aim_on = ([(float(a), float(b)) for a, b in ([] if x is None else x)]
                        for x in (plan.trajectory.laser_on, plan.trajectory.aim_on))  # fmt: skip

    def body(robot: str, cid: str | None, a: int, b: int) -> bytes:
        msg = {"schema": TRAJECTORY_SCHEMA, "robot": robot, "id": cid, "session": session,
               "t": (t[a:b] - t[a]).tolist(), "names": list(plan.joint_names[robot]),
               **{k: v[a:b].tolist() for k, v in rows[robot].items()}}  # fmt: skip
        if gate is not None and robot == gate.robot:  # its digital output switches the laser
            msg["laser_on"] = _clip_intervals(laser_on, float(t[a]), float(t[b - 1]))
            if aim_on:  # the aiming beam of a measurement (same driver, its own output)
                msg["aim_on"] = _clip_intervals(aim_on, float(t[a]), float(t[b - 1]))
        JointTrajectory.model_validate(msg)  # the driver's contract, checked before sending
        return encode_json(msg)

    def make(cid: str | None, a: int, b: int) -> Chunk:
        """Samples a..b-1 as one chunk."""
        bodies = {robot: body(robot, cid, a, b) for robot in rows}
        return Chunk(cid, bodies, float(t[a] - t[0]), float(t[b - 1] - t[a]))

    return make


def _clip_intervals(
    intervals: list[tuple[float, float]], t0: float, t1: float
) -> list[list[float]]:
    """Laser-on intervals (s, plan time) inside ``[t0, t1]``, in chunk time (from ``t0``)."""
    out = []
    for a, b in intervals:
        lo, hi = max(a, t0), min(b, t1)
        if hi > lo:
            out.append([lo - t0, hi - t0])
    return out


class Execution:
    """Sends trajectories to the drivers and collects their verdicts, for one node.

    ``publish(robot, body)`` puts a body on the robot's trajectory key, ``send_stop(reason)``
    publishes a stop; verdicts arrive through ``acks`` (fed from the drivers' status).
    """

    def __init__(
        self,
        robots: tuple[str, ...],
        publish: Callable[[str, bytes], None],
        send_stop: Callable[[str], None],
        acks: AckBoard,
        tracks: MotionTracks,
        ack_timeout: float,
        chunk_bytes: int = CHUNK_BYTES,
    ) -> None:
        self.robots = robots
        self.publish = publish
        self.send_stop = send_stop
        self.acks = acks
        self.tracks = tracks
        self.ack_timeout = ack_timeout
        self.chunk_bytes = chunk_bytes
        self._stream: _Stream | None = None
        self._lock = threading.Lock()

    def busy(self) -> str | None:
        """Why another execution must wait (chunks still to be sent), or None."""
        with self._lock:
            stream = self._stream
        return None if stream is None or stream.done.is_set() else stream.describe()

    def execute(self, plan: Plan, request_id: str, session: str | None) -> Plan:
        """Send the plan's trajectory (chunked if needed), wait for the verdicts on its first
        chunks; the plan with its ``execution`` verdict and ``execution_reason``."""

        traj = plan.trajectory
        laser_on = [] if traj is None else traj.laser_on.tolist()
        laser = plan.resolved.laser
        over = None if laser is None else emission_excess(laser_on, laser.power, laser.limits)
        if over is not None:  # never sent: the gate's driver would cut it short
            return replace(plan, execution=Verdict.REJECTED, execution_reason=f"not sent: {over}")
        chunks = split_trajectory(plan, request_id, session, self.chunk_bytes)
        assert traj is not None  # split_trajectory said so
        total = traj.duration
        moving: set[str] = set()
        begin = time.monotonic()
        verdict, reason = Verdict.ACCEPTED, None
        silent: set[str] = set()  # robots that did not answer: they may still accept
        for k, chunk in enumerate(chunks[:2]):
            acks, timeout = self.send(chunk)
            moving |= {r for r, a in acks.items() if a is not None and a.accepted}
            silent |= {r for r, a in acks.items() if a is None}
            verdict, reason = execution_verdict(acks, timeout)
            if k == 0:
                for robot in moving:
                    begin = self.tracks.accepted(robot, request_id, traj.q[robot][-1], total)
            if verdict is not Verdict.ACCEPTED:
                if len(chunks) > 1:
                    reason = f"chunk {k + 1}/{len(chunks)}: {reason}"
                break
        if verdict is Verdict.REJECTED and moving:
            reason = f"{reason}; stopped {', '.join(sorted(moving))}: the robots move only together"
            self.send_stop(f"request {request_id}: {reason}")
        elif verdict is Verdict.REJECTED and silent:  # a late acceptance must not move the arm
            reason = f"{reason}; stop sent, so a late acceptance does not move"
            self.send_stop(f"request {request_id}: {reason}")
        unanswered = None
        if verdict is Verdict.REJECTED and silent:  # no verdict heard: not known to be refused
            unanswered = tuple(sorted(silent))
        elif len(chunks) > 1:
            with self._lock:
                self._stream = _Stream(self, request_id, chunks, begin).start()
        return replace(plan, execution=verdict, execution_reason=reason,
                       execution_unanswered=unanswered,
                       execution_chunks=len(chunks) if len(chunks) > 1 else None)  # fmt: skip

    def send(self, chunk: Chunk) -> tuple[dict[str, Any], float]:
        """Publish one chunk to every robot; ({robot: verdict or None}, the timeout used)."""
        timeout = self.ack_timeout + PARSE_ALLOWANCE * (chunk.nbytes // 2**20)
        self.acks.expect(list(chunk.bodies), chunk.id)
        for robot, body in chunk.bodies.items():
            self.publish(robot, body)
        return self.acks.wait(timeout), timeout

    def cancel(self, reason: str, trajectory_id: str | None = None) -> None:
        """Send no more chunks (a stop on the bus, a robot halted while it played
        ``trajectory_id``: only a stream of that request is cancelled then)."""
        with self._lock:
            stream = self._stream
        if stream is not None and (trajectory_id is None or stream.owns(trajectory_id)):
            stream.cancel(reason)

    def close(self) -> None:
        self.cancel("the planner node is closing")
        with self._lock:
            stream = self._stream
        if stream is not None:
            stream.join()


class _Stream:
    """The thread sending chunks 3..n of one request (chunks 1 and 2 went out already)."""

    def __init__(self, owner: Execution, request_id: str, chunks: list[Chunk], begin: float):
        self.owner = owner
        self.request_id = request_id
        self.chunks = chunks
        self.begin = begin  # monotonic s: when chunk 1 starts playing
        self.sent = min(2, len(chunks))
        self.done = threading.Event()
        self._cancel = threading.Event()
        self._thread = threading.Thread(target=self._run, name="trajectory-stream", daemon=True)

    def start(self) -> _Stream:
        self._thread.start()
        return self

    def describe(self) -> str:
        last = self.chunks[-1]
        left = self._due(len(self.chunks) - 1) - time.monotonic()
        return (f"the robots are executing request {self.request_id} in {len(self.chunks)} "
                f"chunks ({self.sent} sent; the last one starts in {max(left, 0.0):.1f} s, "
                f"the motion ends in {max(left + last.duration, 0.0):.1f} s)")  # fmt: skip

    def owns(self, trajectory_id: str) -> bool:
        return base_id(trajectory_id) == self.request_id

    def cancel(self, reason: str) -> None:
        if not self.done.is_set() and not self._cancel.is_set():
            log.warning("request %s: no more chunks sent: %s", self.request_id, reason)
        self._cancel.set()

    def join(self) -> None:
        self._thread.join(timeout=5)

    def _due(self, k: int) -> float:
        """Monotonic time (s) to send chunk ``k`` (0-based, k >= 1): once chunk k - 1 plays."""
        prev = self.chunks[k - 1]
        return self.begin + prev.t0 + START_LEAD * prev.duration

    def _run(self) -> None:
        try:
            n = len(self.chunks)
            for k in range(self.sent, n):
                if self._cancel.wait(max(0.0, self._due(k) - time.monotonic())):
                    return
                acks, timeout = self.owner.send(self.chunks[k])
                verdict, reason = execution_verdict(acks, timeout)
                if self._cancel.is_set():
                    return
                if verdict is not Verdict.ACCEPTED:
                    self._fail(f"chunk {k + 1}/{n}: {reason}")
                    return
                self.sent = k + 1
                log.info("request %s: chunk %d/%d accepted", self.request_id, k + 1, n)
            self._cancel.wait(max(0.0, self._due(n - 1) - time.monotonic()))
        except Exception:  # a bug here must not leave the robots running unattended
            log.exception("request %s: trajectory stream failed", self.request_id)
            self._fail("the trajectory stream failed (see the planner log)")
        finally:
            self.done.set()

    def _fail(self, reason: str) -> None:
        log.error("request %s: %s; stopping the robots", self.request_id, reason)
        self.owner.tracks.clear()
        self.owner.send_stop(f"request {self.request_id}: {reason}")
