"""A ``mode: track`` request on the bus: follow ``<prefix>/targets/stream`` with setpoints.

:class:`TrackSession` (one per track request, started by the planner node) wires the pure
:class:`planner.track.follow.TargetFollower` to the bus:

- subscribes ``<prefix>/targets/stream``: a body over 64 KiB, one that is not a valid
  :class:`~schemas.messages.TargetStream`, or one for another ``id`` is counted and
  ignored (the node keeps serving); camera-frame points are mapped to the world with the
  calibrated camera pose. The tracked point is the stream's point nearest the request's
  first point (chosen on the first frame, then fixed by index). Each frame is handled in
  the subscriber's callback: prediction and IK, under the follower's lock;
- streams setpoints at 500 Hz through :class:`planner.service.setpoints.SetpointStreamer`
  (the follower's limited reference, ``laser_on`` to the gate robot);
- ends on the request's ``duration``, :meth:`stop` (``<prefix>/stop``, a halted robot, the
  node failing: heartbeat loss), a stale stream (no frame for 3 frame periods, or none
  within :data:`FIRST_FRAME_TIMEOUT` s of the start), an unsafe or unreachable prediction.
  At the end the last setpoint goes out with the laser off, the stream stops (the drivers
  stop the arm 50 ms later) and, unless the duration simply ran out, ``<prefix>/stop`` is
  published so every driver brakes at once. ``on_end(summary)`` gets the figures: frames,
  ignored bodies, laser-on fraction, the frame -> setpoint latency (s, p50/p99/max: from a
  frame's receipt to the publication of the first setpoint computed from it).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from planner.errors import InputError
from planner.model.system import System
from planner.model.transforms import Array
from planner.service.bus import Keys, decode
from planner.service.setpoints import SetpointStreamer
from planner.track.follow import TargetFollower
from schemas.messages import JointState, TargetStream

log = logging.getLogger("beamrelay.track")

#: bytes: larger target stream bodies are ignored unread
MAX_STREAM_BYTES = 64 * 1024
#: s: the session stops when no frame of its stream came this long after its start
FIRST_FRAME_TIMEOUT = 1.0
TRACK_SCHEMA = "beamrelay.track/1"
#: rad/s: a track request starts only while every joint is slower than this
REST_SPEED = 0.01
#: rad: farther than this from the first estimate's solution, the arm goes there with a
#: planned trajectory before the stream starts (the stream's first setpoint must lie within
#: 0.01 rad of the arm)
APPROACH_GAP = 0.005
#: s past the approach's planned end the robots may take to rest on its last sample
APPROACH_TIMEOUT = 2.0


class TrackSession:
    """One followed target stream (see the module docstring)."""

    def __init__(
        self,
        session: Any,
        keys: Keys,
        session_id: str,
        system: System,
        follower: TargetFollower,
        request_id: str,
        *,
        duration: float | None = None,
        gate_robot: str | None = None,
        aim: bool = False,
        send_stop: Callable[[str], None],
        on_end: Callable[[dict[str, Any]], None],
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.session, self.keys, self.system = session, keys, system
        self.follower, self.id = follower, request_id
        self.duration, self.send_stop, self.on_end, self.clock = duration, send_stop, on_end, clock
        self._lock = threading.Lock()
        self._ended = threading.Event()
        self._done = threading.Event()
        reference: Any = self._reference  # None from it: nothing sent this period
        self._streamer = SetpointStreamer(session, keys, session_id, system.robot_names,
                                          reference=reference, request_id=request_id,
                                          gate_robot=gate_robot, aim=aim, clock=clock)  # fmt: skip
        self._sub: Any = None
        self._joint_subs: list[Any] = []
        self._measured: dict[str, Array] = {}  # robot -> its latest measured joints (rad)
        self._index: int | None = None
        self._receipts: list[float] = []  # perf_counter of frames not yet streamed
        self.latencies: list[float] = []
        self.frames = self.ignored = self.lit = self.sent = 0
        self.t_start = clock()
        self._last: tuple[float, Array, Array] | None = None
        self._final_sent = False
        self.completed = False  # ran for its whole duration (not ended by a fault or stop)
        self.summary: dict[str, Any] | None = None

    # --- lifecycle -------------------------------------------------------------------------
    def start(self) -> TrackSession:
        self._sub = self.session.declare_subscriber(self.keys.target_stream, self._on_sample)
        self._joint_subs = [
            self.session.declare_subscriber(self.keys.joint_states(r), self._on_joints(r))
            for r in self.system.robot_names
        ]
        self._streamer.start()
        threading.Thread(target=self._finish, name="track-end", daemon=True).start()
        return self

    @property
    def active(self) -> bool:
        return not self._done.is_set()

    def stop(self, reason: str) -> None:
        """End the session (any thread): laser off, stream stopped."""
        with self._lock:
            self.follower.stop(reason)
        self._ended.set()

    def wait(self, timeout: float | None = None) -> bool:
        """Block until the session has ended; True if it has."""
        return self._done.wait(timeout)

    def on_status(self, robot: str, msg: Any) -> None:
        """A driver's :class:`~schemas.messages.RobotStatus`: end when it ended or refused
        this stream (of this session, since it started), faults or protective-stops."""
        if not self.active:
            return
        s: Any = getattr(msg, "stream", None)
        ours = s is not None and s.id == self.id and s.session == self._streamer.session_id
        if ours and s.state != "streaming" and (s.t or 0.0) >= self.t_start:
            self.stop(f"{robot} ended the stream ({s.state}): {s.reason}")
        if msg.protective_stop or msg.mode == "fault":
            self.stop(f"{robot} is {msg.mode}: {msg.fault or 'protective stop'}")

    # --- measured joints ----------------------------------------------------------------------
    def _on_joints(self, robot: str) -> Callable[[Any], None]:
        """The follower's laser rule counts the measured arm's spot gap from its command."""

        def cb(sample: Any) -> None:
            try:
                msg = decode(sample.payload.to_bytes(), JointState)
            except InputError:
                return
            q = np.asarray(msg.q, dtype=float)
            if len(q) != self.system.robot(robot).nq or not np.all(np.isfinite(q)):
                return
            self._measured[robot] = q
            if len(self._measured) == len(self.system.robot_names):
                stacked = np.concatenate([self._measured[r] for r in self.system.robot_names])
                with self._lock:
                    self.follower.on_joint_state(stacked, float(msg.t))

        return cb

    # --- target stream ---------------------------------------------------------------------
    def _on_sample(self, sample: Any) -> None:
        received = time.perf_counter()
        try:
            msg = self._decode(sample)
        except InputError as exc:
            self.ignored += 1
            log.debug("target stream body ignored: %s", exc)
            return
        if msg.id != self.id:
            self.ignored += 1
            return
        points = np.asarray(msg.points, dtype=float)
        normals = None if msg.normals is None else np.asarray(msg.normals, dtype=float)
        if msg.frame == "camera":
            if self.system.camera is None:
                self.ignored += 1
                return
            T = self.system.camera.world_T_camera
            points = points @ T[:3, :3].T + T[:3, 3]
            normals = None if normals is None else normals @ T[:3, :3].T
        with self._lock:
            if self._index is None:
                d = np.linalg.norm(points - self.follower.first, axis=1)
                self._index = int(np.argmin(d))
            if self._index >= len(points):
                self.ignored += 1
                return
            k = self._index
            out = self.follower.on_frame(msg.t, points[k], None if normals is None else normals[k],
                                         self.clock())  # fmt: skip
            self.frames += 1
            if out.stopped is None:
                self._receipts.append(received)
        if out.stopped is not None:
            self._ended.set()

    def _decode(self, sample: Any) -> TargetStream:
        payload = sample.payload
        size = 0 if payload is None else len(payload)
        if size > MAX_STREAM_BYTES:
            raise InputError(f"body of {size} bytes over {MAX_STREAM_BYTES}", "body")
        return decode(b"" if payload is None else payload.to_bytes(), TargetStream)

    # --- setpoints (the streamer's thread) -------------------------------------------------
    def _reference(self, t: float) -> tuple[dict[str, tuple[Array, Array]], bool] | None:
        with self._lock:
            self._check_time(t)
            sp = self.follower.setpoint(t)
            receipts, self._receipts = self._receipts, []
        if sp is None:
            if self.follower.unsafe:  # a setpoint broke a safety rule: every arm stops now
                if not self._final_sent:
                    self._final_sent = True
                    self.send_stop(f"tracking {self.id}: {self.follower.stopped}")
                self._ended.set()
                return None
            if self.follower.stopped is not None:
                self._ended.set()
                return self._final(t)
            return None
        _, q, qd, laser = sp
        self._last = (t, q, qd)
        now = time.perf_counter()
        self.latencies += [now - r for r in receipts]
        self.sent += 1
        self.lit += int(laser)
        split = self.system.split_q
        return {r: (split(q)[r], split(qd)[r]) for r in self.system.robot_names}, laser

    def _check_time(self, t: float) -> None:
        f = self.follower
        if self.duration is not None and t - self.t_start >= self.duration:
            self.completed = self.completed or f.stopped is None  # not already ended
            f.stop(f"duration {self.duration:g} s elapsed")
        elif f.frame_seen is None and t - self.t_start > FIRST_FRAME_TIMEOUT:
            f.stop(f"no frame of target stream {self.id!r} within {FIRST_FRAME_TIMEOUT:g} s")

    def _final(self, t: float) -> tuple[dict[str, tuple[Array, Array]], bool] | None:
        """Once: the last setpoint moved on along its velocity, laser off."""
        if self._final_sent or self._last is None:
            return None
        self._final_sent = True
        t0, q, qd = self._last
        q = q + qd * (t - t0)
        split = self.system.split_q
        return {r: (split(q)[r], split(qd)[r]) for r in self.system.robot_names}, False

    # --- the end ---------------------------------------------------------------------------
    def _finish(self) -> None:
        self._ended.wait()
        time.sleep(0.01)  # let the streamer send the final laser-off setpoint
        self._streamer.close()
        with self._lock:
            self.follower.release()
        if self._sub is not None:
            self._sub.undeclare()
        for s in self._joint_subs:
            s.undeclare()
        reason = self.follower.stopped or "stopped"
        if not self.completed:
            self.send_stop(f"tracking {self.id!r} ended: {reason}")
        self.summary = self._summary(reason)
        log.info("tracking %s ended: %s", self.id, json.dumps(self.summary))
        self._done.set()
        self.on_end(self.summary)

    def _summary(self, reason: str) -> dict[str, Any]:
        lat = np.asarray(self.latencies)
        figures = {}
        if len(lat):
            figures = {"latency_p50": float(np.percentile(lat, 50)),
                       "latency_p99": float(np.percentile(lat, 99)),
                       "latency_max": float(lat.max())}  # fmt: skip
        return {"schema": TRACK_SCHEMA, "id": self.id, "ended": reason,
                "completed": self.completed, "frames": self.frames,
                "ignored": self.ignored, "setpoints": self.sent,
                "laser_on_fraction": self.lit / self.sent if self.sent else 0.0,
                "duration": self.clock() - self.t_start, "streamer_error": self._streamer.error,
                **figures}  # fmt: skip


def approach(node: Any, handler: Any, plan: dict[str, Any], q0: Array, q1: Array,
             first: Array, normal: Array | None, request_id: str) -> Array:  # fmt: skip
    """Move from stacked ``q0`` to the first estimate's solution ``q1`` (rad) with a planned
    trajectory (timed and checked under the safety rules like any plan, laser off) and wait
    until every robot rests there; the measured joints then. ExecuteError when no safe move
    exists, a driver refuses it or the robots do not arrive."""
    from planner.service.execution import ExecuteError

    system = handler.system
    if handler.closed_loop is None:
        raise ExecuteError("no planned approach to the tracked target (this planner has no "
                           "move planner): execute a request to it first", list(system.robot_names))  # fmt: skip
    traj = handler.closed_loop.move(q0, q1, 0.0, first, normal)
    traj["laser_on"] = []
    mini = {k: plan[k] for k in ("robots", "joint_names", "scenario")} | {"trajectory": traj}
    node.execution.execute(mini, f"{request_id[:200]}.approach", node.session_id)
    if mini["execution"] != "accepted":
        raise ExecuteError(f"approach to the tracked target refused: {mini['execution_reason']}",
                           list(system.robot_names))  # fmt: skip
    deadline = time.monotonic() + float(traj["t"][-1]) + APPROACH_TIMEOUT
    q_end = {r: np.asarray(traj["q"][r][-1], dtype=float) for r in system.robot_names}
    while not node.joints.rests_at(q_end):
        if time.monotonic() > deadline:
            raise ExecuteError(f"the robots did not reach the tracked target's first estimate "
                               f"within {APPROACH_TIMEOUT:g} s of the approach's end",
                               list(system.robot_names))  # fmt: skip
        time.sleep(0.005)
    return system.stack_q(node.joints.current())


def start_track(node: Any, req: Any) -> dict[str, Any]:
    """Start following the target stream of a validated ``mode: track`` request on a
    :class:`planner.service.node.PlannerNode`; returns the reply document (the plan of the
    first estimate, ``execution: accepted``, ``tracking``). Errors (InputError /
    ExecuteError) name the field."""
    from planner.model.system import Targets
    from planner.service.execution import ExecuteError
    from planner.track.follow import TrackSettings

    if not req.execute:
        raise InputError("mode track moves the robots: it needs execute: true", "execute")
    handler, system = node.handler, node.handler.system
    if handler.track_ik is None:
        raise InputError("this planner has no tracking IK (no closed form for its arms)", "mode")
    node.check_drivers()
    start = node.joints.current()
    for robot in system.robot_names:
        entry = node.joints.get(robot)
        speed = 0.0 if entry is None else float(np.abs(entry[2]).max())
        if speed > REST_SPEED:
            raise ExecuteError(f"{robot} moves at {speed:.3f} rad/s: track once it rests",
                               [robot])  # fmt: skip
    targets = handler.targets(req)
    first = targets.points[0]
    normal = None if targets.normals is None else targets.normals[0]
    one = Targets(first[None], None if normal is None else normal[None], kind="points")
    plan = handler.plan_fn(one, start, False)
    plan["id"] = req.id
    sol = plan["solutions"][0]
    if sol["status"] != "ok":
        raise ExecuteError(f"the target's first estimate is not reachable: {sol['reason']}",
                           list(system.robot_names))  # fmt: skip
    q0 = system.stack_q(start)
    q1 = system.stack_q({r: np.asarray(q) for r, q in sol["q"].items()})
    base = node.track_settings or TrackSettings()
    if req.tolerance is not None and req.tolerance > base.tolerance:
        raise InputError(f"may only tighten the tracking laser-on tolerance "
                         f"{1e3 * base.tolerance:g} mm, got {1e3 * req.tolerance:g} mm",
                         "tolerance")  # fmt: skip
    settings = dataclasses.replace(base, tolerance=req.tolerance or base.tolerance)
    gap = float(np.abs(q1 - q0).max())
    if gap > APPROACH_GAP:  # the first move is a planned, checked trajectory, not a stream
        q0 = approach(node, handler, plan, q0, q1, first, normal, req.id)
    cam = None if system.camera is None else system.camera.world_T_camera
    attached = {o["name"]: np.asarray(o["world_T_object"]["matrix"], dtype=float)
                for o in (plan.get("scenario") or {}).get("keep_out") or []
                if o.get("attached_to") == req.id}  # fmt: skip
    follower = TargetFollower(handler.track_ik, q0, first, cam, settings, attached=attached)
    follower.warm_up(q1, normal)  # the first frame must not pay for first calls
    laser = ((plan.get("scenario") or {}).get("system") or {}).get("laser", {})
    gate = laser.get("gate") or {}
    node.track = TrackSession(node.session, node.keys, node.session_id, system, follower,
                              req.id, duration=req.duration, gate_robot=gate.get("robot"),
                              aim=laser.get("aim") is not None,
                              send_stop=node.send_stop, on_end=node.track_ended).start()  # fmt: skip
    plan["execution"] = "accepted"
    plan["tracking"] = {"stream": req.id, "duration": req.duration,
                        "tolerance": settings.tolerance, "rate": settings.rate}  # fmt: skip
    return plan
