"""beamrelay's state as ROS 2 messages, built from rosbags' type store and CDR serializer.

The message definitions, their RIHS01 type hashes and the CDR bytes all come from
``rosbags`` (the ROS 2 Jazzy store): nothing here packs bytes by hand. :func:`make` fills
every field a caller leaves out with its ROS default (0, "", empty sequences, nested
defaults), so a message reads as the fields that matter.
"""

from __future__ import annotations

from functools import cache
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

from planner.model.transforms import Array

JOINT_STATE = "sensor_msgs/msg/JointState"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"
POINT_CLOUD2 = "sensor_msgs/msg/PointCloud2"
JOINT_TRAJECTORY = "trajectory_msgs/msg/JointTrajectory"
BOOL = "std_msgs/msg/Bool"
FLOAT32 = 7  # sensor_msgs/msg/PointField datatype

#: visualization_msgs/msg/Marker constants
LINE_STRIP, SPHERE_LIST, SPHERE, CUBE = 4, 7, 2, 1
ADD, DELETEALL = 0, 3


@cache
def typestore() -> Any:
    """rosbags' ROS 2 Jazzy type store (definitions, CDR, RIHS01 hashes)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def type_hash(ros_type: str) -> str:
    """The RIHS01 type hash (REP-2016) of ``ros_type``, computed by rosbags from the type
    description in its store."""
    return str(typestore().hash_rihs01(ros_type))


def serialize(msg: Any, ros_type: str) -> bytes:
    """CDR (little endian, with the encapsulation header) of ``msg``."""
    return bytes(typestore().serialize_cdr(msg, ros_type))


def deserialize(data: bytes, ros_type: str) -> Any:
    return typestore().deserialize_cdr(data, ros_type)


def make(ros_type: str, **values: Any) -> Any:
    """A ``ros_type`` message with ``values``; every other field at its ROS default."""
    from rosbags.interfaces import Nodetype

    store = typestore()
    cls = store.types[ros_type]
    _, fields = store.fielddefs[ros_type]
    for name, (kind, spec) in fields:
        if name in values:
            continue
        if kind == Nodetype.BASE:
            values[name] = _base_default(spec[0])
        elif kind == Nodetype.NAME:
            values[name] = make(spec)
        else:  # ARRAY (fixed length) or SEQUENCE
            (sub_kind, sub_spec), length = spec
            n = length if kind == Nodetype.ARRAY else 0
            if sub_kind == Nodetype.BASE and sub_spec[0] != "string":
                values[name] = np.zeros(n, dtype=_DTYPES[sub_spec[0]])
            elif sub_kind == Nodetype.BASE:
                values[name] = [""] * n
            else:
                values[name] = [make(sub_spec) for _ in range(n)]
    return cls(**values)


_DTYPES = {
    "bool": np.bool_, "byte": np.uint8, "char": np.uint8, "int8": np.int8, "uint8": np.uint8,
    "int16": np.int16, "uint16": np.uint16, "int32": np.int32, "uint32": np.uint32,
    "int64": np.int64, "uint64": np.uint64, "float32": np.float32, "float64": np.float64,
}  # fmt: skip


def _base_default(name: str) -> Any:
    if name == "string":
        return ""
    if name == "bool":
        return False
    return 0.0 if name.startswith("float") else 0


def stamp(t: float) -> Any:
    """``builtin_interfaces/msg/Time`` of UNIX time ``t`` (s)."""
    sec = int(np.floor(t))
    nanosec = min(round((t - sec) * 1e9), 999_999_999)  # split first: t * 1e9 loses ~100 ns
    return make("builtin_interfaces/msg/Time", sec=sec, nanosec=nanosec)


def header(t: float, frame: str = "") -> Any:
    return make("std_msgs/msg/Header", stamp=stamp(t), frame_id=frame)


def joint_state(t: float, names: list[str], q: ArrayLike, qd: ArrayLike) -> Any:
    """``sensor_msgs/msg/JointState`` of one robot at UNIX time ``t`` (rad, rad/s; no effort)."""
    return make(
        JOINT_STATE,
        header=header(t),
        name=list(names),
        position=np.asarray(q, dtype=np.float64),
        velocity=np.asarray(qd, dtype=np.float64),
    )


def duration(seconds: float) -> Any:
    """``builtin_interfaces/msg/Duration`` of ``seconds`` >= 0."""
    t = stamp(seconds)
    return make("builtin_interfaces/msg/Duration", sec=t.sec, nanosec=t.nanosec)


def joint_trajectory(
    t: float, names: list[str], times: ArrayLike, q: ArrayLike, qd: ArrayLike, qdd: ArrayLike
) -> Any:
    """``trajectory_msgs/msg/JointTrajectory`` starting at UNIX time ``t``: ``q`` (rad),
    ``qd``, ``qdd`` (K x n) at ``times`` (K, s from the start)."""
    T = np.asarray(times, dtype=float)
    Q, QD, QDD = (np.asarray(a, dtype=np.float64).reshape(len(T), -1) for a in (q, qd, qdd))
    points = [
        make(
            "trajectory_msgs/msg/JointTrajectoryPoint",
            positions=Q[k].copy(),
            velocities=QD[k].copy(),
            accelerations=QDD[k].copy(),
            time_from_start=duration(T[k] - T[0]),
        )
        for k in range(len(T))
    ]
    return make(JOINT_TRAJECTORY, header=header(t), joint_names=list(names), points=points)


def transform(t: float, parent: str, child: str, parent_T_child: Array) -> Any:
    """``geometry_msgs/msg/TransformStamped``: ``child``'s pose in ``parent`` (4x4, m)."""
    T = np.asarray(parent_T_child, dtype=float)
    x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
    return make(
        "geometry_msgs/msg/TransformStamped",
        header=header(t, parent),
        child_frame_id=child,
        transform=make(
            "geometry_msgs/msg/Transform",
            translation=make("geometry_msgs/msg/Vector3", x=T[0, 3], y=T[1, 3], z=T[2, 3]),
            rotation=make("geometry_msgs/msg/Quaternion", x=x, y=y, z=z, w=w),
        ),
    )


def tf_message(transforms: list[Any]) -> Any:
    return make(TF_MESSAGE, transforms=transforms)


def point(p: Array) -> Any:
    return make("geometry_msgs/msg/Point", x=float(p[0]), y=float(p[1]), z=float(p[2]))


def marker(
    t: float,
    ns: str,
    marker_id: int,
    kind: int,
    points: Array,
    rgba: tuple[float, float, float, float],
    scale: float,
    frame: str = "world",
) -> Any:
    """A ``visualization_msgs/msg/Marker`` in ``frame``: a line strip or sphere list through
    ``points`` (K x 3, m), or one sphere at ``points[0]``; ``scale`` is the line width or
    sphere diameter (m)."""
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    one = kind == SPHERE
    return _marker(
        t, ns, marker_id, kind, frame, P[0] if one else np.zeros(3), (scale,) * 3, rgba,
        points=[] if one else [point(p) for p in P],
    )  # fmt: skip


def box(
    t: float,
    ns: str,
    marker_id: int,
    frame: str,
    size: tuple[float, float, float],
    rgba: tuple[float, float, float, float],
) -> Any:
    """A CUBE marker centred on ``frame``'s origin, axis aligned with it, of ``size`` (m),
    locked to the frame (it moves with it through TF)."""
    return _marker(t, ns, marker_id, CUBE, frame, np.zeros(3), size, rgba, frame_locked=True)


def _marker(
    t: float,
    ns: str,
    marker_id: int,
    kind: int,
    frame: str,
    position: Array,
    scale: tuple[float, float, float],
    rgba: tuple[float, float, float, float],
    **fields: Any,
) -> Any:
    pose = make("geometry_msgs/msg/Pose", position=point(position))
    pose.orientation.w = 1.0
    return make(
        "visualization_msgs/msg/Marker",
        header=header(t, frame),
        ns=ns,
        id=marker_id,
        type=kind,
        action=ADD,
        pose=pose,
        scale=make("geometry_msgs/msg/Vector3", x=scale[0], y=scale[1], z=scale[2]),
        color=make("std_msgs/msg/ColorRGBA", r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3]),
        **fields,
    )


def marker_array(markers: list[Any]) -> Any:
    return make(MARKER_ARRAY, markers=markers)


def point_cloud(t: float, frame: str, rows: Array, fields: list[str]) -> Any:
    """``sensor_msgs/msg/PointCloud2`` of ``rows`` (count x len(fields) float32, row-major;
    ``x, y, z`` in m, optional ``r, g, b`` in [0, 1]) in ``frame``: one row of points, float32
    fields at consecutive offsets, the rows' bytes as the data (not dense: NaN rows kept)."""
    data = np.ascontiguousarray(rows, dtype="<f4")
    count, n = data.shape
    if n != len(fields):
        raise ValueError(f"{n} columns for {len(fields)} fields")
    return make(
        POINT_CLOUD2,
        header=header(t, frame),
        height=1,
        width=count,
        fields=[
            make("sensor_msgs/msg/PointField", name=f, offset=4 * i, datatype=FLOAT32, count=1)
            for i, f in enumerate(fields)
        ],
        is_bigendian=False,
        point_step=4 * n,
        row_step=4 * n * count,
        data=data.reshape(-1).view(np.uint8),
        is_dense=False,
    )


def laser_messages(on: bool, aim: bool) -> list[tuple[str, Any]]:
    """The laser state as two ``std_msgs/msg/Bool``: (topic, message) for the treatment
    gate and the aiming beam (:data:`LASER_TOPICS`)."""
    return [(LASER_TOPICS["on"], make(BOOL, data=bool(on))),
            (LASER_TOPICS["aim"], make(BOOL, data=bool(aim)))]  # fmt: skip


#: the laser state's ROS 2 topics: the treatment gate, the aiming beam
LASER_TOPICS = {"on": "/beamrelay/laser/treatment", "aim": "/beamrelay/laser/aim"}
