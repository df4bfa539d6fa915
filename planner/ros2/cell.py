"""The cell as ROS 2 sees it: the TF tree and the markers, from the system model and state.

Frames (tf2 names, no leading ``/``): ``world``; per robot ``<robot>_base`` (its ``base``),
``<robot>_flange`` (``tool0``) and ``<robot>_mirror``; ``laser`` (+z = beam) and ``camera``
(OpenCV optical frame). Static transforms (world -> bases, flange -> mirror, world -> laser,
world or flange -> camera) go on ``/tf_static``; base -> flange, from the robot model's
forward kinematics at the measured joints, on ``/tf``. Markers (in ``world``): the beam as a
line strip from the laser exit over the mirror hits to the first scene surface (red with the
treatment gate on, green with the aiming beam, grey when off), each mirror's rectangle (a
plate in its ``<robot>_mirror`` frame), the last plan's targets, and the camera's measured
spot.
"""

from __future__ import annotations

import json
from typing import Any, NamedTuple

import numpy as np

from planner.console.preview import beam_polyline
from planner.model.scene import SceneModel
from planner.model.system import System
from planner.model.transforms import Array
from planner.ros2 import messages as m

WORLD = "world"
LASER = "laser"
CAMERA = "camera"

BEAM_ON = (1.0, 0.0, 0.0, 1.0)
BEAM_AIM = (0.0, 0.9, 0.0, 0.9)
BEAM_OFF = (0.6, 0.6, 0.6, 0.4)
TARGET_RGBA = (0.1, 0.4, 1.0, 1.0)
SPOT_RGBA = (1.0, 0.8, 0.0, 1.0)
MIRROR_RGBA = (0.75, 0.85, 0.95, 0.8)
MIRROR_THICKNESS = 0.002  # m, of the drawn plate (centred on the mirror frame)
BEAM_WIDTH = 0.002  # m, line width of the beam marker
TARGET_SIZE = 0.004  # m, sphere diameter of a target
SPOT_SIZE = 0.006  # m


def base_frame(robot: str) -> str:
    return f"{robot}_base"


def flange_frame(robot: str) -> str:
    return f"{robot}_flange"


def mirror_frame(robot: str) -> str:
    return f"{robot}_mirror"


class Frame(NamedTuple):
    """One edge of the TF tree: ``parent_T_child`` (4x4, m)."""

    parent: str
    child: str
    parent_T_child: Array


def static_frames(system: System) -> list[Frame]:
    """The transforms that never move: bases, mirror mounts, laser, camera."""
    out = [Frame(WORLD, LASER, system.world_T_laser)]
    for r in system.robots:
        out.append(Frame(WORLD, base_frame(r.name), r.world_T_base))
        out.append(Frame(flange_frame(r.name), mirror_frame(r.name), r.mirror.flange_T_mirror))
    cam = system.camera
    if cam is not None:
        if cam.robot is not None and cam.flange_T_camera is not None:
            out.append(Frame(flange_frame(cam.robot), CAMERA, cam.flange_T_camera))
        else:
            out.append(Frame(WORLD, CAMERA, cam.world_T_camera))
    return out


def moving_frames(system: System, q: dict[str, Array]) -> list[Frame]:
    """base -> flange of every robot in ``q`` (rad), by the robot model's kinematics."""
    return [
        Frame(base_frame(r.name), flange_frame(r.name), r.kinematics.fk(q[r.name]))
        for r in system.robots
        if r.name in q
    ]


def tf_message(t: float, frames: list[Frame]) -> Any:
    """``tf2_msgs/msg/TFMessage`` of ``frames`` stamped at UNIX time ``t``."""
    return m.tf_message([m.transform(t, f.parent, f.child, f.parent_T_child) for f in frames])


def spot_in_world(system: System, q: dict[str, Array], p_camera: Array) -> Array | None:
    """The camera's measured spot (optical frame, m) in the world at joints ``q`` (an
    eye-in-hand camera moves with its robot); None without a camera."""
    if system.camera is None:
        return None
    world_T_camera = system.world_T_camera(q or None)
    return world_T_camera[:3, :3] @ np.asarray(p_camera, dtype=float) + world_T_camera[:3, 3]


def plan_targets(body: bytes) -> Array | None:
    """The targets (K x 3, world, m) of a plan.json body from ``<prefix>/plans``; None for any
    other body (a tracking summary, malformed JSON)."""
    try:
        plan = json.loads(body)
        return np.array([tg["p"] for tg in plan["targets"]], dtype=float).reshape(-1, 3)
    except (ValueError, KeyError, TypeError):
        return None


class PlanTrajectory(NamedTuple):
    """A plan.json ``trajectory``: times (K, s), and per robot q, qd, qdd (K x n)."""

    t: Array
    q: dict[str, Array]
    qd: dict[str, Array]
    qdd: dict[str, Array]


def plan_trajectory(body: bytes) -> PlanTrajectory | None:
    """The ``trajectory`` of a plan.json body, or None (no trajectory, or malformed)."""
    try:
        tr = json.loads(body)["trajectory"]
        t = np.asarray(tr["t"], dtype=float).reshape(-1)
        out = {k: {r: np.asarray(v, dtype=float).reshape(len(t), -1) for r, v in tr[k].items()}
               for k in ("q", "qd", "qdd")}  # fmt: skip
    except (ValueError, KeyError, TypeError, AttributeError):
        return None
    if len(t) == 0 or set(out["q"]) != set(out["qd"]) or set(out["q"]) != set(out["qdd"]):
        return None
    return PlanTrajectory(t, out["q"], out["qd"], out["qdd"])


class Beam(NamedTuple):
    """What the beam marker shows: the gate (``on``) and aiming beam (``aim``) states."""

    on: bool = False
    aim: bool = False

    @property
    def rgba(self) -> tuple[float, float, float, float]:
        return BEAM_ON if self.on else BEAM_AIM if self.aim else BEAM_OFF


BEAM_IDLE = Beam()


def markers(
    t: float,
    system: System,
    scene: SceneModel | None,
    q: dict[str, Array],
    *,
    beam: Beam = BEAM_IDLE,
    targets: Array | None = None,
    spot_world: Array | None = None,
) -> Any:
    """``visualization_msgs/msg/MarkerArray``: a DELETEALL, each mirror's rectangle (in its
    own frame), the beam at joints ``q`` (every robot needed; else no beam), the ``targets``
    (K x 3, world) and the spot."""
    out = [m.make("visualization_msgs/msg/Marker", header=m.header(t, WORLD), action=m.DELETEALL)]
    for i, r in enumerate(system.robots):
        w, h = r.mirror.size
        size = (float(w), float(h), MIRROR_THICKNESS)
        out.append(m.box(t, "mirrors", i, mirror_frame(r.name), size, MIRROR_RGBA))
    if all(r.name in q for r in system.robots):
        line = beam_polyline(system, q, scene)
        out.append(m.marker(t, "beam", 0, m.LINE_STRIP, line, beam.rgba, BEAM_WIDTH))
    if targets is not None and len(targets):
        out.append(m.marker(t, "targets", 0, m.SPHERE_LIST, targets, TARGET_RGBA, TARGET_SIZE))
    if spot_world is not None:
        out.append(m.marker(t, "spot", 0, m.SPHERE, np.asarray(spot_world), SPOT_RGBA, SPOT_SIZE))
    return m.marker_array(out)
