"""Recording the bus to MCAP and playing it back (``beamrelay record`` / ``beamrelay replay``).

File layout (MCAP, profile ``beamrelay``; opens in Foxglove Studio):

- one channel per key expression seen (topic = the key, e.g. ``beamrelay/arm0/joint_states``);
  JSON samples (encoding ``application/json``, or a body that parses as a JSON object) use
  message encoding ``json`` (schemaless), everything else ``beamrelay.bytes``; a sample
  with a Zenoh attachment (``camera/points`` metadata) uses ``beamrelay.attached``: data =
  4-byte big-endian attachment length, attachment, payload;
- with a ROS 2 translator (``record --ros2``, :mod:`planner.ros2.recording`): ROS 2 channels
  beside the raw ones (topics ``/<robot>/joint_states``, ``/<robot>/joint_trajectory``,
  ``/tf``, ``/tf_static``, ``/camera/points``, ``/beamrelay/markers``; schema
  encoding ``ros2msg``, message encoding ``cdr``), which ``replay`` skips;
- liveliness: token appearances and disappearances as JSON ``{"alive": bool}`` messages on
  the topic ``@liveliness/<key>``;
- ``<prefix>/camera/points`` (the point cloud: ~97 % of the bytes at its 15 Hz, 12 MB in
  5 s of the simulated cell) is kept at most ``cloud_rate`` times a second (default 1 Hz;
  0 keeps every cloud), the clouds in between are counted, not written; chunks are
  zstd-compressed;
- ``log_time`` = the UNIX ns the recorder received the sample, ``publish_time`` = the
  sample's Zenoh timestamp when it has one (else the receive time); ``sequence`` counts
  every message of the file from 0.

Replay publishes every message on its key in ``log_time`` order, at the original pace
divided by ``speed`` (``speed = 0``: as fast as possible), with the original bytes,
encoding and attachment. Liveliness tokens are re-declared and withdrawn as recorded.
Command keys (trajectories, setpoints, heartbeats, stop, recover, targets) are skipped
unless ``commands=True``: a replay onto a bus with a real arm must not move it, and even
then it is refused while any robot driver token is alive on the bus.
"""

from __future__ import annotations

import json
import struct
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, BinaryIO, NamedTuple

from planner.errors import InputError

PROFILE = "beamrelay"
LIVELINESS = "@liveliness/"
COMMAND_SUFFIXES = ("/trajectory", "/setpoint", "/heartbeat", "/stop", "/recover", "/targets")
_LEN = struct.Struct(">I")


class Recorded(NamedTuple):
    """One message of a recording: key, payload bytes, encoding, attachment, times (ns)."""

    key: str
    payload: bytes
    encoding: str
    attachment: bytes | None
    log_time: int
    sequence: int


CLOUD_SUFFIX = "/camera/points"
#: Hz: point clouds kept per second by default (the camera publishes 15)
CLOUD_RATE = 1.0
ROS_ENCODING = "cdr"


class Recorder:
    """Subscribes ``<prefix>/**`` (and its liveliness) and writes an MCAP file until closed;
    point clouds at most ``cloud_rate`` Hz (0: all), the others counted in ``clouds_dropped``.

    ``ros``: a translator (:class:`planner.ros2.recording.RosTranslator`) whose ROS 2
    messages are written beside the raw samples."""

    def __init__(self, session: Any, prefix: str, out: BinaryIO,
                 cloud_rate: float = CLOUD_RATE, ros: Any = None) -> None:  # fmt: skip
        from mcap.writer import CompressionType, Writer

        self.writer = Writer(out, compression=CompressionType.ZSTD)
        self.writer.start(profile=PROFILE, library="beamrelay")
        self.channels: dict[tuple[str, str], int] = {}
        self.schemas: dict[str, int] = {}
        self.count = 0
        self.clouds_dropped = 0
        self._cloud_period = 1.0 / cloud_rate if cloud_rate > 0 else 0.0
        self._cloud_last = -float("inf")
        self.ros = ros
        self._lock = threading.Lock()
        self._closed = False
        if ros is not None:
            for msg in ros.static(time.time()):
                self._write_ros(msg, time.time_ns())
        self._handles = [
            session.declare_subscriber(f"{prefix}/**", self._on_sample),
            session.liveliness().declare_subscriber(f"{prefix}/**", self._on_token, history=True),
        ]

    def _channel(self, topic: str, encoding: str, zenoh_encoding: str) -> int:
        ch = self.channels.get((topic, encoding))
        if ch is None:
            meta = {"zenoh_encoding": zenoh_encoding}
            ch = self.writer.register_channel(topic, encoding, 0, meta)
            self.channels[(topic, encoding)] = ch
        return ch

    def _write(self, topic: str, encoding: str, zenc: str, data: bytes, stamp: Any) -> None:
        now = time.time_ns()
        pub = now
        if stamp is not None:
            pub = int(stamp.get_time().timestamp() * 1e9)
        with self._lock:
            if self._closed:
                return
            ch = self._channel(topic, encoding, zenc)
            self.writer.add_message(ch, now, data, pub, self.count)
            self.count += 1

    def _keep_cloud(self) -> bool:
        """Whether a point cloud arriving now is written (at most one per cloud period)."""
        now = time.monotonic()
        with self._lock:
            if now - self._cloud_last < self._cloud_period:
                self.clouds_dropped += 1
                return False
            self._cloud_last = now
            return True

    def _write_ros(self, msg: Any, now: int) -> None:
        """One ROS 2 message (topic, ros_type, CDR data) on its ``cdr`` channel."""
        with self._lock:
            if self._closed:
                return
            ch = self.channels.get((msg.topic, ROS_ENCODING))
            if ch is None:
                schema = self.schemas.get(msg.ros_type)
                if schema is None:
                    text = self.ros.schema(msg.ros_type).encode()
                    schema = self.writer.register_schema(msg.ros_type, "ros2msg", text)
                    self.schemas[msg.ros_type] = schema
                ch = self.writer.register_channel(msg.topic, ROS_ENCODING, schema)
                self.channels[(msg.topic, ROS_ENCODING)] = ch
            self.writer.add_message(ch, now, msg.data, now, self.count)
            self.count += 1

    def _on_sample(self, sample: Any) -> None:
        if str(sample.key_expr).endswith(CLOUD_SUFFIX) and not self._keep_cloud():
            return
        payload = sample.payload.to_bytes()
        zenc = str(sample.encoding)
        att = sample.attachment
        if att is not None:
            a = att.to_bytes()
            data, enc = _LEN.pack(len(a)) + a + payload, "beamrelay.attached"
        else:
            data, enc = payload, ("json" if _is_json(zenc, payload) else "beamrelay.bytes")
        self._write(str(sample.key_expr), enc, zenc, data, sample.timestamp)
        if self.ros is not None:
            now = time.time_ns()
            a = None if att is None else att.to_bytes()
            for msg in self.ros(str(sample.key_expr), payload, a):
                self._write_ros(msg, now)

    def _on_token(self, sample: Any) -> None:
        import zenoh

        alive = sample.kind == zenoh.SampleKind.PUT
        body = json.dumps({"alive": alive}).encode()
        self._write(LIVELINESS + str(sample.key_expr), "json", "application/json", body, None)

    def close(self) -> int:
        """Stop recording, finish the file; the number of messages written."""
        for h in self._handles:
            h.undeclare()
        with self._lock:
            self._closed = True
            self.writer.finish()
        return self.count


def _is_json(zenoh_encoding: str, payload: bytes) -> bool:
    if zenoh_encoding.startswith("application/json"):
        return True
    if payload[:1] != b"{":
        return False
    try:
        return isinstance(json.loads(payload), dict)
    except (ValueError, UnicodeDecodeError):
        return False


def read(path: Path) -> Iterator[Recorded]:
    """The messages of a recording in ``log_time`` order (InputError for a bad file)."""
    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    try:
        with path.open("rb") as f:
            reader = make_reader(f)
            for _, channel, msg in reader.iter_messages(log_time_order=True):
                if channel.message_encoding == ROS_ENCODING:
                    continue  # derived ROS 2 copies: the raw channel is replayed
                zenc = channel.metadata.get("zenoh_encoding", "")
                data, att = msg.data, None
                if channel.message_encoding == "beamrelay.attached":
                    (n,) = _LEN.unpack_from(data)
                    att, data = data[4 : 4 + n], data[4 + n :]
                yield Recorded(channel.topic, data, zenc, att, msg.log_time, msg.sequence)
    except (McapError, struct.error, EOFError, ValueError) as exc:
        raise InputError(f"not a readable MCAP recording: {exc}", str(path)) from exc


def is_command(key: str) -> bool:
    return key.endswith(COMMAND_SUFFIXES)


def replay(
    session: Any,
    path: Path,
    *,
    speed: float = 1.0,
    commands: bool = False,
    stop: threading.Event | None = None,
    on_message: Callable[[Recorded], None] | None = None,
) -> tuple[int, int]:
    """Publish a recording onto the bus (see the module docstring); (published, skipped)."""
    if commands:
        live = [r.ok.key_expr for r in session.liveliness().get("**/alive/*", timeout=1.0)]
        robots = [str(k) for k in live if not str(k).endswith(("/planner", "/camera"))]
        if robots:
            raise InputError(
                f"robot drivers are alive on this bus ({', '.join(robots)}): "
                "refusing to replay commands onto it",
                "--commands",
            )
    tokens: dict[str, Any] = {}
    sent = skipped = 0
    t_rec0: int | None = None
    t_wall0 = time.monotonic()
    try:
        for m in read(path):
            if stop is not None and stop.is_set():
                break
            if t_rec0 is None:
                t_rec0 = m.log_time
            if speed > 0:
                due = t_wall0 + (m.log_time - t_rec0) / 1e9 / speed
                if (wait := due - time.monotonic()) > 0:
                    time.sleep(wait)
            if not commands and is_command(m.key):
                skipped += 1
                continue
            _publish(session, m, tokens)
            sent += 1
            if on_message is not None:
                on_message(m)
    finally:
        for tok in tokens.values():
            tok.undeclare()
    return sent, skipped


def _publish(session: Any, m: Recorded, tokens: dict[str, Any]) -> None:
    if m.key.startswith(LIVELINESS):
        key = m.key[len(LIVELINESS) :]
        alive = json.loads(m.payload).get("alive", False)
        if alive and key not in tokens:
            tokens[key] = session.liveliness().declare_token(key)
        elif not alive and key in tokens:
            tokens.pop(key).undeclare()
        return
    kw: dict[str, Any] = {}
    if m.encoding:
        kw["encoding"] = m.encoding
    if m.attachment is not None:
        kw["attachment"] = m.attachment
    session.put(m.key, m.payload, **kw)
