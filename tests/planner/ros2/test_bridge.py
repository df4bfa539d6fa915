"""The bridge seen from outside: a raw Zenoh subscriber on rmw_zenoh's documented key
pattern (``<domain_id>/<fully_qualified_name>/<type_name>/<type_hash>``, ros2/rmw_zenoh
docs/design.md) receives the messages; rosbags' own deserializer decodes them; the values
are the beamrelay messages they came from. The liveliness tokens are read back with a
liveliness query on ``@ros2_lv/<domain_id>/**`` and compared with strings written from the
document's format."""

from __future__ import annotations

import json
import threading
import time
from typing import Any

import numpy as np
import pytest

from planner.bus.session import Keys, encode, open_session
from planner.model.system import System
from planner.ros2 import messages as m
from planner.ros2.bridge import Ros2Bridge
from planner.ros2.graph import parse_attachment
from schemas.messages import JointState, JointTrajectory
from tests.drivers.conftest import wait_for
from tests.planner.raw_zenoh import raw_session
from tests.planner.ros2.test_messages import PUBLISHED

DOMAIN = 7
JOINT_STATE_HASH = PUBLISHED["sensor_msgs/msg/JointState"]
TF_HASH = PUBLISHED["tf2_msgs/msg/TFMessage"]
# no published values found for these: rosbags' REP-2016 hashes
MARKER_HASH = m.type_hash(m.MARKER_ARRAY)
TRAJ_HASH = m.type_hash(m.JOINT_TRAJECTORY)
POINT_HASH = m.type_hash("geometry_msgs/msg/PointStamped")
POSES_HASH = m.type_hash("geometry_msgs/msg/PoseArray")
TRAJ_KEY = (
    f"{DOMAIN}/arm0/joint_trajectory/trajectory_msgs::msg::dds_::JointTrajectory_/{TRAJ_HASH}"
)
JS_KEY = f"{DOMAIN}/arm0/joint_states/sensor_msgs::msg::dds_::JointState_/{JOINT_STATE_HASH}"
TF_KEY = f"{DOMAIN}/tf/tf2_msgs::msg::dds_::TFMessage_/{TF_HASH}"
STATIC_KEY = f"{DOMAIN}/tf_static/tf2_msgs::msg::dds_::TFMessage_/{TF_HASH}"
MARKER_KEY = f"{DOMAIN}/beamrelay/markers/visualization_msgs::msg::dds_::MarkerArray_/{MARKER_HASH}"
BOOL_HASH = PUBLISHED["std_msgs/msg/Bool"]
LASER_KEYS = {k: f"{DOMAIN}{topic}/std_msgs::msg::dds_::Bool_/{BOOL_HASH}"
              for k, topic in m.LASER_TOPICS.items()}  # fmt: skip


class Received:
    def __init__(self) -> None:
        self.samples: dict[str, list[tuple[bytes, bytes | None]]] = {}
        self.lock = threading.Lock()

    def __call__(self, sample: Any) -> None:
        att = sample.attachment.to_bytes() if sample.attachment is not None else None
        with self.lock:
            self.samples.setdefault(str(sample.key_expr), []).append(
                (sample.payload.to_bytes(), att)
            )

    def get(self, key: str) -> list[tuple[bytes, bytes | None]]:
        with self.lock:
            return list(self.samples.get(key, []))


def test_bridge_publishes_rmw_zenoh_topics_and_tokens(system1: System, endpoint: str) -> None:
    hub = open_session(listen=True, endpoint=endpoint)
    raw = raw_session(endpoint)
    bridge = Ros2Bridge(hub, system1, None, domain=DOMAIN, rate=200.0)
    received = Received()
    sub = raw.declare_subscriber(f"{DOMAIN}/**", received)
    driver = raw.declare_publisher(Keys().joint_states("arm0"))
    planner = raw.declare_publisher(Keys().trajectory("arm0"))
    names = list(system1.robots[0].joint_names)
    js = JointState(t=1_700_000_123.5, names=names, q=[0.1, -1.4, 1.2, -0.3, -1.5, 0.2],
                    qd=[0.0, 0.01, -0.02, 0.0, 0.0, 0.03])  # fmt: skip
    try:
        bridge.start()
        deadline = time.monotonic() + 15.0
        keys = (JS_KEY, TF_KEY, STATIC_KEY, MARKER_KEY, TRAJ_KEY)
        traj = JointTrajectory(robot="arm0", t=[0.0, 0.5, 1.25], names=names,
                               q=[[0.1 * k] * 6 for k in range(3)],
                               qd=[[0.01 * k] * 6 for k in range(3)],
                               qdd=[[0.001 * k] * 6 for k in range(3)])  # fmt: skip

        def complete() -> bool:  # every topic, and markers drawn from the joint states
            if not all(received.get(k) for k in keys):
                return False
            last = m.deserialize(received.get(MARKER_KEY)[-1][0], m.MARKER_ARRAY).markers
            return any(mk.ns == "beam" for mk in last)

        while time.monotonic() < deadline and not complete():
            driver.put(encode(js))
            if not received.get(TRAJ_KEY):
                planner.put(encode(traj))
            time.sleep(0.02)
        missing = [k for k in keys if not received.get(k)]
        assert not missing, f"nothing on {missing}; got {sorted(received.samples)}"

        body, att = received.get(JS_KEY)[-1]
        got = m.deserialize(body, m.JOINT_STATE)
        assert got.name == names
        np.testing.assert_array_equal(got.position, js.q)
        np.testing.assert_array_equal(got.velocity, js.qd)
        assert got.header.stamp.sec == 1_700_000_123
        assert got.header.stamp.nanosec == 500_000_000
        assert att is not None
        seq, stamp_ns, gid = parse_attachment(att)
        assert seq >= 1 and len(gid) == 16 and abs(stamp_ns - 1_700_000_123.5e9) < 1e3

        (tf,) = m.deserialize(received.get(TF_KEY)[-1][0], m.TF_MESSAGE).transforms
        r = system1.robots[0]
        tr = tf.transform.translation
        expected = r.kinematics.fk(np.asarray(js.q))[:3, 3]
        np.testing.assert_allclose([tr.x, tr.y, tr.z], expected, atol=1e-12)
        static = m.deserialize(received.get(STATIC_KEY)[-1][0], m.TF_MESSAGE).transforms
        assert {(t.header.frame_id, t.child_frame_id) for t in static} == {
            ("world", "laser"), ("world", "arm0_base"), ("arm0_flange", "arm0_mirror"),
        }  # fmt: skip
        sent = m.deserialize(received.get(TRAJ_KEY)[-1][0], m.JOINT_TRAJECTORY)
        assert sent.joint_names == names
        starts = [(p.time_from_start.sec, p.time_from_start.nanosec) for p in sent.points]
        assert starts == [(0, 0), (0, 500_000_000), (1, 250_000_000)]
        for k, p in enumerate(sent.points):
            np.testing.assert_array_equal(p.positions, traj.q[k])
            np.testing.assert_array_equal(p.velocities, traj.qd[k])
            np.testing.assert_array_equal(p.accelerations, traj.qdd[k])
        markers = m.deserialize(received.get(MARKER_KEY)[-1][0], m.MARKER_ARRAY).markers
        assert [mk.ns for mk in markers[1:]] == ["mirrors", "beam"]

        zid = str(hub.info.zid())
        tokens = ros_tokens(raw)
        node = f"@ros2_lv/{DOMAIN}/{zid}/0/0/NN/%/%/beamrelay_bridge"
        prefix = f"@ros2_lv/{DOMAIN}/{zid}/0"
        assert tokens == {
            node,
            f"{prefix}/1/MP/%/%/beamrelay_bridge/%arm0%joint_states/"
            f"sensor_msgs::msg::dds_::JointState_/{JOINT_STATE_HASH}/::,10:,:,:,,",
            f"{prefix}/2/MP/%/%/beamrelay_bridge/%arm0%joint_trajectory/"
            f"trajectory_msgs::msg::dds_::JointTrajectory_/{TRAJ_HASH}/::,10:,:,:,,",
            f"{prefix}/3/MP/%/%/beamrelay_bridge/%tf/"
            f"tf2_msgs::msg::dds_::TFMessage_/{TF_HASH}/::,10:,:,:,,",
            f"{prefix}/4/MP/%/%/beamrelay_bridge/%tf_static/"
            f"tf2_msgs::msg::dds_::TFMessage_/{TF_HASH}/:1:,1:,:,:,,",
            f"{prefix}/5/MP/%/%/beamrelay_bridge/%beamrelay%markers/"
            f"visualization_msgs::msg::dds_::MarkerArray_/{MARKER_HASH}/::,10:,:,:,,",
            f"{prefix}/6/MP/%/%/beamrelay_bridge/%beamrelay%laser%treatment/"
            f"std_msgs::msg::dds_::Bool_/{BOOL_HASH}/:1:,1:,:,:,,",
            f"{prefix}/7/MP/%/%/beamrelay_bridge/%beamrelay%laser%aim/"
            f"std_msgs::msg::dds_::Bool_/{BOOL_HASH}/:1:,1:,:,:,,",
            f"{prefix}/8/MS/%/%/beamrelay_bridge/%beamrelay%target/"
            f"geometry_msgs::msg::dds_::PointStamped_/{POINT_HASH}/::,10:,:,:,,",
            f"{prefix}/9/MS/%/%/beamrelay_bridge/%beamrelay%targets/"
            f"geometry_msgs::msg::dds_::PoseArray_/{POSES_HASH}/::,10:,:,:,,",
            f"{prefix}/10/MP/%/%/beamrelay_bridge/%arm0%planned_trajectory/"
            f"trajectory_msgs::msg::dds_::JointTrajectory_/{TRAJ_HASH}/::,10:,:,:,,",
        }
        bridge.close()
        # the graph forgets the node when it closes (undeclarations propagate asynchronously)
        wait_for(lambda: ros_tokens(raw) == set(), 10.0, "the tokens to go")
    finally:
        bridge.close()
        sub.undeclare()
        driver.undeclare()
        planner.undeclare()
        raw.close()
        hub.close()


def ros_tokens(session: Any) -> set[str]:
    replies = session.liveliness().get(f"@ros2_lv/{DOMAIN}/**", timeout=2.0)
    return {str(r.ok.key_expr) for r in replies if r.ok is not None}


def test_bridge_publishes_the_camera_cloud_as_point_cloud2(endpoint: str) -> None:
    from planner.io.scenario import load_scenario, system_from_scenario
    from schemas.points import points_metadata
    from tests.paths import REPO

    system = system_from_scenario(load_scenario(REPO / "scenarios" / "paper_n1.yaml"))
    hub = open_session(listen=True, endpoint=endpoint)
    raw = raw_session(endpoint)
    bridge = Ros2Bridge(hub, system, None, domain=DOMAIN)
    received = Received()
    key = (f"{DOMAIN}/camera/points/sensor_msgs::msg::dds_::PointCloud2_/"
           f"{m.type_hash(m.POINT_CLOUD2)}")  # fmt: skip
    sub = raw.declare_subscriber(key, received)
    camera = raw.declare_publisher(Keys().camera_points)
    rows = np.arange(30, dtype=np.float32).reshape(10, 3) / 10
    meta = points_metadata(rows, 1_700_000_321.25, 4, {})
    try:
        bridge.start()
        deadline = time.monotonic() + 15.0
        while time.monotonic() < deadline and not received.get(key):
            camera.put(rows.tobytes(), attachment=json.dumps(meta).encode())
            time.sleep(0.05)
        assert received.get(key), "no PointCloud2"
        cloud = m.deserialize(received.get(key)[-1][0], m.POINT_CLOUD2)
        assert cloud.header.frame_id == "camera" and cloud.width == 10
        assert [f.name for f in cloud.fields] == ["x", "y", "z"]
        got = np.frombuffer(bytes(cloud.data), dtype="<f4").reshape(10, 3)
        np.testing.assert_array_equal(got, rows)
        assert (cloud.header.stamp.sec, cloud.header.stamp.nanosec) == (1_700_000_321, 250_000_000)
    finally:
        bridge.close()
        sub.undeclare()
        camera.undeclare()
        raw.close()
        hub.close()


def test_ros2_targets_become_target_requests(system1: System, endpoint: str) -> None:
    """A ROS 2 node's PointStamped / PoseArray (CDR by rosbags, on the documented keys) ->
    TargetRequests on beamrelay/targets, frame from the header; other frames are refused."""
    hub = open_session(listen=True, endpoint=endpoint)
    raw = raw_session(endpoint)
    bridge = Ros2Bridge(hub, system1, None, domain=DOMAIN)
    requests: list[dict[str, Any]] = []
    sub = raw.declare_subscriber(Keys().targets, lambda s: requests.append(json.loads(
        s.payload.to_bytes())))  # fmt: skip
    point_key = f"{DOMAIN}/beamrelay/target/geometry_msgs::msg::dds_::PointStamped_/{POINT_HASH}"
    poses_key = f"{DOMAIN}/beamrelay/targets/geometry_msgs::msg::dds_::PoseArray_/{POSES_HASH}"
    point = m.make("geometry_msgs/msg/PointStamped", header=m.header(1.0, "world"),
                   point=m.point([0.4, -0.1, 0.2]))  # fmt: skip
    elsewhere = m.make("geometry_msgs/msg/PointStamped", header=m.header(1.0, "map"),
                       point=m.point([1.0, 2.0, 3.0]))  # fmt: skip
    poses = m.make("geometry_msgs/msg/PoseArray", header=m.header(1.0, "camera"),
                   poses=[m.make("geometry_msgs/msg/Pose", position=m.point(p))
                          for p in ([0.0, 0.01, 0.5], [0.02, 0.0, 0.55])])  # fmt: skip
    try:
        bridge.start()
        deadline = time.monotonic() + 15.0
        while time.monotonic() < deadline and not requests:  # until the links are up
            raw.put(point_key, m.serialize(point, "geometry_msgs/msg/PointStamped"))
            time.sleep(0.1)
        assert requests, "no TargetRequest"
        raw.put(point_key, m.serialize(elsewhere, "geometry_msgs/msg/PointStamped"))
        raw.put(poses_key, m.serialize(poses, "geometry_msgs/msg/PoseArray"))
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline and requests[-1]["frame"] != "camera":
            time.sleep(0.05)
        first, last = requests[0], requests[-1]
        assert (first["frame"], first["points"], first["execute"]) == (
            "world",
            [[0.4, -0.1, 0.2]],
            False,
        )
        assert (last["frame"], last["points"]) == ("camera", [[0.0, 0.01, 0.5], [0.02, 0.0, 0.55]])
        assert all(r["frame"] in ("world", "camera") for r in requests)
        assert bridge.rejected == 1  # the "map" point
    finally:
        bridge.close()
        sub.undeclare()
        raw.close()
        hub.close()


def test_a_late_subscriber_gets_tf_static_from_the_publication_cache(
    system1: System, endpoint: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Transient local as rmw_zenoh does it: an advanced subscriber that joins after the one
    /tf_static sample (no republication within the test) still receives it, from the cache."""
    import zenoh.ext

    from planner.ros2 import bridge as bridge_module

    monkeypatch.setattr(bridge_module, "STATIC_PERIOD", 1e6)
    hub = open_session(listen=True, endpoint=endpoint)
    bridge = Ros2Bridge(hub, system1, None, domain=DOMAIN)
    raw = None
    received = Received()
    try:
        bridge.start()
        wait_for(lambda: bridge.topics["/tf_static"].seq == 1, 10.0, "the /tf_static sample")
        raw = raw_session(endpoint)
        history = zenoh.ext.HistoryConfig(detect_late_publishers=True)
        sub = zenoh.ext.declare_advanced_subscriber(raw, STATIC_KEY, received, history=history)
        wait_for(lambda: bool(received.get(STATIC_KEY)), 15.0, "the cached /tf_static")
        sub.undeclare()
        assert bridge.topics["/tf_static"].seq == 1  # it came from the cache
        tf = m.deserialize(received.get(STATIC_KEY)[0][0], m.TF_MESSAGE)
        assert {t.child_frame_id for t in tf.transforms} == {"laser", "arm0_base", "arm0_mirror"}
    finally:
        bridge.close()
        if raw is not None:
            raw.close()
        hub.close()


def test_bridge_publishes_the_laser_state_only_once_reported(
    system1: System, endpoint: str
) -> None:
    """No LaserState yet: nothing on the laser topics (unknown is not off). Then each
    reported state, decoded by rosbags as std_msgs/Bool, on the treatment and aim topics;
    a subscriber that joins later still gets the state in force (transient-local)."""
    import zenoh.ext

    from schemas.messages import LaserState

    hub = open_session(listen=True, endpoint=endpoint)
    raw = raw_session(endpoint)
    bridge = Ros2Bridge(hub, system1, None, domain=DOMAIN, rate=200.0)
    received = Received()
    sub = raw.declare_subscriber(f"{DOMAIN}/beamrelay/laser/**", received)
    driver = raw.declare_publisher(Keys().laser)
    late = None
    try:
        bridge.start()
        time.sleep(0.5)
        assert not any(received.get(k) for k in LASER_KEYS.values())

        def state(key: str) -> bool | None:
            got = received.get(LASER_KEYS[key])
            return None if not got else bool(m.deserialize(got[-1][0], m.BOOL).data)

        for on, aim in ((False, True), (True, False)):
            body = LaserState(robot="arm0", t=time.time(), on=on, aim=aim, output=0)
            deadline = time.monotonic() + 10.0
            while time.monotonic() < deadline and (state("on"), state("aim")) != (on, aim):
                driver.put(encode(body))
                time.sleep(0.05)
            assert (state("on"), state("aim")) == (on, aim)
        late_got = Received()
        late = zenoh.ext.declare_advanced_subscriber(
            raw, LASER_KEYS["on"], late_got,
            history=zenoh.ext.HistoryConfig(detect_late_publishers=True))  # fmt: skip
        wait_for(lambda: bool(late_got.get(LASER_KEYS["on"])), 10.0, "the cached laser state")
        assert m.deserialize(late_got.get(LASER_KEYS["on"])[0][0], m.BOOL).data is True
    finally:
        if late is not None:
            late.undeclare()
        bridge.close()
        sub.undeclare()
        driver.undeclare()
        raw.close()
        hub.close()


def test_a_timed_plan_is_published_as_each_robots_planned_trajectory(
    system1: System, endpoint: str
) -> None:
    """A plan.json with a trajectory on beamrelay/plans -> /arm0/planned_trajectory, decoded
    by rosbags: the plan's times, positions, velocities and accelerations, the robot's joint
    names; a plan without a trajectory (or garbage) publishes nothing."""
    hub = open_session(listen=True, endpoint=endpoint)
    raw = raw_session(endpoint)
    bridge = Ros2Bridge(hub, system1, None, domain=DOMAIN)
    got = Received()
    key = (
        f"{DOMAIN}/arm0/planned_trajectory/trajectory_msgs::msg::dds_::JointTrajectory_/{TRAJ_HASH}"
    )
    sub = raw.declare_subscriber(key, got)
    rng = np.random.default_rng(3)
    t = np.linspace(0.0, 0.9, 10)
    q, qd, qdd = (rng.normal(size=(10, 6)) for _ in range(3))
    plan = {"targets": [{"p": [0.1, 0.2, 0.3]}],
            "trajectory": {"t": t.tolist(), "q": {"arm0": q.tolist()}, "qd": {"arm0": qd.tolist()},
                           "qdd": {"arm0": qdd.tolist()}}}  # fmt: skip
    plans = raw.declare_publisher(Keys().plans)
    try:
        bridge.start()
        deadline = time.monotonic() + 15.0
        while time.monotonic() < deadline and not got.get(key):  # until the links are up
            plans.put(json.dumps(plan).encode())
            time.sleep(0.2)
        assert got.get(key), "no planned trajectory"
        n = len(got.get(key))
        plans.put(json.dumps({"targets": [{"p": [0, 0, 0]}], "trajectory": None}).encode())
        plans.put(b"\xff garbage")
        time.sleep(0.5)
        assert len(got.get(key)) == n
    finally:
        bridge.close()
        sub.undeclare()
        plans.undeclare()
        raw.close()
        hub.close()
    msg = m.deserialize(got.get(key)[0][0], m.JOINT_TRAJECTORY)
    assert list(msg.joint_names) == list(system1.robots[0].joint_names)
    assert len(msg.points) == 10
    for k, pt in enumerate(msg.points):
        assert pt.time_from_start.sec + 1e-9 * pt.time_from_start.nanosec == pytest.approx(t[k])
        np.testing.assert_array_equal(pt.positions, q[k])
        np.testing.assert_array_equal(pt.velocities, qd[k])
        np.testing.assert_array_equal(pt.accelerations, qdd[k])
