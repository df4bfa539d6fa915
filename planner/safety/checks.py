"""Clearance checks of one configuration: arm-arm, arm-self and arm-scene.

Every check returns :class:`Clearance` records, one per pair of parts, with the signed
distance (m; negative = penetration depth), the distance required, the witness points on
each part and the unit normal from part a to part b, all in the world frame. The witness
points and the normal are what a gradient needs: for a point ``p`` fixed on a link,
``d(distance)/dq = normal . (J_b(p_b) - J_a(p_a))`` with the links' point Jacobians.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from enum import Enum

import numpy as np
import pinocchio as pin

from planner.model.status import Reason
from planner.model.transforms import Array
from planner.safety.geometry import PairKind, SafetyWorld

#: m, default minimum distance arm-arm, arm-scene and beam-arm
DEFAULT_CLEARANCE = 0.01


class Check(Enum):
    ARM_ARM = "arm_arm"
    ARM_SELF = "arm_self"
    ARM_SCENE = "arm_scene"
    BEAM_ARM = "beam_arm"
    BEAM_KEEP_OUT = "beam_keep_out"
    TARGET_KEEP_OUT = "target_keep_out"
    LASER_RETURN = "laser_return"
    CAMERA_LENS = "camera_lens"

    @property
    def reason(self) -> Reason:
        """The plan's failure reason for a violation of this check."""
        if self in (Check.ARM_ARM, Check.ARM_SELF, Check.ARM_SCENE):
            return Reason.COLLISION
        if self is Check.BEAM_ARM:
            return Reason.OCCLUDED
        return Reason.KEEP_OUT


CHECK_OF_PAIR = {
    PairKind.ARM_ARM: Check.ARM_ARM,
    PairKind.ARM_SELF: Check.ARM_SELF,
    PairKind.ARM_SCENE: Check.ARM_SCENE,
}


@dataclass(frozen=True)
class Clearance:
    """Distance between part ``a`` and part ``b`` (names; world part indices ``index_a``,
    ``index_b``, -1 for the beam or a target point): ``distance`` (m, < 0 = penetrating),
    ``required`` (m), witness points ``p_a``, ``p_b`` and unit normal a -> b (world frame).
    ``segment`` is the beam segment index for beam checks (-1 otherwise)."""

    check: Check
    a: str
    b: str
    distance: float
    required: float
    p_a: Array
    p_b: Array
    normal: Array
    index_a: int = -1
    index_b: int = -1
    segment: int = -1

    @property
    def ok(self) -> bool:
        return self.distance >= self.required

    @property
    def margin(self) -> float:
        """distance - required (m); negative on a violation."""
        return self.distance - self.required

    def __str__(self) -> str:
        where = np.round((self.p_a + self.p_b) / 2, 4).tolist()
        seg = f" (beam segment {self.segment})" if self.segment >= 0 else ""
        return (
            f"{self.check.value}: {self.a} - {self.b}{seg} {self.distance * 1000:.1f} mm apart"
            f" (required {self.required * 1000:.1f} mm) at {where} m (world)"
        )


def worst(clearances: Iterable[Clearance]) -> Clearance | None:
    """The record with the smallest margin, or None for none."""
    return min(clearances, key=lambda c: c.margin, default=None)


def violations(clearances: Iterable[Clearance]) -> list[Clearance]:
    """The records below their required distance, worst first."""
    return sorted((c for c in clearances if not c.ok), key=lambda c: c.margin)


def pair_record(world: SafetyWorld, pair: int, check: Check, required: float) -> Clearance:
    cp = world.geom_model.collisionPairs[pair]
    res = world.geom_data.distanceResults[pair]
    p_a, p_b = np.array(res.getNearestPoint1()), np.array(res.getNearestPoint2())
    return Clearance(
        check,
        world.parts[cp.first].name,
        world.parts[cp.second].name,
        float(res.min_distance),
        required,
        p_a,
        p_b,
        np.array(res.normal),
        int(cp.first),
        int(cp.second),
    )


def pair_clearances(
    world: SafetyWorld,
    q: Array,
    kinds: Iterable[PairKind] = tuple(PairKind),
    clearance: float = DEFAULT_CLEARANCE,
) -> list[Clearance]:
    """Every collision pair of the given kinds at stacked joints ``q`` (rad). Arm-self pairs
    must only not touch (required 0); the others keep ``clearance`` (m)."""
    world.update(q)
    wanted = set(kinds)
    out = []
    for i, kind in enumerate(world.pair_kinds):
        if kind in wanted:
            pin.computeDistance(world.geom_model, world.geom_data, i)
            required = 0.0 if kind is PairKind.ARM_SELF else clearance
            out.append(pair_record(world, i, CHECK_OF_PAIR[kind], required))
    return out


def all_pair_distances(world: SafetyWorld, q: Array) -> Array:
    """Signed distances (m) of every collision pair at ``q``, in ``collisionPairs`` order,
    computed in one Pinocchio call (the fast path for sweeps)."""
    q = np.asarray(q, dtype=float)
    world.update(q)
    pin.computeDistances(world.geom_model, world.geom_data)
    return np.array([r.min_distance for r in world.geom_data.distanceResults])


def arm_arm(world: SafetyWorld, q: Array, clearance: float = DEFAULT_CLEARANCE) -> list[Clearance]:
    """Every part of one robot against every part of another (N >= 2)."""
    return pair_clearances(world, q, (PairKind.ARM_ARM,), clearance)


def arm_self(world: SafetyWorld, q: Array) -> list[Clearance]:
    """Non-adjacent links of one robot, and its mirror and mount against its own links."""
    return pair_clearances(world, q, (PairKind.ARM_SELF,))


def arm_scene(
    world: SafetyWorld, q: Array, clearance: float = DEFAULT_CLEARANCE
) -> list[Clearance]:
    """Every moving part of every robot against every scene object."""
    return pair_clearances(world, q, (PairKind.ARM_SCENE,), clearance)
