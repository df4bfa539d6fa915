"""ROS 2 channels of a recording: bus samples translated to CDR messages with ros2msg schemas.

:class:`RosTranslator` turns one bus sample into the ROS 2 messages a recording adds beside
the raw channel (which ``replay`` keeps using): ``<prefix>/<robot>/joint_states`` becomes
``/<robot>/joint_states`` (``sensor_msgs/msg/JointState``) and, with the system model,
``/tf`` (base -> flange); :meth:`RosTranslator.static` gives ``/tf_static``. Schemas are the
concatenated ``.msg`` definitions rosbags generates (MCAP's ``ros2msg`` schema encoding),
the data CDR (message encoding ``cdr``), as Foxglove and ``ros2 bag`` read them. With the
system model it also writes ``/beamrelay/markers`` (the beam at the recorded joints, coloured
by the recorded laser state, the targets of the recorded plans, and the camera's last
measured spot, placed in the world through the camera pose at the recorded joints) at most
``MARKER_RATE`` Hz of recorded time. Trajectories sent to the drivers become
``/<robot>/joint_trajectory`` (``trajectory_msgs/msg/JointTrajectory``), the camera cloud
``/camera/points`` (``sensor_msgs/msg/PointCloud2``, at most ``CLOUD_RATE`` Hz), each laser
state ``/beamrelay/laser/treatment`` and ``/beamrelay/laser/aim`` (``std_msgs/msg/Bool``).
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

from planner.bus.session import Keys, decode
from planner.errors import InputError
from planner.model.scene import SceneModel
from planner.model.system import System
from planner.model.transforms import Array
from planner.ros2 import cell
from planner.ros2 import messages as m
from planner.ros2.bridge import (
    CLOUD_RATE,
    CLOUD_TOPIC,
    MARKER_RATE,
    MARKER_TOPIC,
    joint_states_topic,
    trajectory_topic,
)
from schemas.messages import JointState, JointTrajectory, LaserState, SpotMessage
from schemas.points import decode_points

SCHEMA_ENCODING = "ros2msg"
MESSAGE_ENCODING = "cdr"


class RosMessage(NamedTuple):
    """One ROS 2 message for the file: ``topic``, ``ros_type``, CDR ``data``."""

    topic: str
    ros_type: str
    data: bytes


def schema_text(ros_type: str) -> str:
    """The ``ros2msg`` schema of ``ros_type``: its definition, then each nested type's after a
    ``====`` line and ``MSG: pkg/msg/Name`` (rosbags' generator, as rosbag2 writes it)."""
    text, _ = m.typestore().generate_msgdef(ros_type, ros_version=2)
    return str(text)


class RosTranslator:
    """See the module docstring; ``system`` None: joint states only (no TF)."""

    def __init__(
        self, keys: Keys, system: System | None = None, scene: SceneModel | None = None
    ) -> None:
        self.keys, self.system, self.scene = keys, system, scene
        self.q: dict[str, Array] = {}
        self.beam = cell.BEAM_IDLE
        self.targets: Array | None = None
        self.spot_camera: Array | None = None  # the last measured spot (optical frame, m)
        self._next_markers = self._next_cloud = 0.0

    def schema(self, ros_type: str) -> str:
        return schema_text(ros_type)

    def static(self, t: float) -> list[RosMessage]:
        if self.system is None:
            return []
        msg = cell.tf_message(t, cell.static_frames(self.system))
        return [RosMessage("/tf_static", m.TF_MESSAGE, m.serialize(msg, m.TF_MESSAGE))]

    def __call__(
        self, key: str, payload: bytes, attachment: bytes | None = None
    ) -> list[RosMessage]:
        if key == self.keys.laser:
            return self._on_laser(payload)
        if key == self.keys.plans:
            self._on_plan(payload)
            return []
        if key == self.keys.camera_points:
            return self._cloud(payload, attachment)
        if key == self.keys.camera_spot:
            self._on_spot(payload)
            return []
        prefix, _, rest = key.partition("/")
        robot, _, leaf = rest.partition("/")
        if prefix != self.keys.prefix or "/" in robot:
            return []
        if leaf == "trajectory":
            return self._trajectory(robot, payload)
        if leaf == "joint_states":
            return self._joint_state(robot, payload)
        return []

    def _joint_state(self, robot: str, payload: bytes) -> list[RosMessage]:
        try:
            js = decode(payload, JointState)
        except InputError:
            return []
        msg = m.joint_state(js.t, js.names, js.q, js.qd)
        out = [
            RosMessage(joint_states_topic(robot), m.JOINT_STATE, m.serialize(msg, m.JOINT_STATE))
        ]
        if self.system is not None and robot in self.system.robot_names:
            q = {robot: np.asarray(js.q, dtype=float)}
            tf = cell.tf_message(js.t, cell.moving_frames(self.system, q))
            out.append(RosMessage("/tf", m.TF_MESSAGE, m.serialize(tf, m.TF_MESSAGE)))
            self.q[robot] = q[robot]
            out += self._markers(js.t)
        return out

    def _trajectory(self, robot: str, payload: bytes) -> list[RosMessage]:
        try:
            traj = decode(payload, JointTrajectory)
        except InputError:
            return []
        msg = m.joint_trajectory(time.time(), traj.names, traj.t, traj.q, traj.qd, traj.qdd)
        data = m.serialize(msg, m.JOINT_TRAJECTORY)
        return [RosMessage(trajectory_topic(robot), m.JOINT_TRAJECTORY, data)]

    def _cloud(self, payload: bytes, attachment: bytes | None) -> list[RosMessage]:
        if attachment is None:
            return []
        try:
            rows, meta = decode_points(payload, attachment)
        except InputError:
            return []
        t = float(meta.get("t", time.time()))
        if t < self._next_cloud:
            return []
        self._next_cloud = t + 1.0 / CLOUD_RATE
        msg = m.point_cloud(t, cell.CAMERA, rows, list(meta["fields"]))
        return [RosMessage(CLOUD_TOPIC, m.POINT_CLOUD2, m.serialize(msg, m.POINT_CLOUD2))]

    def _markers(self, t: float) -> list[RosMessage]:
        if self.system is None or t < self._next_markers:
            return []
        self._next_markers = t + 1.0 / MARKER_RATE
        spot = None
        if self.spot_camera is not None:
            spot = cell.spot_in_world(self.system, self.q, self.spot_camera)
        msg = cell.markers(t, self.system, self.scene, self.q, beam=self.beam,
                           targets=self.targets, spot_world=spot)  # fmt: skip
        return [RosMessage(MARKER_TOPIC, m.MARKER_ARRAY, m.serialize(msg, m.MARKER_ARRAY))]

    def _on_laser(self, payload: bytes) -> list[RosMessage]:
        """The beam's colour for the markers, and the laser state's two Bool channels."""
        try:
            laser = decode(payload, LaserState)
        except InputError:
            return []
        self.beam = cell.Beam(on=laser.on, aim=bool(laser.aim))
        return [RosMessage(topic, m.BOOL, m.serialize(msg, m.BOOL))
                for topic, msg in m.laser_messages(laser.on, bool(laser.aim))
                if laser.aim is not None or topic != m.LASER_TOPICS["aim"]]  # fmt: skip

    def _on_spot(self, payload: bytes) -> None:
        """The measured spot for the markers (none while the camera sees none)."""
        try:
            spot = decode(payload, SpotMessage)
        except InputError:
            return
        self.spot_camera = None if spot.p_camera is None else np.asarray(spot.p_camera, float)

    def _on_plan(self, payload: bytes) -> None:
        if (pts := cell.plan_targets(payload)) is not None:
            self.targets = pts
