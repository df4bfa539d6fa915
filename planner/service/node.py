"""The planner node: a thin Zenoh adapter over the pure planning code.

The pure side (request -> targets -> plan.json) is :mod:`planner.service.handler`; what the node
knows of the robots is :mod:`planner.service.execution`; its guards (bounded queue, progress
watchdog, heartbeat) are :mod:`planner.service.guard`. :class:`PlannerNode`:

- queryable ``<prefix>/plan`` replies with plan.json (``application/json``, ``id`` = the
  request's) or an :class:`~schemas.messages.ErrorReply` via ``reply_err``; subscriber
  ``<prefix>/targets`` publishes its result on ``<prefix>/plans``. Bodies over
  ``MAX_PAYLOAD_BYTES`` are refused in the Zenoh callback, before they are copied or queued;
  every other body, whatever it holds, gets a plan or an error naming the field.
- With ``execute: true`` it sends the trajectory to ``<prefix>/<robot>/trajectory`` (one
  :class:`~schemas.messages.JointTrajectory` per robot carrying the request id and the node's
  session id; streamed in chunks when over the body limit, see
  :mod:`planner.service.stream`), planned from where each robot will be when it starts (the
  end of the trajectory it still plays, else its latest ``joint_states``), waits up to
  ``ACK_TIMEOUT`` s for every driver's verdict in ``<prefix>/<robot>/status`` and replies
  ``execution: accepted | rejected`` with ``execution_reason``. It refuses while a robot
  driver's liveliness token ``<prefix>/alive/<robot>`` is missing or a streamed trajectory
  still has chunks to send. If some robots accepted and others did not, it publishes
  ``<prefix>/stop`` (a partial multi-robot motion would misdirect the beam).
- the heartbeat ``<prefix>/heartbeat`` (``session`` = :attr:`session_id`, random per node,
  100 Hz) comes from a child process (:mod:`planner.service.heartbeat`) when the node is
  given its :class:`~planner.service.heartbeat.BusAddress`, else from a thread of this
  process (which the solvers can starve for up to a second); it starts before the node
  declares ``<prefix>/alive/planner``.
- online calibration (opt-in, :mod:`planner.service.online`): spots on ``<prefix>/camera/spot``
  seen at rest, and ``node.online.add_sample(q, spot_world)`` calls (the servo), are refitted
  in the background; a new version is installed between requests (:meth:`install_calibration`)
  and plans report ``metrics.extra.calibration_version``.

One worker thread plans; requests queue up behind it (bounded in count and bytes: a full
queue gets a "busy" error). If the worker dies or stays busy on one request beyond its
allowance, the node is *failed*: the heartbeat stops, the liveliness token goes away and
``on_fatal(reason)`` is called (``beamrelay serve`` then exits non-zero, so its supervisor
restarts it).
"""

from __future__ import annotations

import logging
import threading
import time
import uuid
from collections.abc import Callable
from typing import Any

import numpy as np

from planner.errors import BeamrelayError, InputError
from planner.model.transforms import Array
from planner.service.bodies import encode_json
from planner.service.bus import JSON, MAX_PAYLOAD_BYTES, Keys, decode, encode
from planner.service.execution import (
    ACK_TIMEOUT,
    HALTED_MODES,
    STATE_MAX_AGE,
    AckBoard,
    ExecuteError,
    JointCache,
    MotionTracks,
    trajectory_messages,
)
from planner.service.guard import QUEUE_SIZE, Heartbeat, Job, JobQueue, Progress
from planner.service.handler import (
    RequestHandler,
    error_body,
    handler_from_scenario,
    make_plan_fn,
    request_id_of,
)
from planner.service.heartbeat import BusAddress, HeartbeatProcess
from planner.service.online import OnlineCalibrator, RestSampler
from planner.service.spots import LaserLog, SpotBuffer
from planner.service.stream import Execution

__all__ = [
    "QUEUE_SIZE",
    "STATE_MAX_AGE",
    "BusAddress",
    "ExecuteError",
    "PlannerNode",
    "RequestHandler",
    "error_body",
    "handler_from_scenario",
    "make_plan_fn",
    "request_id_of",
    "trajectory_messages",
]

log = logging.getLogger("beamrelay.node")


class PlannerNode:
    """The Zenoh adapter around a :class:`RequestHandler`. ``start()``, then ``close()``."""

    def __init__(
        self,
        handler: RequestHandler,
        session: Any,
        keys: Keys | None = None,
        *,
        progress: Progress | None = None,
        heartbeat_rate: float | None = None,
        ack_timeout: float = ACK_TIMEOUT,
        bus: BusAddress | None = None,
        online: OnlineCalibrator | None = None,
    ) -> None:
        self.handler = handler
        self.online = online
        self.calibration_version = 0
        self._handler_lock = threading.Lock()
        self._cal_pub: Any = None
        self.session = session
        self.keys = keys or Keys()
        self.robots = handler.system.robot_names
        self.joints = JointCache(self.robots)
        self.tracks = MotionTracks()
        self.acks = AckBoard()
        self.spots = SpotBuffer()
        self.laser = LaserLog()
        self.stop_seen = threading.Event()
        self.ack_timeout = ack_timeout
        self.alive: set[str] = set()
        self.session_id = uuid.uuid4().hex
        self.progress = progress or Progress()
        self._heartbeat_rate = heartbeat_rate
        self.bus = bus
        self.heartbeat: Heartbeat | HeartbeatProcess | None = None
        self._beat_pub: Any = None
        self._publishers: dict[str, Any] = {}
        self.execution = Execution(self.robots, self._publish_trajectory, self.send_stop,
                                   self.acks, self.tracks, ack_timeout)  # fmt: skip
        self._alive_lock = threading.Lock()
        self._jobs = JobQueue()
        self._handles: list[Any] = []
        self._token: Any = None
        self._closing = threading.Event()
        self._worker = threading.Thread(target=self._work, name="planner-worker", daemon=True)
        self.on_alive_change: Callable[[str, bool], None] | None = None
        self.on_fatal: Callable[[str], None] | None = None
        self.failed: str | None = None
        self.served = 0
        self.track: Any = None  # the running TrackSession of a ``mode: track`` request
        self.track_settings: Any = None  # TrackSettings for track requests (None: defaults)

    # --- lifecycle -------------------------------------------------------------------------
    def start(self) -> PlannerNode:
        """Start beating, then declare the token and serve (HeartbeatError if the heartbeat
        process cannot start)."""
        s, k = self.session, self.keys
        self._publishers = {r: s.declare_publisher(k.trajectory(r)) for r in self.robots}
        self._plans = s.declare_publisher(k.plans)
        self._stop_pub = s.declare_publisher(k.stop)
        self.heartbeat = self._start_heartbeat()
        self._token = s.liveliness().declare_token(k.alive("planner"))
        self._handles.append(
            s.liveliness().declare_subscriber(k.alive_all, self._on_alive, history=True)
        )
        for robot in self.robots:
            self._handles.append(s.declare_subscriber(k.joint_states(robot), self._joint_cb(robot)))
            self._handles.append(s.declare_subscriber(k.status(robot), self._status_cb(robot)))
        self._handles.append(s.declare_subscriber(k.stop, self._on_stop))
        self._handles.append(s.declare_subscriber(k.camera_spot, self._on_spot))
        self._handles.append(s.declare_subscriber(k.laser, self._on_laser))
        self._handles.append(s.declare_subscriber(k.targets, self._on_target))
        self._handles.append(s.declare_queryable(k.plan, self._on_query))
        if self.online is not None:
            self._start_online(self.online)
        self._worker.start()
        return self

    def _start_online(self, online: OnlineCalibrator) -> None:
        self._cal_pub = self.session.declare_publisher(self.keys.calibration)
        online.publish = lambda body: self._cal_pub.put(body, encoding=JSON)
        online.on_update = self.install_calibration
        if online.rest_sampling:
            sampler = RestSampler(online, self.robots, self.joints.get)
            self._handles.append(
                self.session.declare_subscriber(self.keys.camera_spot, sampler.callback)
            )
        online.start()

    def install_calibration(self, handler: RequestHandler | None, calibration: Any) -> None:
        """Serve later requests with ``handler`` (planned with ``calibration``, whose
        ``version`` the plans report); a request in progress keeps its handler."""
        if handler is None:
            return
        with self._handler_lock:
            self.handler, self.calibration_version = handler, int(calibration.version)

    def _start_heartbeat(self) -> Heartbeat | HeartbeatProcess:
        rate = {} if self._heartbeat_rate is None else {"rate": self._heartbeat_rate}

        def on_wedged(reason: str) -> None:
            self._fatal(f"planner wedged: {reason}")

        if self.bus is not None:
            return HeartbeatProcess(self.bus, self.keys.heartbeat, self.session_id,
                                    self.progress, on_wedged, **rate).start()  # fmt: skip
        log.warning("heartbeat published from the planner process (no bus address given): "
                    "long solver calls can delay it")  # fmt: skip
        self._beat_pub = self.session.declare_publisher(self.keys.heartbeat)
        return Heartbeat(lambda body: self._beat_pub.put(body, encoding=JSON), self.session_id,
                         self.progress, on_wedged, **rate).start()  # fmt: skip

    def close(self) -> None:
        """Stop beating, undeclare everything, stop the worker (the session stays open)."""
        self._closing.set()
        self._stop_track("the planner node closes")
        if self.online is not None:
            self.online.close()
        if self.heartbeat is not None:
            self.heartbeat.stop()
        self._undeclare_token()
        for h in reversed(self._handles):
            h.undeclare()
        self._handles.clear()
        self._jobs.close()
        self._worker.join(timeout=1 if self.failed else 5)
        self.execution.close()
        pubs = [*self._publishers.values(), self._plans, self._stop_pub, self._beat_pub,
                self._cal_pub]  # fmt: skip
        for p in pubs:
            if p is not None:
                p.undeclare()
        self._publishers.clear()

    def _undeclare_token(self) -> None:
        token, self._token = self._token, None
        if token is not None:
            token.undeclare()

    def _fatal(self, reason: str) -> None:
        """The node can no longer serve: go silent and tell ``on_fatal`` (once)."""
        if self.failed is not None:
            return
        self.failed = reason
        log.critical("planner node failed: %s", reason)
        self._stop_track(f"planner failed: {reason}")
        if self.heartbeat is not None:
            self.heartbeat.stop()
        try:
            self._undeclare_token()
        except Exception:  # the session may be closing; the process exit drops it anyway
            log.exception("could not undeclare the liveliness token")
        if self.on_fatal is not None:
            self.on_fatal(reason)

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

    def _status_cb(self, robot: str) -> Callable[[Any], None]:
        from schemas.messages import RobotStatus

        def cb(sample: Any) -> None:
            try:
                msg = decode(sample.payload.to_bytes(), RobotStatus)
            except InputError as exc:
                log.warning("bad status from %s: %s", robot, exc)
                return
            ack = msg.trajectory
            if ack is not None:
                self.acks.offer(robot, ack)
            if self.track is not None:
                self.track.on_status(robot, msg)
            if msg.mode in HALTED_MODES or msg.protective_stop:
                self.tracks.halted(robot, None if ack is None else ack.id)
                if ack is not None:
                    self.execution.cancel(f"{robot} is {msg.mode}", ack.id)

        return cb

    def _on_stop(self, _sample: Any) -> None:
        self.stop_seen.set()
        self._stop_track(f"stop seen on {self.keys.stop}")
        self.tracks.clear()
        self.execution.cancel(f"stop seen on {self.keys.stop}")

    def _on_spot(self, sample: Any) -> None:
        from schemas.messages import SpotMessage

        try:
            msg = decode(sample.payload.to_bytes(), SpotMessage)
        except InputError as exc:
            log.warning("bad spot message: %s", exc)
            return
        self.spots.offer(msg.t, msg.p_camera, msg.confidence)

    def _on_laser(self, sample: Any) -> None:
        from schemas.messages import LaserState

        try:
            msg = decode(sample.payload.to_bytes(), LaserState)
        except InputError as exc:
            log.warning("bad laser state: %s", exc)
            return
        self.laser.offer(msg.t, msg.on)

    def _on_query(self, query: Any) -> None:
        payload = query.payload
        size = 0 if payload is None else len(payload)
        if size > MAX_PAYLOAD_BYTES:  # refuse before copying the body out of Zenoh
            self._refuse(Job("query", query, b""), _oversize(size))
            return
        self._enqueue(Job("query", query, b"" if payload is None else payload.to_bytes()))

    def _on_target(self, sample: Any) -> None:
        size = len(sample.payload)
        if size > MAX_PAYLOAD_BYTES:
            self._refuse(Job("topic", None, b""), _oversize(size))
            return
        self._enqueue(Job("topic", None, sample.payload.to_bytes()))

    def _enqueue(self, job: Job) -> None:
        full = self._jobs.put(job)
        if full is not None:
            self._refuse(job, InputError(f"planner busy ({full}), retry later", "body"))

    def _refuse(self, job: Job, exc: Exception) -> None:
        try:
            self._respond(job, None, exc)
        except Exception:  # a vanished querier must not break the Zenoh callback
            log.exception("could not send an error reply")

    # --- the worker ------------------------------------------------------------------------
    def _work(self) -> None:
        try:
            while (job := self._jobs.get()) is not None:
                self._run(job)
        finally:
            if not self._closing.is_set():
                self._fatal("the planner worker thread stopped")

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
                self._respond(job, body, err)
            except Exception:  # the querier left, the session closes: nothing to reply to
                log.exception("could not send the reply")
        finally:
            self.progress.end()

    def _respond(self, job: Job, body: bytes | None, exc: Exception | None) -> None:
        if exc is not None:
            body = error_body(exc, request_id_of(job.payload))
        assert body is not None
        if job.kind == "query":
            if exc is None:
                job.query.reply(self.keys.plan, body, encoding=JSON)
            else:
                job.query.reply_err(body, encoding=JSON)
            job.query.drop()
        else:
            self._plans.put(body, encoding=JSON)

    def serve(self, payload: bytes) -> bytes:
        """Handle one request body: validate, plan, maybe execute; the plan.json reply.
        While a ``mode: track`` request runs, every request gets a "busy tracking" error. The
        handler (and so the calibration) is fixed for the whole request."""
        from planner.service.closed_loop import check_closed_loop

        if self.track is not None and self.track.active:
            raise InputError(f"planner busy tracking {self.track.id!r}: publish on "
                             f"{self.keys.stop} to end it, or wait for its duration", "body")  # fmt: skip
        with self._handler_lock:
            handler, version = self.handler, self.calibration_version
        req = handler.parse(payload)
        check_closed_loop(req, handler.system)
        if req.closed_loop and handler.closed_loop is None:
            raise InputError("this planner serves no closed_loop requests", "closed_loop")
        if req.mode == "track":
            from planner.service.track import start_track

            return encode_json(start_track(self, req))
        targets = handler.targets(req)
        self.progress.targets(len(targets.points))
        start = None
        if req.execute:
            self.check_drivers()
            start = self.start_state()
        elif req.trajectory:  # a preview: the trajectory execute would send, not sent
            start = self.start_state()
        timed = (req.execute and not req.closed_loop) or req.trajectory
        plan = handler.plan_fn(targets, start, timed, dwell=req.dwell)
        plan["id"] = req.id
        if self.online is not None:
            plan["metrics"].setdefault("extra", {})["calibration_version"] = version
        if req.execute and req.closed_loop:
            assert start is not None
            self.execute_closed_loop(plan, targets, req, start, handler)
        elif req.execute:
            self.execute(plan, req.id)
        self.served += 1
        return encode_json(plan)

    # --- execution -------------------------------------------------------------------------
    def check_drivers(self) -> None:
        """ExecuteError naming every robot whose driver's liveliness token is missing, or
        when a streamed trajectory still has chunks to send."""
        with self._alive_lock:
            down = [r for r in self.robots if r not in self.alive]
        if down:
            raise ExecuteError(f"robot driver down: {', '.join(down)}", down)
        busy = self.execution.busy()
        if busy is not None:
            raise ExecuteError(f"{busy}: execute again after that", list(self.robots))

    def start_state(self) -> dict[str, Array]:
        """Where each robot will be when a trajectory sent now starts (rad): the end of the
        trajectory it still plays, else its latest joint state (ExecuteError if stale)."""
        start = {}
        for robot in self.robots:
            q_end = self.tracks.running_end(robot)
            if q_end is not None:
                start[robot] = q_end
        rest = tuple(r for r in self.robots if r not in start)
        return start | (self.joints.current(robots=rest) if rest else {})

    def execute(self, plan: dict[str, Any], request_id: str) -> None:
        """Send the plan's trajectories, wait for the drivers' verdicts, and write them into
        ``plan`` (``execution``, ``execution_reason``)."""
        if all(s["status"] != "ok" for s in plan["solutions"]):
            raise ExecuteError("no target could be solved, nothing to execute", [])
        self.execution.execute(plan, request_id, self.session_id)

    def execute_closed_loop(
        self,
        plan: dict[str, Any],
        targets: Any,
        req: Any,
        start: dict[str, Array],
        handler: RequestHandler,
    ) -> None:
        """Servo every solved target on the camera's measured spot, then dwell
        (:mod:`planner.service.closed_loop`) in the calibration of ``handler`` (the one the
        request was planned with); writes ``closed_loop`` and the verdict. With online
        calibration, the measurement dwells at rest are its samples (the rest sampler)."""
        from planner.service.closed_loop import Motion, execute_closed_loop

        config = handler.closed_loop
        assert config is not None
        head = {k: plan[k] for k in ("robots", "joint_names", "scenario")}

        def send(trajectory: dict[str, Any], move_id: str) -> tuple[str, str | None]:
            mini = head | {"trajectory": trajectory}
            self.execution.execute(mini, move_id, self.session_id)
            return mini["execution"], mini["execution_reason"]

        self.stop_seen.clear()
        laser = self.laser if config.gated else None
        motion = Motion(send, self.rests_at, self.spots, self.stop_seen, self.progress.tick, laser)
        system = handler.system
        execute_closed_loop(plan, targets, req, system.stack_q(start), config, motion, system)

    def rests_at(self, q: Array) -> bool:
        """Whether every robot's fresh joint state is at rest on stacked ``q`` (rad)."""
        return self.joints.rests_at(self.handler.system.split_q(q))

    def _stop_track(self, reason: str) -> None:
        if self.track is not None and self.track.active:
            self.track.stop(reason)

    def track_ended(self, summary: dict[str, Any]) -> None:
        """A track session's figures, published on ``<prefix>/plans``."""
        try:
            self._plans.put(encode_json(summary), encoding=JSON)
        except Exception:  # the session may be closing
            log.exception("could not publish the tracking summary")

    def _publish_trajectory(self, robot: str, body: bytes) -> None:
        self._publishers[robot].put(body, encoding=JSON)

    def send_stop(self, reason: str) -> None:
        """Publish ``<prefix>/stop`` (every driver brakes, laser off)."""
        from schemas.messages import StopMessage

        msg = StopMessage(t=time.time(), source="planner", reason=reason[:1000])
        self._stop_pub.put(encode(msg), encoding=JSON)


def _oversize(size: int) -> InputError:
    return InputError(
        f"body of {size} bytes exceeds the limit of {MAX_PAYLOAD_BYTES} bytes (not read)", "body"
    )
