"""ROS 2 channels of a recording: bus samples translated to CDR messages with ros2msg schemas.

:class:`RosTranslator` turns one bus sample into the ROS 2 messages a recording adds beside
the raw channel (which ``replay`` keeps using): ``<prefix>/<robot>/joint_states`` becomes
``/<robot>/joint_states`` (``sensor_msgs/msg/JointState``) and, with the system model,
``/tf`` (base -> flange); :meth:`RosTranslator.static` gives ``/tf_static``. Schemas are the
concatenated ``.msg`` definitions rosbags generates (MCAP's ``ros2msg`` schema encoding),
the data CDR (message encoding ``cdr``), as Foxglove and ``ros2 bag`` read them.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from planner.errors import InputError
from planner.model.system import System
from planner.ros2 import cell
from planner.ros2 import messages as m
from planner.ros2.bridge import joint_states_topic
from planner.service.bus import Keys, decode
from schemas.messages import JointState

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

    def __init__(self, keys: Keys, system: System | None = None) -> None:
        self.keys, self.system = keys, system

    def schema(self, ros_type: str) -> str:
        return schema_text(ros_type)

    def static(self, t: float) -> list[RosMessage]:
        if self.system is None:
            return []
        msg = cell.tf_message(t, cell.static_frames(self.system))
        return [RosMessage("/tf_static", m.TF_MESSAGE, m.serialize(msg, m.TF_MESSAGE))]

    def __call__(self, key: str, payload: bytes) -> list[RosMessage]:
        prefix, _, rest = key.partition("/")
        robot, _, leaf = rest.partition("/")
        if prefix != self.keys.prefix or leaf != "joint_states" or "/" in robot:
            return []
        try:
            js = decode(payload, JointState)
        except InputError:
            return []
        out = [
            RosMessage(
                joint_states_topic(robot),
                m.JOINT_STATE,
                m.serialize(m.joint_state(js.t, js.names, js.q, js.qd), m.JOINT_STATE),
            )
        ]
        if self.system is not None and robot in self.system.robot_names:
            q = {robot: np.asarray(js.q, dtype=float)}
            tf = cell.tf_message(js.t, cell.moving_frames(self.system, q))
            out.append(RosMessage("/tf", m.TF_MESSAGE, m.serialize(tf, m.TF_MESSAGE)))
        return out
