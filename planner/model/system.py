"""The resolved system: laser, robots with mirrors, camera. Frozen dataclasses of numpy arrays.

Built from a validated scenario by :func:`planner.io.scenario.system_from_scenario`; everything
inside the planner works on these, never on pydantic models. Units SI, poses ``a_T_b``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import TYPE_CHECKING

import numpy as np

from planner.model.limits import Limits as Limits  # re-exported
from planner.model.mirror import Mirror
from planner.model.transforms import Array

if TYPE_CHECKING:
    from planner.model.kinematics import RobotKinematics

JOINT_NAMES_UR = (
    "shoulder_pan",
    "shoulder_lift",
    "elbow",
    "wrist_1",
    "wrist_2",
    "wrist_3",
)
DEFAULT_HOME = (0.0, -np.pi / 2, np.pi / 2, -np.pi / 2, -np.pi / 2, 0.0)


@dataclass(frozen=True)
class Robot:
    name: str
    kinematics: RobotKinematics
    world_T_base: Array
    mirror: Mirror
    home: Array
    limits: Limits

    @property
    def nq(self) -> int:
        return self.kinematics.nq

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.kinematics.joint_names


@dataclass(frozen=True)
class Intrinsics:
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float


@dataclass(frozen=True)
class Camera:
    """An RGB-D camera, OpenCV optical frame (x right, y down, z forward).

    Fixed cameras have ``robot = None``. A camera on a robot's flange (eye-in-hand) has
    ``robot`` and ``flange_T_camera``; its ``world_T_camera`` is then the pose at that
    robot's home joints (use :meth:`System.world_T_camera` for other joints).
    """

    world_T_camera: Array
    intrinsics: Intrinsics
    robot: str | None = None
    flange_T_camera: Array | None = None


@dataclass(frozen=True)
class System:
    """Laser + N robot-mirror pairs (beam hits them in order) + optional camera."""

    world_T_laser: Array
    robots: tuple[Robot, ...]
    camera: Camera | None = None

    @property
    def n_robots(self) -> int:
        return len(self.robots)

    @property
    def nq(self) -> int:
        return sum(r.nq for r in self.robots)

    @property
    def robot_names(self) -> tuple[str, ...]:
        return tuple(r.name for r in self.robots)

    def robot(self, name: str) -> Robot:
        for r in self.robots:
            if r.name == name:
                return r
        raise KeyError(f"unknown robot {name!r}; known: {', '.join(self.robot_names)}")

    def split_q(self, q: Array) -> dict[str, Array]:
        """Stacked joint vector -> ``{robot name: q}``."""
        out, i = {}, 0
        for r in self.robots:
            out[r.name] = np.asarray(q[i : i + r.nq], dtype=float)
            i += r.nq
        return out

    def stack_q(self, q: dict[str, Array] | list[Array]) -> Array:
        """``{robot name: q}`` (or a list in robot order) -> stacked joint vector."""
        if isinstance(q, dict):
            return np.concatenate([np.asarray(q[r.name], dtype=float) for r in self.robots])
        return np.concatenate([np.asarray(x, dtype=float) for x in q])

    @property
    def home(self) -> Array:
        return self.stack_q([r.home for r in self.robots])

    @property
    def lower(self) -> Array:
        return self.stack_q([r.limits.lower for r in self.robots])

    @property
    def upper(self) -> Array:
        return self.stack_q([r.limits.upper for r in self.robots])

    @property
    def limits(self) -> Limits:
        """Every robot's joint limits stacked in robot order, like the joint vector."""
        return Limits(
            *(
                self.stack_q([getattr(r.limits, f.name) for r in self.robots])
                for f in fields(Limits)
            )
        )

    def world_T_camera(self, q: Array | dict[str, Array] | None = None) -> Array:
        """The camera pose in the world at joints ``q`` (stacked vector, ``{robot: q}`` or
        None = home); a fixed camera ignores ``q``. Robots missing from a mapping are taken
        at home. Raises ``ValueError`` when the system has no camera."""
        cam = self.camera
        if cam is None:
            raise ValueError("the system has no camera")
        if cam.robot is None or cam.flange_T_camera is None:
            return cam.world_T_camera
        r = self.robot(cam.robot)
        if q is None:
            q_r = r.home
        elif isinstance(q, dict):
            q_r = np.asarray(q.get(r.name, r.home), dtype=float)
        else:
            q_r = self.split_q(np.asarray(q, dtype=float))[r.name]
        return r.world_T_base @ r.kinematics.fk(q_r) @ cam.flange_T_camera

    def with_params(
        self,
        world_T_laser: Array | None = None,
        flange_T_mirror: dict[str, Array] | None = None,
        world_T_base: dict[str, Array] | None = None,
    ) -> System:
        """A copy with some geometry replaced (calibration, sensitivity studies)."""
        robots = []
        for r in self.robots:
            if flange_T_mirror and r.name in flange_T_mirror:
                r = replace(r, mirror=replace(r.mirror, flange_T_mirror=flange_T_mirror[r.name]))
            if world_T_base and r.name in world_T_base:
                r = replace(r, world_T_base=world_T_base[r.name])
            robots.append(r)
        return replace(
            self,
            world_T_laser=self.world_T_laser if world_T_laser is None else world_T_laser,
            robots=tuple(robots),
        )


@dataclass(frozen=True)
class Targets:
    """Targets in the world frame. ``normals`` rows are unit or NaN (no normal)."""

    points: Array  # (K, 3)
    normals: Array | None = None  # (K, 3) or None
    kind: str = "points"  # points | grid | path
    closed: bool = False
    meta: dict[str, object] = field(default_factory=dict)
    surface_tolerance: float = 0.0
    """m: how far a target may lie from the scene surface that carries it and still be
    planned onto it (:mod:`planner.plan.landing`; camera-frame point targets); 0: exact"""
    cloud: Array | None = None
    """(N, 3) world points of the camera's live cloud around the targets (m, through the
    calibrated camera pose): a surface that can carry them where the scene has none"""

    def __len__(self) -> int:
        return len(self.points)

    def normal(self, k: int) -> Array | None:
        if self.normals is None or not np.all(np.isfinite(self.normals[k])):
            return None
        return self.normals[k]
