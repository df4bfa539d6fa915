"""The planner node: a thin Zenoh adapter over the pure planning code.

The pure side (request -> targets -> plan.json) is :mod:`planner.service.handler`; what the node
knows of the robots is :mod:`planner.service.execution`; its guards (bounded queue, the worker
thread, progress watchdog, heartbeat) are :mod:`planner.service.guard`. :class:`PlannerNode`:

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
  ``<prefix>/stop`` (a partial multi-robot motion would misdirect the beam). Likewise when a
  robot halts (braking, stopped, fault, protective stop) or its token goes while its
  trajectory may still run: every robot stops.
- the heartbeat ``<prefix>/heartbeat`` (``session`` = :attr:`session_id`, random per node,
  100 Hz) comes from a child process (:mod:`planner.service.heartbeat`) when the node is
  given its :class:`~planner.service.heartbeat.BusAddress`, else from a thread of this
  process (which the solvers can starve for up to a second); it starts before the node
  declares ``<prefix>/alive/planner``.
- online calibration (opt-in, :mod:`planner.service.online`): spots on ``<prefix>/camera/spot``
  seen at rest, and ``node.online.add_sample(q, spot_world)`` calls (the servo), are refitted
  in the background (wired by :func:`planner.service.online.attach`); a new version is installed between requests (:meth:`install_calibration`)
  and plans report ``metrics.extra.calibration_version``.

One worker thread plans; requests queue up behind it (bounded in count and bytes: a full
queue gets a "busy" error). If the worker dies or stays busy on one request beyond its
allowance, the node is *failed*: the heartbeat stops, the liveliness token goes away and
``on_fatal(reason)`` is called (``beamrelay serve`` then exits non-zero, so its supervisor
restarts it).
"""
# long module: the planner node: its request queue, heartbeat, execution and replies share one session

from __future__ import annotations

import dataclasses
import logging
import threading
import time
import uuid
from collections.abc import Callable
from typing import Any

from planner.bus.bodies import encode_json
from planner.bus.events import event, request_fields, stop_fields, verdict_fields
from planner.bus.session import JSON, Keys, decode_sample, encode, update_alive, urgent
from planner.errors import InputError
from planner.io.plan import Plan
from planner.model.system import Targets
from planner.model.transforms import Array
from planner.service.execution import (
    ACK_TIMEOUT,
    HALTED_MODES,
    STATE_MAX_AGE,
    AckBoard,
    ExecuteError,
    JointCache,
    MotionTracks,
    start_state,
)
from planner.service.guard import QUEUE_SIZE, Heartbeat, Job, Progress, Worker
from planner.service.handler import (
    PREVIEW_RATE,
    RequestHandler,
    error_body,
    handler_from_scenario,
    make_plan_fn,
    request_id_of,
)
from planner.service.heartbeat import BusAddress, HeartbeatProcess, start_heartbeat
from planner.service.live_cloud import LiveCloud
from planner.service.online import OnlineCalibrator, attach
from planner.service.spots import LaserLog, SpotBuffer
from planner.service.stream import Execution, trajectory_messages
from schemas.messages import RobotStatus, StopMessage, TargetRequest

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


DRIVER_GRACE = 10.0
"""s after the planner's start during which an execute waits for drivers still starting
(``beamrelay up`` starts them together; a request sent at once would find them down)"""
DRIVER_POLL = 0.05  # s


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
        driver_grace: float = DRIVER_GRACE,
        warm_up: bool = False,
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
        self._faults: dict[str, str | None] = {}  # robot -> the fault its status last reported
        self.spots = SpotBuffer()
        self.cloud = LiveCloud()  # the camera's newest cloud: a surface for camera targets
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
        self._handles: list[Any] = []
        self._token: Any = None
        self._closing = threading.Event()
        self._started: float | None = None  # monotonic s of start()
        self._seen: set[str] = set()  # nodes whose token was ever seen
        self.driver_grace = driver_grace
        # serve and respond are looked up per job: a subclass or a test may replace them
        self._worker = Worker(lambda body: self.serve(body),
                              lambda *a: self._respond(*a), self.progress, self._worker_stopped,
                              self._warm_up if warm_up else None)  # fmt: skip
        self.on_alive_change: Callable[[str, bool], None] | None = None
        self.on_fatal: Callable[[str], None] | None = None
        self.failed: str | None = None
        self.served = 0
        self.track: Any = None  # the running TrackSession of a ``mode: track`` request
        self.track_settings: Any = None  # TrackSettings for track requests (None: defaults)

    # --- lifecycle -------------------------------------------------------------------------
    def start(self) -> PlannerNode:
        """Start beating and serving, then declare the token: a client that sees the token
        finds the queryable there (HeartbeatError if the heartbeat process cannot start)."""
        s, k = self.session, self.keys
        self._publishers = {r: s.declare_publisher(k.trajectory(r)) for r in self.robots}
        self._plans = s.declare_publisher(k.plans)
        self._stop_pub = s.declare_publisher(k.stop, **urgent())
        self._start_heartbeat()
        self._handles.append(
            s.liveliness().declare_subscriber(k.alive_all, self._on_alive, history=True)
        )
        for robot in self.robots:
            nq = self.handler.system.robot(robot).nq
            self._handles.append(s.declare_subscriber(k.joint_states(robot),
                                                      self.joints.callback(robot, nq)))  # fmt: skip
            self._handles.append(s.declare_subscriber(k.status(robot), self._status_cb(robot)))
        self._handles.append(s.declare_subscriber(k.stop, self._on_stop))
        self._handles.append(s.declare_subscriber(k.camera_spot, self.spots.callback))
        if self.handler.system.camera is not None:
            self._handles.append(s.declare_subscriber(k.camera_points, self.cloud.callback))
        self._handles.append(s.declare_subscriber(k.laser, self.laser.callback))
        self._handles.append(s.declare_subscriber(k.targets, self._on_target))
        self._handles.append(s.declare_queryable(k.plan, self._on_query))
        if self.online is not None:
            self._cal_pub, handles = attach(self.online, s, k, self.robots, self.joints.get,
                                            self.install_calibration)  # fmt: skip
            self._handles += handles
        self._worker.start()
        self._token = s.liveliness().declare_token(k.alive("planner"))
        self._started = time.monotonic()
        return self

    def with_cloud(
        self, targets: Targets, req: TargetRequest, start: dict[str, Array] | None
    ) -> Targets:
        """Camera-frame point targets with a fixed camera's live cloud around them (world,
        through its calibrated pose) as a surface that may carry them
        (:func:`planner.plan.landing.cloud_landings`); other targets as they are."""
        cam = self.handler.system.camera
        if req.frame != "camera" or targets.kind != "points" or targets.surface_tolerance <= 0:
            return targets
        if cam is None or cam.robot is not None:  # a moving camera's cloud: other joints
            return targets
        cloud = self.cloud.around(targets.points, self.handler.system.world_T_camera(start))
        return targets if cloud is None else dataclasses.replace(targets, cloud=cloud)

    def _warm_up(self) -> None:
        """The worker's first task with ``warm_up``: :meth:`RequestHandler.warm_up`
        (requests queue behind it, as they would behind a cold first request)."""
        with self._handler_lock:
            handler = self.handler
        event(log, "warmed_up", seconds=round(handler.warm_up(), 3))

    def install_calibration(self, handler: RequestHandler | None, calibration: Any) -> None:
        """Serve later requests with ``handler`` (planned with ``calibration``, whose
        ``version`` the plans report); a request in progress keeps its handler."""
        if handler is None:
            return
        with self._handler_lock:
            self.handler, self.calibration_version = handler, int(calibration.version)

    def _start_heartbeat(self) -> None:
        def on_wedged(reason: str) -> None:
            self._fatal(f"planner wedged: {reason}")

        self.heartbeat, self._beat_pub = start_heartbeat(
            self.session, self.keys.heartbeat, self.session_id, self.progress, on_wedged,
            self.bus, self._heartbeat_rate)  # fmt: skip

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
        self._worker.close(timeout=1 if self.failed else 5)
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
        node, up = update_alive(self.alive, self._alive_lock, sample)
        if up:
            self._seen.add(node)
        log.info("%s %s", node, "up" if up else "DOWN")
        if not up and node in self.robots and self.tracks.running_end(node) is not None:
            self._halt_all(f"{node}'s liveliness token is gone during an execution")
        if self.on_alive_change is not None:
            self.on_alive_change(node, up)

    def _status_cb(self, robot: str) -> Callable[[Any], None]:

        def cb(sample: Any) -> None:
            msg = decode_sample(sample, RobotStatus, log, f"status from {robot}")
            if msg is None:
                return
            ack = msg.trajectory
            if ack is not None:
                self.acks.offer(robot, ack)
            self._log_fault(robot, msg)
            if self.track is not None:
                self.track.on_status(robot, msg)
            if msg.mode in HALTED_MODES or msg.protective_stop:
                why = "protective-stopped" if msg.protective_stop else msg.mode
                if self.tracks.halted(robot, None if ack is None else ack.id):
                    self._halt_all(f"{robot} is {why} during an execution: {msg.fault or why}")
                if ack is not None:
                    self.execution.cancel(f"{robot} is {why}", ack.id)

        return cb

    def _log_fault(self, robot: str, msg: Any) -> None:
        """One ``fault`` event when a driver's reported fault changes (and ``fault_cleared``)."""
        fault = "protective stop" if msg.protective_stop else msg.fault
        if fault == self._faults.get(robot):
            return
        self._faults[robot] = fault
        ack = msg.trajectory
        event(log, "fault" if fault else "fault_cleared", logging.WARNING if fault else logging.INFO,
              robot=robot, id=None if ack is None else ack.id, mode=msg.mode, fault=fault)  # fmt: skip

    def _halt_all(self, reason: str) -> None:
        """One robot halted (or vanished) mid-execution: stop them all (the beam chain)."""
        log.warning("stopping every robot: %s", reason)
        self.tracks.clear()
        self.execution.cancel(reason)
        try:
            self.send_stop(reason)
        except Exception:  # the session may be closing
            log.exception("could not publish the stop")

    def _on_stop(self, sample: Any) -> None:
        event(log, "stop_seen", logging.WARNING, **stop_fields(sample))
        self.stop_seen.set()
        self._stop_track(f"stop seen on {self.keys.stop}")
        self.tracks.clear()
        self.execution.cancel(f"stop seen on {self.keys.stop}")

    def _on_query(self, query: Any) -> None:
        self._worker.take("query", query, query.payload)

    def _on_target(self, sample: Any) -> None:
        self._worker.take("topic", None, sample.payload)

    # --- the worker ------------------------------------------------------------------------
    def _worker_stopped(self) -> None:
        if not self._closing.is_set():
            self._fatal("the planner worker thread stopped")

    def _respond(self, job: Job, body: bytes | None, exc: Exception | None) -> None:
        if exc is not None:
            event(log, "refused", logging.WARNING, id=request_id_of(job.payload), error=str(exc))
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
        from planner.service.closed_loop import check_closed_loop, execute_on_node

        if self.track is not None and self.track.active:
            raise InputError(f"planner busy tracking {self.track.id!r}: publish on "
                             f"{self.keys.stop} to end it, or wait for its duration", "body")  # fmt: skip
        with self._handler_lock:
            handler, version = self.handler, self.calibration_version
        req = handler.parse(payload)
        event(log, "request", **request_fields(req))
        check_closed_loop(req, handler.system, handler.closed_loop)
        if req.closed_loop and handler.closed_loop is None:
            raise InputError("this planner serves no closed_loop requests", "closed_loop")
        if req.mode == "track":
            from planner.service.track_start import start_track

            return encode_json(start_track(self, req).to_document())
        start = None
        if req.execute:
            self.check_drivers()
            start = self.start_state()
        elif req.trajectory:  # a preview: the trajectory execute would send, not sent
            start = self.start_state()
        targets = self.with_cloud(handler.targets(req, start), req, start)
        self.progress.targets(len(targets.points))
        timed = (req.execute and not req.closed_loop) or req.trajectory
        rate = PREVIEW_RATE if timed and not req.execute else None  # a preview: coarser
        plan = handler.plan_fn(targets, start, timed, dwell=req.dwell, rate=rate)
        plan = dataclasses.replace(plan, id=req.id)
        for text in plan.warnings or ():  # logged before anything moves
            event(log, "warning", logging.WARNING, id=req.id, text=text)
        if self.online is not None:
            extra = plan.metrics.with_extra(calibration_version=version)
            plan = dataclasses.replace(plan, metrics=extra)
            self.online.add_planned(plan)  # a refit must keep these hits on the mirror
        if req.execute and req.closed_loop:
            assert start is not None
            plan = execute_on_node(self, plan, targets, req, start, handler)
        elif req.execute:
            plan = self.execute(plan, req.id)
        self.served += 1
        event(log, "verdict", **verdict_fields(plan))
        return encode_json(plan.to_document())

    # --- execution -------------------------------------------------------------------------
    def check_drivers(self) -> None:
        """ExecuteError naming every robot whose driver's liveliness token is missing, or
        when a streamed trajectory still has chunks to send. Within :data:`DRIVER_GRACE` s
        of the planner's start a driver never seen may still be starting: wait for it till
        then (one that was seen and left is down at once)."""
        while True:
            with self._alive_lock:
                down = [r for r in self.robots if r not in self.alive]
            if not down or any(r in self._seen for r in down) or not self._starting():
                break
        if down:
            raise ExecuteError(f"robot driver down: {', '.join(down)}", down)
        busy = self.execution.busy()
        if busy is not None:
            raise ExecuteError(f"{busy}: execute again after that", list(self.robots))

    def start_state(self) -> dict[str, Array]:
        """Where each robot will be when a trajectory sent now starts (rad): the end of the
        trajectory it still plays, else its latest joint state (ExecuteError if stale; a
        driver that just started has :data:`DRIVER_GRACE` s to send its first)."""
        while True:
            try:
                return start_state(self.robots, self.tracks, self.joints)
            except ExecuteError:
                if not self._starting():
                    raise

    def _starting(self) -> bool:
        """Whether the planner started less than ``driver_grace`` s ago (then wait a poll
        period and say True)."""
        if self._started is None or time.monotonic() - self._started >= self.driver_grace:
            return False
        return not self._closing.wait(DRIVER_POLL)

    def execute(self, plan: Plan, request_id: str) -> Plan:
        """Send the plan's trajectories, wait for the drivers' verdicts; the plan with them
        (``execution``, ``execution_reason``)."""
        if not plan.any_ok:
            raise ExecuteError("no target could be solved, nothing to execute", [])
        return self.execution.execute(plan, request_id, self.session_id)

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

        msg = StopMessage(t=time.time(), source="planner", reason=reason[:1000])
        self._stop_pub.put(encode(msg), encoding=JSON)
