"""Swept collision check of a joint trajectory (arm-arm, arm-self, arm-scene).

Between two consecutive samples the joints are taken to move linearly (the robot's servo
interpolates its set points that way). Conservative advancement: a part moves by at most
``sum_j |dq_j| * reach_j`` over a joint step ``dq`` (m), where ``reach_j`` bounds the
distance of any point of the part from joint j's axis by the chain's joint offsets plus the
part's extent (configuration independent, from the model); joints that carry both parts of
a pair do not change their distance and are left out (:func:`pair_weights`). A pair measured
at one sample is certified up to the furthest later sample whose accumulated joint travel
keeps the bound within its distance margin, and measured again there; a pair whose margin
does not cover the next step is checked inside it by halving the step, down to
``resolution`` (m) of motion, where the sampled distance decides. The first violation (in
time) is returned with its evidence. Times in s, joints in rad, distances in m, world frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import coal
import numpy as np
import pinocchio as pin

from planner.model.status import Reason
from planner.model.transforms import Array
from planner.safety.checks import CHECK_OF_PAIR, DEFAULT_CLEARANCE, Clearance, pair_record
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


@lru_cache(maxsize=16)
def pair_weights(world: SafetyWorld) -> Array:
    """(pairs, nq) matrix W: the distance of collision pair i changes by at most
    ``W[i] @ |dq|`` (m) over a linear joint step dq. Joints that carry both parts (the common
    ancestors: a robot's shoulder for two of its own links) move them as one body and are
    left out, so a pair of one robot only counts the joints between its two links."""
    R = reach_table(world)
    carries = R > 0  # joints (columns) that move each part (rows)
    W = np.empty((len(world.pair_kinds), world.nq))
    for i, cp in enumerate(world.geom_model.collisionPairs):
        a, b = int(cp.first), int(cp.second)
        shared = carries[a] & carries[b]
        W[i] = np.where(shared, 0.0, R[a] + R[b])
    W.flags.writeable = False  # cached per world
    return W


def _required(world: SafetyWorld, clearance: float) -> Array:
    return np.array([0.0 if k is PairKind.ARM_SELF else clearance for k in world.pair_kinds])


def _distance(world: SafetyWorld, pair: int) -> float:
    pin.computeDistance(world.geom_model, world.geom_data, pair)
    return float(world.geom_data.distanceResults[pair].min_distance)


#: sample offsets tried when advancing a pair: the largest certified one is taken
_OFFSETS = 2 ** np.arange(0, 18)


def check_sweep(
    world: SafetyWorld,
    t: Array,
    q: Array,
    clearance: float = DEFAULT_CLEARANCE,
    resolution: float = DEFAULT_RESOLUTION,
) -> SweepViolation | None:
    """First collision-pair violation along samples ``q`` (M x nq, rad) at times ``t`` (M,
    s), or None when every pair keeps its distance over the whole trajectory.

    Each pair is measured at a sample, then skipped ahead to the furthest sample its
    distance margin still certifies (its :func:`pair_weights` bound on the joint travel
    since); a pair whose margin does not cover even the next step is checked inside that
    step by bisection down to ``resolution`` (m of motion)."""
    t = np.asarray(t, dtype=float).reshape(-1)
    Q = np.asarray(q, dtype=float)
    if Q.ndim != 2 or Q.shape != (len(t), world.nq) or not np.all(np.isfinite(Q)):
        raise ValueError(f"expected q of shape ({len(t)}, {world.nq}) finite rad, got {Q.shape}")
    if not world.pair_kinds:
        return None
    W = pair_weights(world)
    req = _required(world, clearance)
    travel = np.vstack([np.zeros(world.nq), np.cumsum(np.abs(np.diff(Q, axis=0)), axis=0)])
    M = len(t)
    due = np.zeros(len(req), dtype=int)  # next sample at which each pair is measured
    while True:
        k = int(due.min())
        if k >= M:
            return None
        world.update(Q[k])
        pairs = np.flatnonzero(due == k)
        d = np.array([_distance(world, int(i)) for i in pairs])
        slack = d - req[pairs]
        if np.any(slack < 0):
            i = int(pairs[np.argmin(slack)])
            return _violation(world, t[k], k, Q[k], i, clearance)
        if k + 1 == M:
            return None
        offsets = _OFFSETS[k + _OFFSETS < M]
        moved = (travel[k + offsets] - travel[k]) @ W[pairs].T  # (offsets, pairs)
        ok = moved <= slack[None, :]
        reach = np.where(ok.any(axis=0), offsets[np.argmin(ok, axis=0) - 1], 0)
        reach = np.where(ok.all(axis=0), offsets[-1], reach)  # certified to the last offset
        hits = []
        for p_, r_, dist in zip(pairs, reach, d, strict=True):
            p, r = int(p_), int(r_)
            if r == 0:  # not even the next step is certified: look inside it
                hit = _step(world, W[p], req[p], p, Q[k], Q[k + 1], dist, resolution, 0)
                if hit is not None:
                    hits.append((hit[0], hit[1], p))
                r = 1
            due[p] = k + r
        if hits:
            s, qs, p = min(hits, key=lambda h: h[0])
            return _violation(world, t[k] + s * (t[k + 1] - t[k]), k, qs, p, clearance)


def _step(
    world: SafetyWorld,
    w: Array,
    req: float,
    pair: int,
    q0: Array,
    q1: Array,
    d0: float,
    resolution: float,
    depth: int,
) -> tuple[float, Array] | None:
    """Violation of one pair inside the step q0 -> q1 as (fraction of the step, q), or None."""
    bound = float(w @ np.abs(q1 - q0))
    if d0 - bound >= req or bound <= resolution or depth >= _MAX_DEPTH:
        return None
    qm = (q0 + q1) / 2
    world.update(qm)
    dm = _distance(world, pair)
    first = _step(world, w, req, pair, q0, qm, d0, resolution, depth + 1)
    if first is not None:
        return first[0] / 2, first[1]
    if dm < req:
        return 0.5, qm
    second = _step(world, w, req, pair, qm, q1, dm, resolution, depth + 1)
    if second is not None:
        return 0.5 + second[0] / 2, second[1]
    return None


def _violation(
    world: SafetyWorld, t: float, k: int, q: Array, pair: int, clearance: float
) -> SweepViolation:
    world.update(q)
    pin.computeDistance(world.geom_model, world.geom_data, pair)
    kind = world.pair_kinds[pair]
    required = 0.0 if kind is PairKind.ARM_SELF else clearance
    return SweepViolation(float(t), k, q, pair_record(world, pair, CHECK_OF_PAIR[kind], required))
