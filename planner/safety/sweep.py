"""Swept collision check of a joint trajectory (arm-arm, arm-self, arm-scene).

Between two consecutive samples the joints are taken to move linearly (the robot's servo
interpolates its set points that way). Conservative advancement: a part on link L of a
robot moves by at most ``sum_j<=L |dq_j| * reach_j`` over a joint step ``dq`` (m), where
``reach_j`` bounds the distance of any point of the part from joint j's axis by the chain's
joint offsets plus the part's extent (configuration independent, from the model). A pair is
certified over the step when its distance at the step's start minus both parts' bounds still
meets the required distance; otherwise the step is halved, down to ``resolution`` (m) of
motion, where the sampled distance decides. The first violation (in time) is returned with
its evidence. Times in s, joints in rad, distances in m, world frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import coal
import numpy as np

from planner.model.status import Reason
from planner.model.transforms import Array
from planner.safety.checks import (
    CHECK_OF_PAIR,
    DEFAULT_CLEARANCE,
    Clearance,
    all_pair_distances,
    pair_record,
)
from planner.safety.geometry import PairKind, SafetyWorld

#: m, motion bound below which a step is no longer split
DEFAULT_RESOLUTION = 1e-4
_MAX_DEPTH = 24


@dataclass(frozen=True)
class SweepViolation:
    """The first violation along a trajectory: at time ``t`` (s; between samples
    ``sample`` and ``sample + 1`` when interpolated), joints ``q`` (rad), with evidence."""

    t: float
    sample: int
    q: Array
    clearance: Clearance

    @property
    def reason(self) -> Reason:
        return self.clearance.check.reason

    def __str__(self) -> str:
        return f"t = {self.t:.4f} s: {self.clearance}"


def _part_extent(world: SafetyWorld, index: int) -> float:
    """Radius (m) of a ball about the part's joint origin that contains the part."""
    obj = world.geom_model.geometryObjects[index]
    g = obj.geometry
    centre = float(np.linalg.norm(obj.placement.translation))
    if isinstance(g, coal.Capsule):
        return centre + g.halfLength + g.radius
    if isinstance(g, coal.Box):
        return centre + float(np.linalg.norm(g.halfSide))
    g.computeLocalAABB()
    return centre + float(g.aabb_radius)


def reach_table(world: SafetyWorld) -> Array:
    """(n_parts, nq) matrix R: a part moves at most ``R @ |dq|`` (m) for a joint step dq."""
    model = world.model
    R = np.zeros((len(world.parts), world.nq))
    for part in world.parts:
        joint = world.geom_model.geometryObjects[part.index].parentJoint
        extent = _part_extent(world, part.index)
        offset = 0.0  # chain length from the current joint to the part's joint
        j = joint
        while j > 0:
            R[part.index, model.joints[j].idx_q] = offset + extent
            offset += float(np.linalg.norm(model.jointPlacements[j].translation))
            j = model.parents[j]
    return R


def _required(world: SafetyWorld, clearance: float) -> Array:
    return np.array([0.0 if k is PairKind.ARM_SELF else clearance for k in world.pair_kinds])


def check_sweep(
    world: SafetyWorld,
    t: Array,
    q: Array,
    clearance: float = DEFAULT_CLEARANCE,
    resolution: float = DEFAULT_RESOLUTION,
) -> SweepViolation | None:
    """First collision-pair violation along samples ``q`` (M x nq, rad) at times ``t`` (M,
    s), or None when every pair keeps its distance over the whole trajectory."""
    t = np.asarray(t, dtype=float).reshape(-1)
    Q = np.asarray(q, dtype=float)
    if Q.ndim != 2 or Q.shape != (len(t), world.nq) or not np.all(np.isfinite(Q)):
        raise ValueError(f"expected q of shape ({len(t)}, {world.nq}) finite rad, got {Q.shape}")
    if not world.pair_kinds:
        return None
    R = reach_table(world)
    pairs = np.array([(cp.first, cp.second) for cp in world.geom_model.collisionPairs])
    req = _required(world, clearance)
    d_prev = all_pair_distances(world, Q[0])
    for k in range(len(t)):
        bad = np.flatnonzero(d_prev < req)
        if bad.size:
            return _violation(
                world, t[k], k, Q[k], int(bad[np.argmin(d_prev[bad] - req[bad])]), clearance
            )
        if k + 1 == len(t):
            break
        hit = _step(world, R, pairs, req, Q[k], Q[k + 1], d_prev, resolution, 0)
        if hit is not None:
            s, qs, i = hit
            return _violation(world, t[k] + s * (t[k + 1] - t[k]), k, qs, i, clearance)
        d_prev = all_pair_distances(world, Q[k + 1])
    return None


def _step(
    world: SafetyWorld,
    R: Array,
    pairs: Array,
    req: Array,
    q0: Array,
    q1: Array,
    d0: Array,
    resolution: float,
    depth: int,
) -> tuple[float, Array, int] | None:
    """Violation inside the step q0 -> q1 as (fraction of the step, q, pair), or None."""
    move = R @ np.abs(q1 - q0)
    bound = move[pairs[:, 0]] + move[pairs[:, 1]]
    if np.all(d0 - bound >= req) or bound.max() <= resolution or depth >= _MAX_DEPTH:
        return None
    qm = (q0 + q1) / 2
    dm = all_pair_distances(world, qm)
    bad = np.flatnonzero(dm < req)
    first = _step(world, R, pairs, req, q0, qm, d0, resolution, depth + 1)
    if first is not None:
        return first[0] / 2, first[1], first[2]
    if bad.size:
        return 0.5, qm, int(bad[np.argmin(dm[bad] - req[bad])])
    second = _step(world, R, pairs, req, qm, q1, dm, resolution, depth + 1)
    if second is not None:
        return 0.5 + second[0] / 2, second[1], second[2]
    return None


def _violation(
    world: SafetyWorld, t: float, k: int, q: Array, pair: int, clearance: float
) -> SweepViolation:
    all_pair_distances(world, q)
    kind = world.pair_kinds[pair]
    required = 0.0 if kind is PairKind.ARM_SELF else clearance
    return SweepViolation(float(t), k, q, pair_record(world, pair, CHECK_OF_PAIR[kind], required))
