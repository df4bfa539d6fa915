"""``record --ros2``: ROS 2 channels in the MCAP file, read back with mcap and decoded with
mcap-ros2-support (an independent ros2msg/CDR decoder); ``replay``'s reader still sees only
the raw bus channels."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from drivers.record import Recorder, read
from planner.bus.session import Keys, encode, open_session
from planner.model.system import System
from planner.ros2 import messages as m
from planner.ros2.bridge import MARKER_TOPIC
from planner.ros2.recording import RosTranslator
from schemas.messages import JointState, JointTrajectory, LaserState
from schemas.points import points_metadata
from tests.drivers.conftest import wait_for


def test_recording_has_ros2_schemas_channels_and_tf_tree(
    system1: System, endpoint: str, tmp_path: Path
) -> None:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    prefix = "brros"
    hub = open_session(listen=True, endpoint=endpoint)
    path = tmp_path / "ros.mcap"
    out = path.open("wb")
    rec = Recorder(hub, prefix, out, ros=RosTranslator(Keys(prefix), system1))
    names = list(system1.robots[0].joint_names)
    sent = [
        JointState(t=1_700_000_000.0 + 0.01 * k, names=names, q=[0.1 * k, -1.5, 1.4, -1.6, -1.5, 0.0],
                   qd=[0.0] * 6)
        for k in range(5)
    ]  # fmt: skip
    traj = JointTrajectory(robot="arm0", t=[0.0, 0.25], names=names, q=[[0.0] * 6, [0.1] * 6],
                           qd=[[0.0] * 6] * 2, qdd=[[0.0] * 6] * 2)  # fmt: skip
    rows = np.arange(12, dtype=np.float32).reshape(4, 3)
    try:
        pub = hub.declare_publisher(Keys(prefix).joint_states("arm0"))
        laser = hub.declare_publisher(Keys(prefix).laser)
        time.sleep(0.2)
        laser.put(encode(LaserState(robot="arm0", t=sent[0].t, on=True)))
        wait_for(lambda: rec.count >= 2, 5.0)
        for js in sent:
            pub.put(encode(js))
        # per sample: raw + JointState + TF; markers once (10 Hz of the samples' 40 ms)
        wait_for(lambda: rec.count >= 2 + 3 * len(sent) + 1, 5.0)
        n = rec.count
        keys = Keys(prefix)
        hub.put(keys.trajectory("arm0"), encode(traj))
        hub.put(keys.camera_points, rows.tobytes(),
                attachment=json.dumps(points_metadata(rows, 5.0, 1, {})).encode())  # fmt: skip
        wait_for(lambda: rec.count >= n + 4, 5.0)  # two raw, two ROS 2
        pub.undeclare()
        laser.undeclare()
        rec.close()
    finally:
        out.close()
        hub.close()

    reader = make_reader(path.open("rb"), decoder_factories=[DecoderFactory()])
    summary = reader.get_summary()
    assert summary is not None
    schemas = {s.name: s.encoding for s in summary.schemas.values()}
    ros_types = ["sensor_msgs/msg/JointState", "tf2_msgs/msg/TFMessage",
                 "visualization_msgs/msg/MarkerArray", "trajectory_msgs/msg/JointTrajectory",
                 "sensor_msgs/msg/PointCloud2", "std_msgs/msg/Bool"]  # fmt: skip
    assert schemas == dict.fromkeys(ros_types, "ros2msg")
    channels = {c.topic: c.message_encoding for c in summary.channels.values()}
    raw = {
        f"{prefix}/arm0/joint_states": "json",
        f"{prefix}/laser": "json",
        f"{prefix}/arm0/trajectory": "json",
        f"{prefix}/camera/points": "beamrelay.attached",
    }
    ros = ["/arm0/joint_states", "/tf", "/tf_static", "/beamrelay/markers",
           "/arm0/joint_trajectory", "/camera/points", "/beamrelay/laser/treatment"]  # fmt: skip
    assert channels == {**raw, **dict.fromkeys(ros, "cdr")}

    decoded: dict[str, list] = {}
    for _, channel, _, msg in reader.iter_decoded_messages(topics=ros):
        decoded.setdefault(channel.topic, []).append(msg)
    assert [list(m.position) for m in decoded["/arm0/joint_states"]] == [js.q for js in sent]
    assert decoded["/arm0/joint_states"][0].name == names
    (static,) = decoded["/tf_static"]
    edges = {(t.header.frame_id, t.child_frame_id) for t in static.transforms}
    edges |= {(t.header.frame_id, t.child_frame_id) for m in decoded["/tf"] for t in m.transforms}
    assert edges == {("world", "laser"), ("world", "arm0_base"), ("arm0_base", "arm0_flange"),
                     ("arm0_flange", "arm0_mirror")}  # fmt: skip
    last = decoded["/tf"][-1].transforms[0].transform.translation
    fk = system1.robots[0].kinematics.fk(np.asarray(sent[-1].q))[:3, 3]
    np.testing.assert_allclose([last.x, last.y, last.z], fk, atol=1e-12)

    (markers,) = decoded["/beamrelay/markers"]
    beam = next(mk for mk in markers.markers if mk.ns == "beam")
    assert (beam.color.r, beam.color.g, beam.color.b) == (1.0, 0.0, 0.0)  # the gate was on
    first = beam.points[0]
    np.testing.assert_allclose([first.x, first.y, first.z], system1.world_T_laser[:3, 3])

    (sent_traj,) = decoded["/arm0/joint_trajectory"]
    assert [list(p.positions) for p in sent_traj.points] == traj.q
    assert sent_traj.points[1].time_from_start.nanosec == 250_000_000
    # the gate on; no aim channel: the state had no aiming beam (aim None), which is not "off"
    assert [m.data for m in decoded["/beamrelay/laser/treatment"]] == [True]
    (cloud,) = decoded["/camera/points"]
    assert cloud.header.frame_id == "camera" and cloud.width == 4
    np.testing.assert_array_equal(np.frombuffer(bytes(cloud.data), "<f4").reshape(4, 3), rows)

    # replay reads the raw channels only
    assert {m.key for m in read(path)} == set(raw)


def test_record_command_writes_the_static_tf_with_a_scenario(endpoint: str, tmp_path: Path) -> None:
    import subprocess
    import sys

    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from tests.paths import REPO

    out = tmp_path / "s.mcap"
    hub = open_session(listen=True, endpoint=endpoint)
    try:
        rec = subprocess.run([sys.executable, "-m", "planner.cli", "record", "-o", str(out),
                              "--duration", "1", "--ros2", "--scenario",
                              str(REPO / "scenarios" / "paper_n1.yaml"), "--endpoint", endpoint],
                             capture_output=True, text=True, timeout=120)  # fmt: skip
    finally:
        hub.close()
    assert rec.returncode == 0, rec.stderr
    with out.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        ((schema, channel, _, msg),) = list(reader.iter_decoded_messages())
    assert (channel.topic, schema.name, schema.encoding) == (
        "/tf_static",
        "tf2_msgs/msg/TFMessage",
        "ros2msg",
    )
    children = {t.child_frame_id for t in msg.transforms}
    assert children == {"laser", "camera", "arm0_base", "arm0_mirror"}


def test_the_markers_show_the_measured_spot_where_the_camera_saw_it() -> None:
    """A recorded camera/spot becomes the markers' spot sphere, in the world through the
    scenario's camera pose (an independent transform of the message's point); a spot the
    camera lost (p_camera null) takes it away."""
    from planner.io.scenario import load_scenario, system_from_scenario
    from schemas.messages import SpotMessage
    from tests.paths import REPO

    system = system_from_scenario(load_scenario(REPO / "scenarios" / "paper_n1.yaml"))
    keys = Keys("recspot")
    ros = RosTranslator(keys, system)
    p_cam = np.array([0.02, -0.01, 0.9])
    ros(keys.camera_spot, encode(SpotMessage(t=1.0, p_camera=p_cam.tolist(), confidence=0.9)))
    names = list(system.robots[0].joint_names)
    js = JointState(t=2.0, names=names, q=system.robots[0].home.tolist(), qd=[0.0] * 6)
    out = ros(keys.joint_states("arm0"), encode(js))
    (markers,) = [m.deserialize(r.data, m.MARKER_ARRAY) for r in out if r.topic == MARKER_TOPIC]
    (spot,) = [mk for mk in markers.markers if mk.ns == "spot"]
    assert system.camera is not None
    T = system.camera.world_T_camera
    p = spot.pose.position
    np.testing.assert_allclose([p.x, p.y, p.z], T[:3, :3] @ p_cam + T[:3, 3], atol=1e-12)
    ros(keys.camera_spot, encode(SpotMessage(t=3.0, p_camera=None, confidence=0.0)))
    js2 = JointState(t=3.0, names=names, q=system.robots[0].home.tolist(), qd=[0.0] * 6)
    out = ros(keys.joint_states("arm0"), encode(js2))
    (markers,) = [m.deserialize(r.data, m.MARKER_ARRAY) for r in out if r.topic == MARKER_TOPIC]
    assert "spot" not in {mk.ns for mk in markers.markers}
