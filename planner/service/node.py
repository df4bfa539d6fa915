"""The planner node (SPEC section 6): a thin Zenoh adapter over the pure planning code.

The pure side (request -> targets -> plan.json) is :mod:`planner.service.handler`.
:class:`PlannerNode` is the Zenoh side: queryable ``<prefix>/plan`` replies with plan.json
  (``application/json``) or an :class:`~schemas.messages.ErrorReply` via ``reply_err``;
  subscriber ``<prefix>/targets`` publishes its result on ``<prefix>/plans``. With
  ``execute: true`` it sends one :class:`~schemas.messages.JointTrajectory` per robot to
  ``<prefix>/<robot>/trajectory``, planned from the robots' latest ``joint_states``; it
  refuses while a robot driver's liveliness token ``<prefix>/alive/<robot>`` is missing.
  It declares ``<prefix>/alive/planner``. One worker thread plans, requests queue up behind
  it (bounded: a full queue gets a "busy" error), so any number of clients may call at once.
"""

from __future__ import annotations

import json
import logging
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from planner.errors import BeamrelayError, InputError
from planner.model.transforms import Array
from planner.service.bus import JSON, Keys, decode, encode
from planner.service.handler import RequestHandler, handler_from_scenario, make_plan_fn

__all__ = [
    "ExecuteError",
    "PlannerNode",
    "RequestHandler",
    "handler_from_scenario",
    "make_plan_fn",
    "trajectory_messages",
]

log = logging.getLogger("beamrelay.node")

#: a joint state older than this (s, receiver clock) does not count as "current"
STATE_MAX_AGE = 0.5
#: requests waiting for the worker beyond this many get a "busy" error reply
QUEUE_SIZE = 64


class ExecuteError(BeamrelayError):
    """``execute`` refused: a driver is down or its joint state is missing/stale.

    ``robots`` names the robots concerned.
    """

    def __init__(self, reason: str, robots: list[str]) -> None:
        self.reason = reason
        self.robots = robots
        super().__init__(reason)


def error_body(exc: Exception, request_id: str | None = None) -> bytes:
    """An :class:`~schemas.messages.ErrorReply` JSON body for any error of ours."""
    from schemas.messages import ErrorReply

    if isinstance(exc, InputError):
        msg = ErrorReply(id=request_id, error=exc.reason, field=exc.where or None)
    elif isinstance(exc, ExecuteError):
        msg = ErrorReply(id=request_id, error=exc.reason, field="execute")
    else:
        msg = ErrorReply(id=request_id, error=f"{type(exc).__name__}: {exc}")
    return encode(msg)


def request_id_of(payload: bytes) -> str | None:
    """Best effort: the ``id`` of a (possibly invalid) request body, for error replies."""
    try:
        data = json.loads(payload)
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError):
        return None
    rid = data.get("id") if isinstance(data, dict) else None
    return rid if isinstance(rid, str) else None


@dataclass
class JointCache:
    """Latest joint state per robot (receiver clock), thread safe."""

    names: tuple[str, ...]
    _q: dict[str, tuple[float, Array, Array]] = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def update(self, robot: str, q: Array, qd: Array) -> None:
        with self._lock:
            self._q[robot] = (time.monotonic(), q, qd)

    def get(self, robot: str) -> tuple[float, Array, Array] | None:
        with self._lock:
            return self._q.get(robot)

    def current(self, max_age: float = STATE_MAX_AGE) -> dict[str, Array]:
        """``{robot: q}`` for every robot, or ExecuteError naming the missing/stale ones."""
        now = time.monotonic()
        out, missing = {}, []
        for name in self.names:
            entry = self.get(name)
            if entry is None or now - entry[0] > max_age:
                missing.append(name)
            else:
                out[name] = entry[1]
        if missing:
            raise ExecuteError(
                f"no current joint state from {', '.join(missing)} "
                f"(none received in the last {max_age:g} s)",
                missing,
            )
        return out


def trajectory_messages(plan: dict[str, Any]) -> dict[str, bytes]:
    """One JointTrajectory body per robot from a plan's ``trajectory`` (times from 0)."""
    from schemas.messages import JointTrajectory

    traj = plan.get("trajectory")
    if not traj:
        raise ExecuteError("the plan has no trajectory to execute", list(plan["robots"]))
    t = np.asarray(traj["t"], dtype=float)
    keep = np.concatenate([[True], np.diff(t) > 0])  # drivers require increasing times
    out = {}
    for robot in plan["robots"]:
        rows = {k: np.asarray(traj[k][robot], dtype=float)[keep] for k in ("q", "qd", "qdd")}
        msg = JointTrajectory(
            robot=robot,
            t=(t[keep] - t[0]).tolist(),
            names=list(plan["joint_names"][robot]),
            q=rows["q"].tolist(),
            qd=rows["qd"].tolist(),
            qdd=rows["qdd"].tolist(),
        )
        out[robot] = encode(msg)
    return out


class PlannerNode:
    """The Zenoh adapter around a :class:`RequestHandler`. ``start()``, then ``close()``."""

    def __init__(self, handler: RequestHandler, session: Any, keys: Keys | None = None) -> None:
        self.handler = handler
        self.session = session
        self.keys = keys or Keys()
        self.robots = handler.system.robot_names
        self.joints = JointCache(self.robots)
        self.alive: set[str] = set()
        self._alive_lock = threading.Lock()
        self._jobs: queue.Queue[tuple[str, Any, bytes] | None] = queue.Queue(QUEUE_SIZE)
        self._handles: list[Any] = []
        self._worker = threading.Thread(target=self._work, name="planner-worker", daemon=True)
        self.on_alive_change: Callable[[str, bool], None] | None = None
        self.served = 0

    # --- lifecycle -------------------------------------------------------------------------
    def start(self) -> PlannerNode:
        s, k = self.session, self.keys
        self._handles.append(s.liveliness().declare_token(k.alive("planner")))
        self._handles.append(
            s.liveliness().declare_subscriber(k.alive_all, self._on_alive, history=True)
        )
        for robot in self.robots:
            self._handles.append(s.declare_subscriber(k.joint_states(robot), self._joint_cb(robot)))
        self._publishers = {r: s.declare_publisher(k.trajectory(r)) for r in self.robots}
        self._plans = s.declare_publisher(k.plans)
        self._handles.append(s.declare_subscriber(k.targets, self._on_target))
        self._handles.append(s.declare_queryable(k.plan, self._on_query))
        self._worker.start()
        return self

    def close(self) -> None:
        """Undeclare everything and stop the worker (the session stays open)."""
        for h in reversed(self._handles):
            h.undeclare()
        self._handles.clear()
        for p in [*self._publishers.values(), self._plans]:
            p.undeclare()
        self._publishers.clear()
        self._jobs.put(None)
        self._worker.join(timeout=5)

    # --- callbacks (Zenoh threads: never plan here) ------------------------------------------
    def _on_alive(self, sample: Any) -> None:
        import zenoh

        node = str(sample.key_expr).rsplit("/", 1)[-1]
        up = sample.kind == zenoh.SampleKind.PUT
        with self._alive_lock:
            (self.alive.add if up else self.alive.discard)(node)
        log.info("%s %s", node, "up" if up else "DOWN")
        if self.on_alive_change is not None:
            self.on_alive_change(node, up)

    def _joint_cb(self, robot: str) -> Callable[[Any], None]:
        from schemas.messages import JointState

        n = self.handler.system.robot(robot).nq

        def cb(sample: Any) -> None:
            try:
                msg = decode(sample.payload.to_bytes(), JointState)
            except InputError as exc:
                log.warning("bad joint state from %s: %s", robot, exc)
                return
            q, qd = np.asarray(msg.q), np.asarray(msg.qd)
            if q.shape == (n,):
                self.joints.update(robot, q, qd)

        return cb

    def _on_query(self, query: Any) -> None:
        payload = query.payload.to_bytes() if query.payload is not None else b""
        self._enqueue(("query", query, payload))

    def _on_target(self, sample: Any) -> None:
        self._enqueue(("topic", None, sample.payload.to_bytes()))

    def _enqueue(self, job: tuple[str, Any, bytes]) -> None:
        try:
            self._jobs.put_nowait(job)
        except queue.Full:
            busy = InputError(f"planner busy ({QUEUE_SIZE} requests waiting), retry later")
            self._respond(job, None, busy)

    # --- the worker ------------------------------------------------------------------------
    def _work(self) -> None:
        while (job := self._jobs.get()) is not None:
            try:
                self._respond(job, self.serve(job[2]), None)
            except BeamrelayError as exc:
                self._respond(job, None, exc)
            except Exception as exc:  # a bug must not kill the node: report it, keep serving
                log.exception("request failed")
                self._respond(job, None, exc)

    def _respond(
        self, job: tuple[str, Any, bytes], body: bytes | None, exc: Exception | None
    ) -> None:
        kind, query, payload = job
        if exc is not None:
            body = error_body(exc, request_id_of(payload))
        assert body is not None
        if kind == "query":
            if exc is None:
                query.reply(self.keys.plan, body, encoding=JSON)
            else:
                query.reply_err(body, encoding=JSON)
            query.drop()
        else:
            self._plans.put(body, encoding=JSON)

    def serve(self, payload: bytes) -> bytes:
        """Handle one request body: validate, plan, maybe execute; the plan.json reply."""
        req = self.handler.parse(payload)
        start = None
        if req.execute:
            self.check_drivers()
            start = self.joints.current()
        plan = self.handler.plan(req, start, trajectory=req.execute)
        if req.execute:
            failed = [s["target"] for s in plan["solutions"] if s["status"] != "ok"]
            if len(failed) == len(plan["solutions"]):
                raise ExecuteError("no target could be solved, nothing to execute", [])
            for robot, body in trajectory_messages(plan).items():
                self._publishers[robot].put(body, encoding=JSON)
        self.served += 1
        return encode(plan)

    def check_drivers(self) -> None:
        """ExecuteError naming every robot whose driver's liveliness token is missing."""
        with self._alive_lock:
            down = [r for r in self.robots if r not in self.alive]
        if down:
            raise ExecuteError(f"robot driver down: {', '.join(down)}", down)
