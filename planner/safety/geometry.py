"""One collision world for a system: every robot's links, mirror and mount, the scene and
the keep-out volumes, as a Pinocchio ``GeometryModel`` over one combined ``Model``.

The combined model stacks the robots' joints in system order, so its configuration is the
system's stacked joint vector (rad). Link capsules (:mod:`planner.safety.ur5e`), the mirror
plate and its mount block move with their joints; the robot bases, scene objects and
keep-out volumes hang on the universe joint at their world poses. All placements
(``geom_data.oMg``), witness points and normals are in the world frame, metres.

Collision pairs (``geom_model.collisionPairs``) are the ones that can be checked for a given
configuration alone: arm-arm (every part of one robot against every part of another),
arm-self (parts two or more links apart; the mirror and mount against every own link but
wrist_3, which carries them) and arm-scene (moving parts against scene objects; the fixed
base stands on the scene by design). The beam and keep-out checks need the beam and use the
placements only (:mod:`planner.safety.beam`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import Enum

import coal
import numpy as np
import pinocchio as pin

from planner.errors import InputError
from planner.model.robots import collision_shapes
from planner.model.system import Robot, System
from planner.model.transforms import Array, inv_T, make_T
from planner.safety.shapes import Volume, coal_shape
from planner.safety.ur5e import (
    DEFAULT_MIRROR_BLOCKS,
    UR5E_SELF_EXCLUDED,
    BoxSpec,
    CapsuleSpec,
    MirrorBlocks,
)

#: link index of parts fixed to the flange (the wrist_3 link)
FLANGE_LINK = 6


class PartKind(Enum):
    LINK = "link"
    MIRROR = "mirror"
    MOUNT = "mount"
    SCENE = "scene"
    KEEP_OUT = "keep_out"


class PairKind(Enum):
    ARM_ARM = "arm_arm"
    ARM_SELF = "arm_self"
    ARM_SCENE = "arm_scene"


@dataclass(frozen=True)
class Part:
    """Geometry ``index`` of the world: ``name`` (``arm0/upper_arm``, ``scene/board``),
    ``robot`` index (-1 for scene and keep-out), ``link`` index (0 = base .. 6 = wrist_3,
    -1 off the robots)."""

    index: int
    name: str
    kind: PartKind
    robot: int = -1
    link: int = -1

    @property
    def on_robot(self) -> bool:
        return self.robot >= 0


def _se3(T: Array) -> pin.SE3:
    return pin.SE3(np.asarray(T[:3, :3], dtype=float), np.asarray(T[:3, 3], dtype=float))


def capsule_placement(a: Array, b: Array) -> tuple[Array, float]:
    """Pose (4x4, z along ``b - a``, origin at the midpoint) and length (m) of the coal
    capsule whose segment is ``a -> b``."""
    # plain floats: numpy calls on 3-vectors cost ~1 µs each and this runs per beam segment
    ax, ay, az = (float(v) for v in a)
    bx, by, bz = (float(v) for v in b)
    dx, dy, dz = bx - ax, by - ay, bz - az
    length = math.sqrt(dx * dx + dy * dy + dz * dz)
    zx, zy, zz = (dx / length, dy / length, dz / length) if length > 0 else (0.0, 0.0, 1.0)
    # x = e_x cross z (or e_y cross z near the x axis), normalised; y = z cross x
    xx, xy, xz = (0.0, -zz, zy) if abs(zx) < 0.9 else (zz, 0.0, -zx)
    nx = math.sqrt(xx * xx + xy * xy + xz * xz)
    xx, xy, xz = xx / nx, xy / nx, xz / nx
    yx, yy, yz = zy * xz - zz * xy, zz * xx - zx * xz, zx * xy - zy * xx
    T = np.array(
        [
            [xx, yx, zx, (ax + bx) / 2],
            [xy, yy, zy, (ay + by) / 2],
            [xz, yz, zz, (az + bz) / 2],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )
    return T, length


def mirror_boxes(robot: Robot, blocks: MirrorBlocks) -> list[tuple[str, Array, Array]]:
    """``(name, flange_T_box centre, full extents)`` of the mirror plate and its mount. The
    plate reaches from the face's highest point down to ``thickness`` below its lowest
    (:meth:`planner.model.mirror.Surface.depth`; mirror z in [-thickness, 0] when flat)."""
    fTm = robot.mirror.flange_T_mirror
    w, h = robot.mirror.size
    lo, hi = robot.mirror.surface.depth((w, h))
    t = blocks.thickness + (hi - lo)
    plate = fTm @ make_T(p=[0.0, 0.0, hi - t / 2])
    out = [("mirror", plate, np.array([w, h, t]))]
    back = fTm @ np.array([0.0, 0.0, hi - t, 1.0])
    height = float(back[2]) - blocks.mount_gap
    if height > 1e-3:
        centre = make_T(p=[back[0], back[1], height / 2])
        out.append(("mount", centre, np.array([blocks.mount_width, blocks.mount_width, height])))
    return out


def is_ur5e(robot: Robot, tolerance: float = 0.01) -> bool:
    """True for the nominal UR5e, or a 6-joint model whose joint origins lie within
    ``tolerance`` (m) of the nominal UR5e's at a few configurations (a calibrated UR5e)."""
    kin = robot.kinematics
    if kin.name == "ur5e":
        return True
    if kin.nq != 6:
        return False
    from planner.model.kinematics import RobotKinematics

    nominal = RobotKinematics.ur5e()
    for q in np.random.default_rng(0).uniform(-np.pi, np.pi, (4, 6)):
        if np.abs(kin.joint_origins(q) - nominal.joint_origins(q)).max() > tolerance:
            return False
    return True


class SafetyWorld:
    """The collision world of ``system`` (see the module docstring).

    ``scene``: obstacles the arms must keep clear of; ``keep_out``: volumes the beam must not
    enter; ``capsules``: per robot name, ``(capsules, boxes)`` link tables for robots that
    are not the UR5e (a URDF whose joint origins lie within 1 cm of the nominal UR5e's
    counts as one). ``bare``: a robot without a table gets only its mirror and mount (listed
    in :attr:`unchecked`) instead of an error.
    """

    def __init__(
        self,
        system: System,
        scene: Sequence[Volume] = (),
        keep_out: Sequence[Volume] = (),
        *,
        blocks: MirrorBlocks = DEFAULT_MIRROR_BLOCKS,
        capsules: Mapping[str, tuple[Sequence[CapsuleSpec], Sequence[BoxSpec]]] | None = None,
        bare: bool = False,
    ) -> None:
        self.system = system
        self.blocks = blocks
        self.model = pin.Model()
        self.geom_model = pin.GeometryModel()
        self.parts: list[Part] = []
        self.flange_joint: list[int] = []
        #: per robot, the mirror frame in the frame of the joint that carries it
        self.joint_T_mirror: list[Array] = []
        #: robots whose links have no collision geometry (``bare``)
        self.unchecked: list[str] = []
        for k, robot in enumerate(system.robots):
            table = (capsules or {}).get(robot.name)
            if table is None:
                shapes = collision_shapes(robot.kinematics.name)
                if (shapes is None or robot.nq != shapes.nq) and not bare:
                    raise InputError(
                        f"no collision capsules for robot model {robot.kinematics.name!r}",
                        robot.name,
                    )
                if shapes is not None and robot.nq == shapes.nq:
                    table = (shapes.capsules, shapes.boxes)
                else:
                    self.unchecked.append(robot.name)
                    table = ((), ())
            self._add_robot(k, robot, *table)
        for v in scene:
            self._add_fixed(f"scene/{v.name}", PartKind.SCENE, v, solid=False)
        for v in keep_out:
            self._add_fixed(f"keep_out/{v.name}", PartKind.KEEP_OUT, v, solid=True)
        self.pair_kinds: list[PairKind] = []
        self._add_pairs()
        self.data = self.model.createData()
        self.geom_data = pin.GeometryData(self.geom_model)
        for req in self.geom_data.distanceRequests:
            req.gjk_tolerance = 1e-12
        self._geometries = [g.geometry for g in self.geom_model.geometryObjects]
        self._placements: dict[int, coal.Transform3s] | None = None
        self._q: Array | None = None
        self.update(pin.neutral(self.model))  # places the fixed parts once

    # construction -------------------------------------------------------------------------
    def _add_geometry(self, part: Part, joint: int, placement: Array, geometry: object) -> None:
        obj = pin.GeometryObject(part.name, joint, _se3(placement), geometry)
        self.geom_model.addGeometryObject(obj)
        self.parts.append(part)

    def _add_robot(
        self, k: int, robot: Robot, table: Sequence[CapsuleSpec], boxes: Sequence[BoxSpec]
    ) -> None:
        km = robot.kinematics.model
        kd = km.createData()
        pin.framesForwardKinematics(km, kd, pin.neutral(km))
        base_T_universe = inv_T(kd.oMf[robot.kinematics.base_id].homogeneous)
        world_T_universe = robot.world_T_base @ base_T_universe
        joints = [0]
        for j in range(1, km.njoints):
            parent = joints[km.parents[j]]
            placement = km.jointPlacements[j].homogeneous
            if km.parents[j] == 0:
                placement = world_T_universe @ placement
            jid = self.model.addJoint(
                parent, km.joints[j].extract(), _se3(placement), f"{robot.name}/{km.names[j]}"
            )
            joints.append(jid)
        # link i frame = joint i frame; link 0 = base frame (on the universe joint)
        for spec in table:
            frame = robot.world_T_base if spec.link == 0 else np.eye(4)
            T, length = capsule_placement(np.array(spec.a), np.array(spec.b))
            part = Part(len(self.parts), f"{robot.name}/{spec.name}", PartKind.LINK, k, spec.link)
            self._add_geometry(
                part, joints[spec.link], frame @ T, coal.Capsule(spec.radius, length)
            )
        for bspec in boxes:
            frame = robot.world_T_base if bspec.link == 0 else np.eye(4)
            part = Part(len(self.parts), f"{robot.name}/{bspec.name}", PartKind.LINK, k, bspec.link)
            T = frame @ make_T(p=bspec.centre)
            self._add_geometry(part, joints[bspec.link], T, coal.Box(*bspec.extents))
        flange = km.frames[robot.kinematics.flange_id]
        joint6_T_flange = flange.placement.homogeneous
        self.flange_joint.append(joints[flange.parentJoint])
        self.joint_T_mirror.append(joint6_T_flange @ robot.mirror.flange_T_mirror)
        for name, fTb, extents in mirror_boxes(robot, self.blocks):
            kind = PartKind.MIRROR if name == "mirror" else PartKind.MOUNT
            part = Part(len(self.parts), f"{robot.name}/{name}", kind, k, FLANGE_LINK)
            self._add_geometry(
                part, joints[flange.parentJoint], joint6_T_flange @ fTb, coal.Box(*extents)
            )

    def _add_fixed(self, name: str, kind: PartKind, v: Volume, *, solid: bool) -> None:
        part = Part(len(self.parts), name, kind)
        self._add_geometry(part, 0, v.world_T_object, coal_shape(v, solid=solid))

    def _pair_kind(self, a: Part, b: Part) -> PairKind | None:
        if a.on_robot and b.on_robot:
            if a.robot != b.robot:
                return PairKind.ARM_ARM
            if PartKind.LINK not in (a.kind, b.kind):
                return None  # mirror vs its own mount
            if a.kind != PartKind.LINK or b.kind != PartKind.LINK:
                return PairKind.ARM_SELF if min(a.link, b.link) < FLANGE_LINK else None
            names = (a.name.split("/", 1)[1], b.name.split("/", 1)[1])
            if names in UR5E_SELF_EXCLUDED or names[::-1] in UR5E_SELF_EXCLUDED:
                return None
            return PairKind.ARM_SELF if abs(a.link - b.link) >= 2 else None
        moving = a if a.on_robot else b
        other = b if a.on_robot else a
        if moving.on_robot and other.kind == PartKind.SCENE and moving.link > 0:
            return PairKind.ARM_SCENE
        return None

    def _add_pairs(self) -> None:
        for i, a in enumerate(self.parts):
            for b in self.parts[i + 1 :]:
                kind = self._pair_kind(a, b)
                if kind is not None:
                    self.geom_model.addCollisionPair(pin.CollisionPair(a.index, b.index))
                    self.pair_kinds.append(kind)

    # queries ------------------------------------------------------------------------------
    @property
    def nq(self) -> int:
        return int(self.model.nq)

    def update(self, q: Array) -> None:
        """Place every part at the stacked joint vector ``q`` (rad)."""
        q = np.asarray(q, dtype=float).reshape(-1)
        if q.shape != (self.nq,) or not np.all(np.isfinite(q)):
            raise InputError(f"expected {self.nq} finite joint values (rad), got {q.shape}")
        if self._q is not None and np.array_equal(q, self._q):
            return
        pin.forwardKinematics(self.model, self.data, q)
        pin.updateGeometryPlacements(self.model, self.data, self.geom_model, self.geom_data)
        self._q = q.copy()
        self._placements = None

    def placement(self, index: int) -> coal.Transform3s:
        """World pose of part ``index`` at the last :meth:`update`."""
        if self._placements is None:
            self._placements = {}
        T = self._placements.get(index)
        if T is None:
            M = self.geom_data.oMg[index]
            T = self._placements[index] = coal.Transform3s(M.rotation, M.translation)
        return T

    def geometry(self, index: int) -> coal.CollisionGeometry:
        """The coal shape of part ``index`` in its own frame."""
        return self._geometries[index]

    def parts_of(self, *kinds: PartKind) -> list[Part]:
        return [p for p in self.parts if p.kind in kinds]

    def pairs(self, kind: PairKind) -> list[int]:
        """Indices into ``geom_model.collisionPairs`` of one kind."""
        return [i for i, k in enumerate(self.pair_kinds) if k == kind]
