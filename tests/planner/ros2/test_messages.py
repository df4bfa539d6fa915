"""ROS 2 messages: type hashes against published values, CDR decoded by rosbags' own reader."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from planner.model.system import System
from planner.ros2 import cell
from planner.ros2 import messages as m

#: RIHS01 hashes published by others (REP-2016 hashes of the Jazzy-era definitions):
PUBLISHED = {
    # ros2/rmw_zenoh docs/design.md, the `chatter` examples
    "std_msgs/msg/String": "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
    # ros2_pyterfaces' tests (test_hashes: JointState)
    "sensor_msgs/msg/JointState": (
        "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e"
    ),
    # a zenoh-cpp tf2 listener declaring rmw_zenoh tokens for /tf and /tf_static
    "tf2_msgs/msg/TFMessage": (
        "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087"
    ),
    # a Rust Zenoh ROS 2 client's message table (its MessageTypeInfo impls; the same table
    # gives std_msgs/String the rmw_zenoh value above)
    "std_msgs/msg/Bool": "RIHS01_feb91e995ff9ebd09c0cb3d2aed18b11077585839fb5db80193b62d74528f6c9",
}


@pytest.mark.parametrize("ros_type", sorted(PUBLISHED))
def test_type_hashes_match_published_values(ros_type: str) -> None:
    assert m.type_hash(ros_type) == PUBLISHED[ros_type]


def test_marker_array_hash_is_a_rihs01_digest() -> None:
    h = m.type_hash(m.MARKER_ARRAY)
    assert h.startswith("RIHS01_") and len(h) == 7 + 64
    assert h != m.type_hash("visualization_msgs/msg/Marker")


def test_joint_state_round_trips_through_cdr() -> None:
    q = np.array([0.1, -1.2, 1.3, -0.4, 0.5, 0.6])
    qd = np.array([0.01, 0.0, -0.02, 0.03, 0.0, 0.0])
    names = ["shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3"]
    data = m.serialize(m.joint_state(1_700_000_000.25, names, q, qd), m.JOINT_STATE)
    assert data[:4] == b"\x00\x01\x00\x00"  # CDR little endian encapsulation
    back = m.deserialize(data, m.JOINT_STATE)
    assert back.name == names
    np.testing.assert_array_equal(back.position, q)
    np.testing.assert_array_equal(back.velocity, qd)
    assert len(back.effort) == 0
    assert (back.header.stamp.sec, back.header.stamp.nanosec) == (1_700_000_000, 250_000_000)


def test_flange_transform_is_the_ur5e_check_value(system1: System) -> None:
    """SPEC 2: q = [0, -pi/2, 0, -pi/2, 0, 0] puts the flange at (0, -0.2329, 1.0794) m."""
    r = system1.robots[0]
    q = {r.name: np.array([0, -np.pi / 2, 0, -np.pi / 2, 0, 0])}
    data = m.serialize(cell.tf_message(0.0, cell.moving_frames(system1, q)), m.TF_MESSAGE)
    (tf,) = m.deserialize(data, m.TF_MESSAGE).transforms
    assert (tf.header.frame_id, tf.child_frame_id) == ("arm0_base", "arm0_flange")
    tr = tf.transform.translation
    np.testing.assert_allclose([tr.x, tr.y, tr.z], [0.0, -0.2329, 1.0794], atol=1e-4)
    rot = tf.transform.rotation
    R = Rotation.from_quat([rot.x, rot.y, rot.z, rot.w]).as_matrix()
    np.testing.assert_allclose(R, r.kinematics.fk(q[r.name])[:3, :3], atol=1e-12)


def test_static_frames_form_one_tree_rooted_at_world(system1: System) -> None:
    frames = cell.static_frames(system1) + cell.moving_frames(system1, {"arm0": np.zeros(6)})
    parents = {f.child: f.parent for f in frames}
    assert len(parents) == len(frames)  # each child has exactly one parent
    for child in parents:
        seen = child
        for _ in range(len(frames) + 1):
            if seen == "world":
                break
            seen = parents[seen]
        assert seen == "world", f"{child} does not reach world"
    # world_T_mirror composed along the tree equals the model's
    r = system1.robots[0]
    T = {f.child: f.parent_T_child for f in frames}
    world_T_mirror = T["arm0_base"] @ T["arm0_flange"] @ T["arm0_mirror"]
    expected = r.world_T_base @ r.kinematics.fk(np.zeros(6)) @ r.mirror.flange_T_mirror
    np.testing.assert_allclose(world_T_mirror, expected, atol=1e-12)


def test_markers_carry_the_beam_targets_and_spot(system1: System) -> None:
    from planner.beam.trace import trace_beam

    q = {"arm0": system1.robots[0].home}
    targets = np.array([[0.5, 0.0, 0.1], [0.5, 0.05, 0.1]])
    msg = cell.markers(3.0, system1, None, q, beam=cell.Beam(on=True), targets=targets,
                       spot_world=np.array([0.4, 0.1, 0.0]))  # fmt: skip
    back = m.deserialize(m.serialize(msg, m.MARKER_ARRAY), m.MARKER_ARRAY)
    clear, mirror, beam, tgt, spot = back.markers
    assert clear.action == m.DELETEALL
    assert (mirror.ns, mirror.type, mirror.header.frame_id) == ("mirrors", m.CUBE, "arm0_mirror")
    size = system1.robots[0].mirror.size
    assert (mirror.scale.x, mirror.scale.y) == (size[0], size[1]) and mirror.frame_locked
    assert (beam.ns, beam.type, beam.header.frame_id) == ("beam", m.LINE_STRIP, "world")
    pts = np.array([[p.x, p.y, p.z] for p in beam.points])
    np.testing.assert_allclose(pts[0], system1.world_T_laser[:3, 3], atol=1e-12)
    tr = trace_beam(system1, system1.stack_q(q), np.zeros(3))
    if tr.ahead[0] > 0 and tr.front[0] > 0 and np.all(tr.roi[0] >= 0):
        np.testing.assert_allclose(pts[1], tr.hits[0], atol=1e-9)
    assert (beam.color.r, beam.color.g) == (1.0, 0.0)
    got = np.array([[p.x, p.y, p.z] for p in tgt.points])
    np.testing.assert_allclose(got, targets)
    assert spot.type == m.SPHERE
    assert (spot.pose.position.x, spot.pose.position.y) == (0.4, 0.1)


def test_point_cloud_round_trips_with_the_rows_as_data() -> None:
    rng = np.random.default_rng(3)
    rows = rng.normal(size=(50, 6)).astype(np.float32)
    rows[7] = np.nan
    fields = ["x", "y", "z", "r", "g", "b"]
    back = m.deserialize(m.serialize(m.point_cloud(2.5, "camera", rows, fields), m.POINT_CLOUD2),
                         m.POINT_CLOUD2)  # fmt: skip
    assert (back.height, back.width, back.point_step, back.row_step) == (1, 50, 24, 1200)
    assert [(f.name, f.offset, f.datatype, f.count) for f in back.fields] == [
        (n, 4 * i, 7, 1) for i, n in enumerate(fields)
    ]
    assert back.header.frame_id == "camera" and not back.is_bigendian and not back.is_dense
    got = np.frombuffer(bytes(back.data), dtype="<f4").reshape(50, 6)
    np.testing.assert_array_equal(got, rows)  # NaN rows compare equal position-wise
    with pytest.raises(ValueError, match="3 columns for 6 fields"):
        m.point_cloud(0.0, "camera", rows[:, :3], fields)


def test_spot_in_world_uses_the_camera_pose() -> None:
    from planner.io.scenario import load_scenario, system_from_scenario
    from tests.paths import REPO

    system = system_from_scenario(load_scenario(REPO / "scenarios" / "paper_n1.yaml"))
    assert system.camera is not None
    p_camera = np.array([0.01, -0.02, 0.6])
    T = system.camera.world_T_camera
    expected = (T @ np.append(p_camera, 1.0))[:3]
    got = cell.spot_in_world(system, {}, p_camera)
    assert got is not None
    np.testing.assert_allclose(got, expected, atol=1e-12)
