"""Targets from ROS 2: ``geometry_msgs/msg/PointStamped`` on ``/beamrelay/target`` and
``geometry_msgs/msg/PoseArray`` (the poses' positions) on ``/beamrelay/targets`` become
TargetRequests on the bus's ``<prefix>/targets`` (planned, not executed: motion stays the
planner's and the operator's). The frame is the header's ``frame_id``: ``world``, or
``camera`` (the camera's optical frame, as on ``/tf_static``); any other frame is refused.
"""

from __future__ import annotations

from typing import Any, NamedTuple

from planner.ros2 import cell
from planner.ros2 import messages as m
from schemas.messages import TargetRequest

POINT_STAMPED = "geometry_msgs/msg/PointStamped"
POSE_ARRAY = "geometry_msgs/msg/PoseArray"
FRAMES = {cell.WORLD: "world", cell.CAMERA: "camera"}


class Input(NamedTuple):
    """A ROS 2 topic the bridge subscribes to and the message type it takes."""

    topic: str
    ros_type: str


INPUTS = (Input("/beamrelay/target", POINT_STAMPED), Input("/beamrelay/targets", POSE_ARRAY))


def target_request(ros_type: str, data: bytes, request_id: str) -> TargetRequest:
    """The TargetRequest of one CDR message of ``ros_type``; ValueError (with the reason)
    for a body that does not decode, an unknown frame or no points."""
    try:
        msg = m.deserialize(data, ros_type)
    except Exception as exc:  # rosbags raises several types for a bad body
        raise ValueError(f"not a {ros_type}: {exc}") from None
    frame = msg.header.frame_id.lstrip("/")
    if frame not in FRAMES:
        raise ValueError(f"frame_id {frame!r}: expected {' or '.join(FRAMES)}")
    if ros_type == POINT_STAMPED:
        points = [_xyz(msg.point)]
    else:
        points = [_xyz(p.position) for p in msg.poses]
    if not points:
        raise ValueError("no poses")
    body: dict[str, Any] = {"schema": "beamrelay.request/1", "id": request_id,
                            "frame": FRAMES[frame], "points": points}  # fmt: skip
    return TargetRequest.model_validate(body)


def _xyz(p: Any) -> list[float]:
    return [float(p.x), float(p.y), float(p.z)]
