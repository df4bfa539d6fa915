"""The Zenoh side of a camera driver, common to the ``sim`` and ``realsense`` backends.

:class:`CameraNode` runs the source in a thread at ``spot_rate`` (30 Hz by default) and

- publishes ``<prefix>/camera/spot`` (:class:`schemas.messages.SpotMessage`: ``p_camera`` in
  the camera optical frame, m, or null; ``confidence`` in [0, 1]) every frame,
- publishes ``<prefix>/camera/points`` every ``spot_rate / points_rate`` frames (15 Hz by
  default): payload = the raw float32 array, row-major, ``count`` rows of ``fields``
  (``x, y, z`` in m, camera frame; the RealSense source adds ``r, g, b`` in [0, 1]);
  attachment = JSON metadata (:func:`points_metadata`), decoded by :func:`decode_points`,
- subscribes ``<prefix>/<robot>/joint_states`` of the robots the source asks for (the
  simulated camera needs them to trace the true beam),
- declares the liveliness token ``<prefix>/alive/camera``,
- for sources that can (``markers``): the queryable ``<prefix>/camera/markers``: the query
  body is JSON (``board_points``, and what the source needs: ``charuco`` for the RealSense
  source, ``board_pose`` / ``robot`` for the simulated one), the reply
  ``{"t": UNIX s, "points_camera": [[x, y, z] or null, ...]}`` (camera optical frame, m),
- for sources that use them (the RealSense source): subscribes the laser gate state,
  ``<prefix>/laser`` (JSON ``{"on": bool, "aim": bool, "t": UNIX s}``: lit when either is
  on) and the ``laser_on`` field of
  ``<prefix>/*/status``, and ``<prefix>/camera/predicted`` (JSON ``{"p_camera": [x, y, z],
  "t": UNIX s}``: the planner's predicted spot, camera optical frame, m).

A source's ``grab`` may return False (an incomplete frameset, a timeout): nothing is
published for it. Message times ``t`` are the frame's capture time when the source gives
one (``frame_time``), else the time it was grabbed.
"""

from __future__ import annotations

import json
import threading
import time
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from drivers.loop_node import LoopNode
from planner.bus.session import JSON, Keys, bulk, decode, encode
from planner.errors import InputError
from planner.model.transforms import Array
from schemas.messages import JointState, LaserState, SpotMessage
from schemas.points import POINTS_SCHEMA, decode_points, points_metadata

__all__ = [
    "POINTS_SCHEMA",
    "CameraNode",
    "CameraSource",
    "SpotReading",
    "decode_points",
    "points_metadata",
]


@dataclass(frozen=True)
class SpotReading:
    """A detected spot: position in the camera optical frame (m) and confidence in [0, 1]."""

    p_camera: Array
    confidence: float


class CameraSource(Protocol):
    """What :class:`CameraNode` needs from a backend (``drivers.camera.sim`` / ``drivers.camera.realsense``)."""

    kind: str
    robot_names: tuple[str, ...]

    def on_joint_state(self, robot: str, q: Array, t: float | None = None) -> None: ...
    def grab(self) -> bool | None: ...
    def points(self) -> tuple[Any, dict[str, Any]]: ...
    def spot(self) -> SpotReading | None: ...
    def close(self) -> None: ...


class CameraNode(LoopNode):
    """Runs one camera source on the bus (see the module docstring)."""

    join_timeout = 5.0  # s: a real camera may block for a frame

    def __init__(
        self,
        session: Any,
        keys: Keys,
        source: CameraSource,
        *,
        spot_rate: float = 30.0,
        points_rate: float = 15.0,
    ) -> None:
        super().__init__()
        self.session = session
        self.keys = keys
        self.source = source
        self.period = 1.0 / spot_rate
        self._points_every = max(1, round(spot_rate / points_rate))
        self.frames = 0
        self.skipped = 0  # framesets the source could not deliver (incomplete, timeout)
        self._lock = threading.Lock()  # the source: frame loop vs. marker queries
        self.error: str | None = None

    def start(self, loop: bool = True) -> CameraNode:
        """Declare the bus handles and (``loop``) run the frame loop; without it the caller
        calls :meth:`publish_frame` itself (tests, replays)."""
        s, k = self.session, self.keys
        self._pub_spot = s.declare_publisher(k.camera_spot, encoding=JSON)
        self._pub_points = s.declare_publisher(k.camera_points, **bulk())
        for robot in self.source.robot_names:
            self._handles.append(s.declare_subscriber(k.joint_states(robot), self._joints(robot)))
        if hasattr(self.source, "on_laser"):  # a source that sees the spot only when lit
            self._handles.append(s.declare_subscriber(k.laser, self._on_laser))
        if hasattr(self.source, "on_gate"):
            self._handles += [
                s.declare_subscriber(f"{k.prefix}/laser", self._on_gate),
                s.declare_subscriber(f"{k.prefix}/*/status", self._on_gate),
            ]
        if hasattr(self.source, "markers"):
            self._handles.append(
                s.declare_queryable(f"{k.prefix}/camera/markers", self._on_markers)
            )
        if hasattr(self.source, "on_predicted"):
            self._handles.append(
                s.declare_subscriber(f"{k.prefix}/camera/predicted", self._on_predicted)
            )
        self._handles.append(s.liveliness().declare_token(k.alive("camera")))
        if loop:
            self._start_loop("camera")
        return self

    def _close(self) -> None:
        self.source.close()

    def _joints(self, robot: str) -> Any:
        def on_state(sample: Any) -> None:
            try:
                msg = decode(sample.payload.to_bytes(), JointState)
            except InputError:
                return  # a malformed state is ignored; the last good one stays
            self.source.on_joint_state(robot, np.asarray(msg.q, dtype=float), msg.t)

        return on_state

    def _on_laser(self, sample: Any) -> None:

        try:
            msg = decode(sample.payload.to_bytes(), LaserState)
        except InputError:
            return  # a malformed state is ignored; the last good one stays
        self.source.on_laser(msg.on or bool(msg.aim))  # type: ignore[attr-defined]

    def _on_gate(self, sample: Any) -> None:
        """Laser gate state from ``<prefix>/laser`` (``on``) or a robot status (``laser_on``)."""
        body = _small_json(sample)
        if body is not None and "on" in body:
            self._laser_states = True
        elif getattr(self, "_laser_states", False):
            return  # a status's laser_on is the treatment gate only: the LaserState says more
        on = body.get("on", body.get("laser_on")) if body else None
        if isinstance(on, bool) and body is not None and body.get("aim") is True:
            on = True  # the aiming beam is lit: the camera sees its spot
        if isinstance(on, bool):
            t = body.get("t") if body else None
            stamp = float(t) if isinstance(t, int | float) and np.isfinite(t) else time.time()
            self.source.on_gate(on, stamp)  # type: ignore[attr-defined]

    def _on_markers(self, query: Any) -> None:
        """Board markers as the camera sees them now (see the module docstring)."""
        body = _small_json(query) or {}
        try:
            with self._lock:
                found = self.source.markers(body)  # type: ignore[attr-defined]
            pts = np.asarray(found, dtype=np.float64)
            rows = [p.tolist() if np.all(np.isfinite(p)) else None for p in pts.reshape(-1, 3)]
            reply = {"t": time.time(), "points_camera": rows}
        except (InputError, ValueError, KeyError, TypeError, AttributeError) as exc:
            reply = {"error": str(exc)}
        query.reply(query.key_expr, json.dumps(reply).encode())

    def _on_predicted(self, sample: Any) -> None:
        body = _small_json(sample)
        p = body.get("p_camera") if body else None
        try:
            arr = np.asarray(p, dtype=float)
        except (TypeError, ValueError):
            return
        if arr.shape == (3,) and np.all(np.isfinite(arr)):
            self.source.on_predicted(arr, time.time())  # type: ignore[attr-defined]

    def _loop(self) -> None:
        next_t = time.monotonic()
        while not self._stop.is_set():
            self.publish_frame()
            next_t += self.period
            delay = next_t - time.monotonic()
            if delay > 0:
                self._stop.wait(delay)
            else:
                next_t = time.monotonic()  # late: do not try to catch up

    def publish_frame(self) -> None:
        """Grab one frame (blocks at the device rate for a real camera), publish its spot
        and, when due, its cloud."""
        with self._lock:
            self._publish_frame()

    def _publish_frame(self) -> None:
        if self.source.grab() is False:
            self.skipped += 1
            return
        frame_time = getattr(self.source, "frame_time", None)
        now = frame_time() if frame_time is not None else time.time()
        # the spot first: a simulated camera traces it from the joints it knows now, at the
        # frame's time, not after the (slower) cloud
        reading = self.source.spot()
        if reading is None:
            msg = SpotMessage(t=now, p_camera=None, confidence=0.0)
        else:
            msg = SpotMessage(
                t=now, p_camera=reading.p_camera.tolist(), confidence=reading.confidence
            )
        self._pub_spot.put(encode(msg))
        if self.frames % self._points_every == 0:
            pts, extra = self.source.points()
            pts = np.ascontiguousarray(pts, dtype=np.float32)
            meta = points_metadata(pts, now, self.frames, extra)
            self._pub_points.put(pts.tobytes(), attachment=json.dumps(meta).encode())
        self.frames += 1


def _small_json(sample: Any) -> dict[str, Any] | None:
    """A JSON object body (sample or query) of at most 64 KiB, or None."""
    try:
        payload = sample.payload
        if payload is None or len(payload) > 65536:
            return None
        body = json.loads(payload.to_bytes())
    except (ValueError, UnicodeDecodeError):
        return None
    return body if isinstance(body, dict) else None
