"""A ``mode: track`` request on the bus: follow ``<prefix>/targets/stream`` with setpoints.

:class:`TrackSession` (one per track request, started by the planner node) wires the pure
:class:`planner.track.follow.TargetFollower` to the bus:

- subscribes ``<prefix>/targets/stream``: a body over 64 KiB, one that is not a valid
  :class:`~schemas.messages.TargetStream`, or one for another ``id`` is counted and
  ignored (the node keeps serving); camera-frame points are mapped to the world with the
  calibrated camera pose at the arms' latest measured joints (as requests are:
  :func:`planner.service.handler.camera_to_world`), and the first estimate lands on the
  surface that carries it (:mod:`planner.plan.landing`). The tracked point is the stream's point nearest the request's
  first point (chosen on the first frame, then fixed by index); so are the follower's
  markers (the request's other points, at least 3, when keep-out volumes are attached to
  the stream: their rigid motion moves them). The subscriber's callback only keeps the
  newest frame; a thread of its own (nice -10 where permitted) solves it: prediction and IK
  outside the follower's lock (the setpoints are checked under a twin of the IK's safety
  rules), then the new reference committed under it, so a slow solve never holds up a
  setpoint, and a frame that a newer one replaced before it was solved is skipped
  (counted);
- with a :class:`~planner.track.correction.SpotCorrection` (a camera-frame track request
  whose camera can see the beam: :func:`planner.service.track_start.camera_correction`),
  subscribes ``<prefix>/camera/spot`` too: each frame's point is aimed at corrected by the
  spots the camera saw, the treatment is on only while the correction permits it (read
  without a lock by the setpoint thread), and a world-frame frame ends the session with a
  reason (it would add the camera's error);
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

import contextlib
import json
import logging
import os
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from planner.bus.priority import TIMING_NICE
from planner.bus.session import Keys, decode, decode_sample
from planner.errors import InputError
from planner.model.system import System
from planner.model.transforms import Array
from planner.service.handler import camera_to_world
from planner.service.setpoints import SetpointStreamer
from planner.track.correction import SpotCorrection
from planner.track.follow import TargetFollower
from schemas.messages import TRACK_SCHEMA, JointState, SpotMessage, TargetStream

log = logging.getLogger("beamrelay.track")

#: bytes: larger target stream bodies are ignored unread
MAX_STREAM_BYTES = 64 * 1024
#: s: the session stops when no frame of its stream came this long after its start
FIRST_FRAME_TIMEOUT = 1.0


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
        correction: SpotCorrection | None = None,
    ) -> None:
        self.session, self.keys, self.system = session, keys, system
        self.follower, self.id = follower, request_id
        self.duration, self.send_stop, self.on_end, self.clock = duration, send_stop, on_end, clock
        self._lock = threading.Lock()  # the follower's setpoint state
        self.correction = correction
        self._correction_lock = threading.Lock()
        self._frame_lock = threading.Lock()  # one frame solved at a time
        self._slot_lock = threading.Lock()
        self._slot: tuple[float, float, Array, Array | None] | None = None  # the newest frame
        self._frame_ready = threading.Event()
        self.skipped = 0  # frames replaced by a newer one before they were solved
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
        self._marker_index: Array | None = None  # the stream's points matched to the markers
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
        if self.correction is not None:
            self._joint_subs.append(
                self.session.declare_subscriber(self.keys.camera_spot, self._on_spot)
            )
        self._streamer.start()
        threading.Thread(target=self._solve_frames, name="track-frames", daemon=True).start()
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
                if self.correction is not None:
                    with self._correction_lock:
                        self.correction.on_joints(float(msg.t), stacked)

        return cb

    def _on_spot(self, sample: Any) -> None:
        """A camera spot: the correction's measurement (a bad body is logged and ignored;
        nothing escapes into the Zenoh callback)."""
        msg = decode_sample(sample, SpotMessage, log, "spot message")
        if msg is None or self.correction is None:
            return
        p = None if msg.p_camera is None else np.asarray(msg.p_camera, dtype=float)
        with self._correction_lock:
            try:
                self.correction.on_spot(float(msg.t), p, float(msg.confidence))
            except (ArithmeticError, ValueError) as exc:  # a degenerate beam: no model spot
                self.correction.dropped["model_invalid"] += 1
                log.debug("camera spot not used: %s", exc)

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
        if self.correction is not None and msg.frame != "camera":
            self.ignored += 1  # corrected in the camera's frame: a world frame would add its error
            self.stop(f"target stream {self.id!r} sends {msg.frame}-frame points but the "
                      "request is in the camera frame: send the stream with frame: camera, "
                      "or request in the world frame")  # fmt: skip
            return
        points = np.asarray(msg.points, dtype=float)
        normals = None if msg.normals is None else np.asarray(msg.normals, dtype=float)
        if msg.frame == "camera":
            cam = self.system.camera
            # an eye-in-hand camera's pose needs its arm's measured joints: until they came,
            # the frame would map through the home pose and could fix the wrong point
            if cam is None or (cam.robot is not None and cam.robot not in self._measured):
                self.ignored += 1
                return
            points, normals = camera_to_world(self.system, points, normals, dict(self._measured))
        if self._index is None:
            self._index = int(nearest(points, self.follower.first[None])[0])
            if self.follower.markers is not None:
                self._marker_index = nearest(points, self.follower.markers)
        if self._index >= len(points):
            self.ignored += 1
            return
        with self._slot_lock:  # the newest frame replaces one not yet solved
            self.skipped += self._slot is not None
            self._slot = (received, float(msg.t), points, normals)
        self._frame_ready.set()

    def _solve_frames(self) -> None:
        """The frames' thread: solves the newest frame (nice :data:`TIMING_NICE` where
        permitted: a late solve lets the stream go stale), commits it under the lock."""
        with contextlib.suppress(OSError):
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), TIMING_NICE)
        while not self._ended.is_set():
            if not self._frame_ready.wait(0.05):
                continue
            with self._slot_lock:
                slot, self._slot = self._slot, None
                self._frame_ready.clear()
            if slot is not None:
                self._solve(*slot)

    def _solve(self, received: float, t: float, points: Array, normals: Array | None) -> None:
        assert self._index is not None
        k, m = self._index, self._marker_index
        markers = None if m is None or m.max() >= len(points) else points[m]
        point, normal = points[k], None if normals is None else normals[k]
        if self.correction is not None:
            with self._correction_lock:
                self.correction.on_target(t, point, normal)
                point = self.correction.corrected(point)
        with self._frame_lock:  # setpoints go on meanwhile
            out, segment = self.follower.solve_frame(t, point, normal, self.clock(),
                                                     markers=markers)  # fmt: skip
            with self._lock:
                if segment is not None:
                    self.follower.commit(segment)
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
        if laser and self.correction is not None:  # treatment only on a measured landing
            laser = self.correction.permits(t)  # lock-free: one attribute, replaced whole
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
        with self._frame_lock, self._lock:  # no frame's solve moves the volumes after this
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
        correction = {}
        if self.correction is not None:
            with self._correction_lock:
                correction = {"camera_correction": self.correction.figures()}
        figures = {}
        if len(lat):
            figures = {"latency_p50": float(np.percentile(lat, 50)),
                       "latency_p99": float(np.percentile(lat, 99)),
                       "latency_max": float(lat.max())}  # fmt: skip
        return {"schema": TRACK_SCHEMA, "id": self.id, "ended": reason,
                "completed": self.completed, "frames": self.frames,
                "ignored": self.ignored, "skipped": self.skipped, "setpoints": self.sent,
                "laser_on_fraction": self.lit / self.sent if self.sent else 0.0,
                "duration": self.clock() - self.t_start, "streamer_error": self._streamer.error,
                **figures, **correction}  # fmt: skip


def nearest(points: Array, to: Array) -> Array:
    """Index of the point of ``points`` (K x 3) nearest each of ``to`` (M x 3)."""
    d = np.linalg.norm(points[None, :, :] - np.asarray(to)[:, None, :], axis=2)
    return np.asarray(np.argmin(d, axis=1))
