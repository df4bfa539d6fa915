"""The ROS 2 bridge node: beamrelay's bus republished the way rmw_zenoh publishes.

:class:`Ros2Bridge` runs in its own process (``beamrelay ros2 bridge``, or ``beamrelay up
--ros2``), or in a process of the system for that process's own topics (``serve|driver
robot|driver camera --ros2``: :class:`Parts`, :func:`start_in_process`), always on its own
Zenoh session and thread: nothing on the drivers' control loops or the planner's request
path waits for it. Bus callbacks only store the latest state
(:class:`planner.console.live.LiveState`, plus the last plan's targets); one publishing
thread converts and publishes at fixed rates:

- ``/<robot>/joint_states`` (``sensor_msgs/msg/JointState``) and ``/tf`` (base -> flange)
  at ``rate`` Hz whenever a robot reported new joints;
- ``/<robot>/joint_trajectory`` (``trajectory_msgs/msg/JointTrajectory``): each trajectory
  the planner sends a driver (executing), stamped when the bridge saw it;
- ``/<robot>/planned_trajectory`` (the same type): the trajectory of each timed plan on
  ``<prefix>/plans`` (planned, executed or not: a preview shows here before it moves);
- ``/tf_static`` every ``STATIC_PERIOD`` s (see below);
- ``/beamrelay/markers`` (``visualization_msgs/msg/MarkerArray``) at ``MARKER_RATE`` Hz;
- ``/camera/points`` (``sensor_msgs/msg/PointCloud2``, ``camera`` frame), the newest cloud
  at most ``CLOUD_RATE`` Hz (with a camera in the scenario);
- ``/beamrelay/laser/treatment`` and ``/beamrelay/laser/aim`` (``std_msgs/msg/Bool``,
  transient-local: a late subscriber gets the last state): the laser gate as its driver
  last reported it, at every change and every ``STATIC_PERIOD`` s while the report is at
  most ``LASER_RECENT`` s old; nothing before the first report (no report is not "off"),
  and no aim topic value for a rig without an aiming beam.

It subscribes to ROS 2 targets (:mod:`planner.ros2.inputs`) and forwards them as
TargetRequests on the bus.

Every publisher and the node itself declare rmw_zenoh's liveliness tokens
(:mod:`planner.ros2.graph`), so ``ros2 node list`` / ``ros2 topic list`` on
``RMW_IMPLEMENTATION=rmw_zenoh_cpp`` see them; every sample carries rmw_zenoh's attachment.
``/tf_static`` is transient-local (as tf2 expects): an advanced publisher whose cache a
late subscriber queries; it is also republished every ``STATIC_PERIOD`` s.
"""
# long module: one bridge node: its bus inputs, its publishing thread and the eight topics it converts share its latest-state store

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from planner.bus.session import JSON, Keys, decode, encode, open_session
from planner.console.live import LiveState
from planner.errors import InputError
from planner.model.scene import SceneModel
from planner.model.system import System
from planner.model.transforms import Array
from planner.ros2 import cell
from planner.ros2 import messages as m
from planner.ros2.graph import (
    LATCHED,
    VOLATILE,
    Durability,
    Node,
    Qos,
    attachment,
    gid,
    topic_key,
)
from planner.ros2.inputs import INPUTS, target_request
from schemas.messages import JointTrajectory
from schemas.points import decode_points

log = logging.getLogger(__name__)

NODE_NAME = "beamrelay_bridge"
DEFAULT_RATE = 100.0  # Hz, joint states and /tf
MARKER_RATE = 10.0  # Hz
STATIC_PERIOD = 1.0  # s between /tf_static republications
MARKER_TOPIC = "/beamrelay/markers"
CLOUD_TOPIC = "/camera/points"
CLOUD_RATE = 5.0  # Hz at most
LASER_RECENT = 1.0  # s: a laser state older than this is not republished
INBOX = 16  # ROS 2 target messages kept between two publishing periods (older dropped)
DEFAULT_KEYS = Keys()


def joint_states_topic(robot: str) -> str:
    return f"/{robot}/joint_states"


def trajectory_topic(robot: str) -> str:
    return f"/{robot}/joint_trajectory"


def planned_topic(robot: str) -> str:
    return f"/{robot}/planned_trajectory"


@dataclass
class Topic:
    """One ROS publisher: its data key, liveliness token and rmw_zenoh attachment state."""

    name: str
    ros_type: str
    key: str
    token: str
    gid: bytes
    qos: Qos = VOLATILE
    seq: int = 0
    handles: list[Any] = field(default_factory=list)

    def publish(self, msg: Any, t: float) -> None:
        self.seq += 1
        body = m.serialize(msg, self.ros_type)
        self.handles[0].put(body, attachment=attachment(self.seq, round(t * 1e9), self.gid))


def _publisher(session: Any, topic: Topic) -> Any:
    """A Zenoh publisher for ``topic``; transient-local ones are advanced publishers with a
    cache of ``depth`` samples that late subscribers query (rmw_zenoh's design: "a Zenoh
    advanced publisher will be created with a publication cache")."""
    if topic.qos.durability is not Durability.TRANSIENT_LOCAL:
        return session.declare_publisher(topic.key)
    import zenoh.ext

    cache = zenoh.ext.CacheConfig(max_samples=topic.qos.depth)
    # sequence numbers (sample-miss detection) order the cache: no session timestamping needed
    return zenoh.ext.declare_advanced_publisher(
        session,
        topic.key,
        cache=cache,
        sample_miss_detection=zenoh.ext.MissDetectionConfig(
            heartbeat=None, sporadic_heartbeat=None
        ),
        publisher_detection=True,
    )


@dataclass(frozen=True)
class Parts:
    """What one bridge publishes, as the ROS 2 node ``node``: the joint states, ``/tf`` and
    joint trajectories of ``robots`` (None: every robot), ``/tf_static``, the markers, the
    camera cloud, the laser state, and whether it takes ROS 2 targets in."""

    node: str = NODE_NAME
    robots: tuple[str, ...] | None = None
    planned: bool = True  # every robot's planned trajectory, from the plans
    static: bool = True
    markers: bool = True
    cloud: bool = True
    laser: bool = True
    inputs: bool = True

    @classmethod
    def planner(cls) -> Parts:
        """``serve --ros2``: the planned trajectories, the cell's fixed frames, the markers,
        ROS 2 targets in."""
        return cls("beamrelay_planner", robots=(), cloud=False, laser=False)

    @classmethod
    def robot(cls, name: str, gate: bool) -> Parts:
        """``driver robot --name NAME --ros2``: that robot's joint states, ``/tf`` and the
        trajectories it is sent; the laser state if its output is the gate."""
        return cls(f"beamrelay_{name}", robots=(name,), planned=False, static=False,
                   markers=False, cloud=False, laser=gate, inputs=False)  # fmt: skip

    @classmethod
    def camera(cls) -> Parts:
        """``driver camera --ros2``: the cloud."""
        return cls("beamrelay_camera", robots=(), planned=False, static=False, markers=False,
                   laser=False, inputs=False)  # fmt: skip


class Ros2Bridge:
    """See the module docstring. ``start`` declares everything, ``close`` undoes it."""

    def __init__(
        self,
        session: Any,
        system: System,
        scene: SceneModel | None,
        *,
        keys: Keys = DEFAULT_KEYS,
        domain: int = 0,
        rate: float = DEFAULT_RATE,
        parts: Parts = Parts(),
    ) -> None:
        if not 0 <= domain <= 232:
            raise ValueError(f"ROS domain id {domain} is outside 0..232")
        if not 1.0 <= rate <= 1000.0:
            raise ValueError(f"ROS 2 publishing rate {rate} Hz is outside 1..1000 Hz")
        self.session, self.system, self.scene = session, system, scene
        self.keys, self.domain, self.period = keys, domain, 1.0 / rate
        self.parts = parts
        self.node = Node(domain, str(session.info.zid()), parts.node)
        self.live = LiveState(keys)
        self.targets: Array | None = None
        self.published = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._node_token: Any = None
        self._plans_sub: Any = None
        self._traj_sub: Any = None
        self._targets_pub: Any = None
        self.topics: dict[str, Topic] = {}
        robots = system.robot_names if parts.robots is None else parts.robots
        for r in robots:
            self._topic(joint_states_topic(r), m.JOINT_STATE)
            self._topic(trajectory_topic(r), m.JOINT_TRAJECTORY)
        self._trajectories: dict[str, bytes] = {}  # robot -> newest raw body not yet sent
        self._plan_body: bytes | None = None  # the newest plan not yet published
        if robots:
            self._topic("/tf", m.TF_MESSAGE)
        if parts.static:
            self._topic("/tf_static", m.TF_MESSAGE, LATCHED)
        if parts.markers:
            self._topic(MARKER_TOPIC, m.MARKER_ARRAY)
        if parts.laser:
            for name in m.LASER_TOPICS.values():
                self._topic(name, m.BOOL, LATCHED)
        self._laser: tuple[bool, bool] | None = None  # the last (on, aim) published
        self.inputs: dict[str, Topic] = {}
        for inp in INPUTS if parts.inputs else ():
            h = m.type_hash(inp.ros_type)
            token = self.node.subscription_token(self._next_id(), inp.topic, inp.ros_type, h)
            key = topic_key(self.domain, inp.topic, inp.ros_type, h)
            self.inputs[inp.topic] = Topic(inp.topic, inp.ros_type, key, token, gid(token))
        self._inbox: deque[tuple[str, bytes]] = deque(maxlen=INBOX)
        self.requests = self.rejected = 0
        if system.camera is not None and parts.cloud:
            self._topic(CLOUD_TOPIC, m.POINT_CLOUD2)
        self._cloud_seq = 0
        if parts.planned:  # last: the entity ids of the topics above stay as they were
            for r in system.robot_names:
                self._topic(planned_topic(r), m.JOINT_TRAJECTORY)

    def _next_id(self) -> int:
        return len(self.topics) + len(getattr(self, "inputs", {})) + 1

    def _topic(self, name: str, ros_type: str, qos: Qos = VOLATILE) -> None:
        h = m.type_hash(ros_type)
        token = self.node.publisher_token(self._next_id(), name, ros_type, h, qos)
        key = topic_key(self.domain, name, ros_type, h)
        self.topics[name] = Topic(name, ros_type, key, token, gid(token), qos)

    def start(self) -> None:
        s = self.session
        self._node_token = s.liveliness().declare_token(self.node.token())
        for topic in self.topics.values():
            topic.handles = [_publisher(s, topic), s.liveliness().declare_token(topic.token)]
        for inp in self.inputs.values():
            inp.handles = [
                s.declare_subscriber(inp.key, self._on_input(inp.name)),
                s.liveliness().declare_token(inp.token),
            ]
        if self.inputs:
            self._targets_pub = s.declare_publisher(self.keys.targets)
        self.live.subscribe(s)
        if MARKER_TOPIC in self.topics or self.parts.planned:
            self._plans_sub = s.declare_subscriber(self.keys.plans, self._on_plan)
        if any(t.endswith("/joint_trajectory") for t in self.topics):
            self._traj_sub = s.declare_subscriber(self.keys.trajectory("*"), self._on_trajectory)
        self._thread = threading.Thread(target=self._run, name="ros2-bridge", daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        self.live.close()
        entities = [*self.topics.values(), *self.inputs.values()]
        handles = [h for t in entities for h in t.handles]
        for h in [self._plans_sub, self._traj_sub, self._targets_pub, *handles, self._node_token]:
            if h is not None:
                h.undeclare()
        for t in entities:
            t.handles = []
        self._plans_sub = self._traj_sub = self._targets_pub = self._node_token = None
        self._thread = None

    def _on_plan(self, sample: Any) -> None:
        body = sample.payload.to_bytes()
        pts = cell.plan_targets(body)
        if pts is not None:  # else a tracking summary: keep the last targets
            with self._lock:
                self.targets = pts
                self._plan_body = body  # its trajectory is parsed on the publishing thread

    def publish_planned(self) -> None:
        """The newest plan's trajectory (a timed plan's ``trajectory``), per robot, as
        JointTrajectory on ``/<robot>/planned_trajectory``; an untimed plan has none."""
        with self._lock:
            body, self._plan_body = self._plan_body, None
        if body is None or not self.parts.planned:
            return
        traj = cell.plan_trajectory(body)
        if traj is None:
            return
        t = time.time()
        for robot in self.system.robots:
            if robot.name in traj.q and planned_topic(robot.name) in self.topics:
                msg = m.joint_trajectory(t, list(robot.joint_names), traj.t, traj.q[robot.name],
                                         traj.qd[robot.name], traj.qdd[robot.name])  # fmt: skip
                self.topics[planned_topic(robot.name)].publish(msg, t)

    def _on_trajectory(self, sample: Any) -> None:
        robot = str(sample.key_expr).split("/")[-2]
        if trajectory_topic(robot) in self.topics:
            with self._lock:  # parsed on the publishing thread, never in the callback
                self._trajectories[robot] = sample.payload.to_bytes()

    def _on_input(self, topic: str) -> Any:
        def cb(sample: Any) -> None:  # stored only; converted on the publishing thread
            self._inbox.append((topic, sample.payload.to_bytes()))

        return cb

    def forward_targets(self) -> None:
        """Each ROS 2 target message received since the last call, as a TargetRequest on
        ``<prefix>/targets`` (planned, not executed); bad ones are counted and logged."""
        while self._inbox:
            topic, body = self._inbox.popleft()
            self.requests += 1
            try:
                req = target_request(self.inputs[topic].ros_type, body, f"ros2-{self.requests}")
            except ValueError as exc:
                self.rejected += 1
                log.warning("ROS 2 %s refused: %s", topic, exc)
                continue
            self._targets_pub.put(encode(req), encoding=JSON)

    def publish_trajectories(self) -> None:
        """Each trajectory a robot was sent since the last call, as JointTrajectory."""
        with self._lock:
            bodies, self._trajectories = self._trajectories, {}
        for robot, body in bodies.items():
            try:
                traj = decode(body, JointTrajectory)
            except InputError:
                continue  # the driver rejects it too
            t = time.time()
            msg = m.joint_trajectory(t, traj.names, traj.t, traj.q, traj.qd, traj.qdd)
            self.topics[trajectory_topic(robot)].publish(msg, t)

    # publishing thread ------------------------------------------------------------------------
    def _run(self) -> None:
        next_static = next_markers = next_cloud = 0.0
        seen: dict[str, float] = {}
        due = time.monotonic()
        while not self._stop.wait(max(0.0, due - time.monotonic())):
            now = time.monotonic()
            due = max(due + self.period, now)  # fixed rate; no catching up after a stall
            try:
                self._publish_joints(seen)
                self.publish_trajectories()
                self.publish_planned()
                self.forward_targets()
                periodic = now >= next_static
                if periodic:
                    if "/tf_static" in self.topics:
                        self.publish_static()
                    next_static = now + STATIC_PERIOD
                if self.parts.laser:
                    self.publish_laser(force=periodic)
                if now >= next_markers and MARKER_TOPIC in self.topics:
                    self.publish_markers()
                    next_markers = now + 1.0 / MARKER_RATE
                if now >= next_cloud and CLOUD_TOPIC in self.topics:
                    self.publish_cloud()
                    next_cloud = now + 1.0 / CLOUD_RATE
            except Exception:  # a bad state must not end the bridge
                log.exception("ROS 2 bridge: publishing failed")

    def _publish_joints(self, seen: dict[str, float]) -> None:
        fresh = {r: s for r, s in self.live.joint_states().items() if seen.get(r) != s.at}
        q: dict[str, Array] = {}
        for robot, stamped in fresh.items():
            if joint_states_topic(robot) not in self.topics:
                continue
            js = stamped.value
            seen[robot] = stamped.at
            q[robot] = np.asarray(js.q, dtype=float)
            msg = m.joint_state(js.t, js.names, js.q, js.qd)
            self.topics[joint_states_topic(robot)].publish(msg, js.t)
        if q:
            t = time.time()
            self.topics["/tf"].publish(cell.tf_message(t, cell.moving_frames(self.system, q)), t)
            self.published += 1

    def publish_static(self) -> None:
        t = time.time()
        self.topics["/tf_static"].publish(cell.tf_message(t, cell.static_frames(self.system)), t)

    def publish_laser(self, force: bool = False) -> None:
        """The newest LaserState as the Bool topics, when it changed, or with ``force`` while
        it is recent (a driver reports with every status; an old report is not repeated as
        if it were news: std_msgs/Bool carries no time). The aim topic only for a rig with an
        aiming beam (``aim`` None: no such beam, not "off")."""
        stamped = self.live.snapshot()["laser"]
        if stamped is None:
            return  # never reported: unknown, not off
        laser = stamped.value
        state = (bool(laser.on), bool(laser.aim))
        recent = time.monotonic() - stamped.at <= LASER_RECENT
        if state == self._laser and not (force and recent):
            return
        self._laser = state
        for topic, msg in m.laser_messages(*state):
            if topic == m.LASER_TOPICS["aim"] and laser.aim is None:
                continue
            self.topics[topic].publish(msg, float(laser.t))

    def publish_cloud(self) -> None:
        """The newest camera cloud, if new, as PointCloud2 in the ``camera`` frame."""

        self._cloud_seq, sample = self.live.take_points(self._cloud_seq)
        if sample is None:
            return
        try:
            rows, meta = decode_points(*sample)
        except InputError:
            return  # LiveState keeps raw bodies; a malformed one is dropped here
        t = float(meta.get("t", time.time()))
        msg = m.point_cloud(t, cell.CAMERA, rows, list(meta["fields"]))
        self.topics[CLOUD_TOPIC].publish(msg, t)

    def publish_markers(self) -> None:
        robots = self.system.robot_names
        q = self.live.joint_vector(robots) or {}
        snap = self.live.snapshot()
        laser = snap["laser"].value if snap["laser"] is not None else None
        spot = snap["spot"].value if snap["spot"] is not None else None
        with self._lock:
            targets = self.targets
        beam = cell.Beam(on=bool(laser and laser.on), aim=bool(laser and laser.aim))
        spot_world = None
        if spot is not None and spot.p_camera is not None:
            spot_world = cell.spot_in_world(self.system, q, np.asarray(spot.p_camera))
        t = time.time()
        msg = cell.markers(t, self.system, self.scene, q, beam=beam, targets=targets,
                           spot_world=spot_world)  # fmt: skip
        self.topics[MARKER_TOPIC].publish(msg, t)


@dataclass
class InProcess:
    """A started bridge on a session of its own (see :func:`start_in_process`)."""

    bridge: Ros2Bridge
    session: Any

    def close(self) -> None:
        """Stop the bridge (its tokens go away) and close its session."""
        self.bridge.close()
        self.session.close()


def start_in_process(
    system: System,
    scene: SceneModel | None,
    parts: Parts,
    *,
    domain: int,
    keys: Keys,
    endpoint: str | None,
    zenoh_config: Any = None,
) -> InProcess:
    """A bridge for one process's own topics (``--ros2`` on ``serve`` and the drivers), on a
    session of its own connected to ``endpoint`` (the bus the process is on), started."""

    session = open_session(listen=False, endpoint=endpoint, config_file=zenoh_config)
    bridge = Ros2Bridge(session, system, scene, keys=keys, domain=domain, parts=parts)
    bridge.start()
    return InProcess(bridge, session)
