"""Clearance as linear constraints of an NLP: the pairs within a margin of their required
distance at a configuration, each with its distance gradient in the joints.

For parts a and b with coal witness points ``p_a``, ``p_b`` and unit normal ``n`` (a -> b,
world frame), ``d(distance)/dq = n . (J_b(p_b) - J_a(p_a))``, ``J_x(p)`` the 3 x nq
Jacobian of the world point ``p`` fixed on x's body (zero on the scene, the keep-out volumes
and the robot bases). A beam segment's witness point ``p = (1 - s) P_k + s P_(k+1)`` moves
with the polyline's points: ``J = (1 - s) dP_k/dq + s dP_(k+1)/dq``; the laser exit is
fixed and the spot end is held on its target by the IK's equality constraints, so both have
zero Jacobians; the mirror hits' Jacobians come from the beam graph (:func:`hit_jacobian`).

A row says ``gradient . (q - q0) + distance >= required + buffer``: the linearisation at
``q0``, ``buffer`` (m) absorbing the second-order error so that a solution of the
linearised problem passes the exact rules after one or two re-linearisations. Pairs: arm-arm,
arm-self, arm-scene (the collision world's pairs) and every beam segment against the arm
parts and keep-out volumes (:class:`~planner.safety.beam_pairs.BeamPairs`). World frame,
metres, radians.
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import casadi as ca
import numpy as np
import pinocchio as pin

from planner.beam.graph import beam_chain, chain_symbols, system_params
from planner.model.kinematics import RobotKinematics
from planner.model.mirror import Surface
from planner.model.transforms import Array
from planner.safety.model import Safety

#: m beyond its required distance at which a pair becomes a constraint row
NEAR_MARGIN = 0.02
#: m a row asks beyond the required distance (covers the linearisation error)
BUFFER = 5e-4


class ClearanceRow(NamedTuple):
    """One pair's linearised clearance at ``q0`` (stacked rad): ``gradient`` (nq, m/rad) of
    its ``distance`` (m), which must stay >= ``required`` (m). ``key`` names the pair
    (``("arm", pair)`` or ``("beam", pair)``), ``label`` reads ``a - b``."""

    key: tuple[str, int]
    gradient: Array
    distance: float
    required: float
    q0: Array
    label: str

    def bound(self, buffer: float = BUFFER) -> float:
        """Lower bound of ``gradient . q`` (m)."""
        return float(self.required + buffer - self.distance + self.gradient @ self.q0)


@lru_cache(maxsize=16)
def hit_jacobian(
    kinematics: tuple[RobotKinematics, ...], surfaces: tuple[Surface, ...]
) -> ca.Function:
    """``beam_hit_jac``: the mirror hits (3 x N, world m) and their Jacobian in the stacked
    joints (3N x nq, rows hit-major: x, y, z of hit 0, then hit 1, ...), geometry inputs by
    name as in :func:`planner.beam.graph.beam_function`."""
    sym = chain_symbols(kinematics)
    hits, *_ = beam_chain(sym.q, sym.world_T_laser, sym.bases, sym.mounts, kinematics, surfaces)
    H = ca.vertcat(*hits)
    ins = sym._asdict()
    outs = {"hits": ca.horzcat(*hits), "J": ca.densify(ca.jacobian(H, sym.q))}
    return ca.Function("beam_hit_jac", ins | outs, list(ins), list(outs))


def polyline_jacobians(safety: Safety, q: Array) -> Array:
    """dP/dq of the beam polyline laser exit, N hits, spot ((N + 2) x 3 x nq): the hits'
    from the beam graph, the fixed laser exit's and the target-held spot's zero."""
    system = safety.system
    f = hit_jacobian(system.kinematics, system.surfaces)
    J = np.asarray(f(q=q, **system_params(system))["J"], dtype=float)
    N = system.n_robots
    out = np.zeros((N + 2, 3, system.nq))
    out[1 : N + 1] = J.reshape(N, 3, system.nq)
    return out


def _skew(r: Array) -> Array:
    return np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])


class Linearizer:
    """Constraint rows of ``safety``'s distance rules at a configuration (module docstring):
    every pair closer than its required distance + ``margin`` (m)."""

    def __init__(self, safety: Safety, margin: float = NEAR_MARGIN) -> None:
        self.safety = safety
        self.margin = margin
        world = safety.world
        self.near = pin.GeometryData(world.geom_model)
        for req, kind in zip(self.near.collisionRequests, world.pair_kinds, strict=True):
            req.security_margin = safety.required(kind) + margin
        for req in self.near.distanceRequests:
            req.gjk_tolerance = 1e-12
        bp = safety.beam_pairs
        self.near_beam = pin.GeometryData(bp.model)
        for req, info in zip(self.near_beam.collisionRequests, bp.pair_info, strict=True):
            req.security_margin = info[3] + margin
        for req in self.near_beam.distanceRequests:
            req.gjk_tolerance = 1e-12

    def _point_jacobian(self, index: int, p: Array) -> Array:
        """3 x nq Jacobian of world point ``p`` fixed on world part ``index`` (after
        ``computeJointJacobians``)."""
        world = self.safety.world
        joint = world.geom_model.geometryObjects[index].parentJoint
        if joint == 0:
            return np.zeros((3, world.nq))
        J = pin.getJointJacobian(world.model, world.data, joint, pin.LOCAL_WORLD_ALIGNED)
        r = p - world.data.oMi[joint].translation
        return np.asarray(J[:3] - _skew(r) @ J[3:])

    def rows(self, q: Array, points: Array | None = None, dP: Array | None = None
             ) -> list[ClearanceRow]:  # fmt: skip
        """The rows at stacked joints ``q`` (rad): the arm pairs, and with the beam
        polyline ``points`` ((N + 2) x 3, world m) and its Jacobians ``dP`` ((N + 2) x 3 x nq,
        default :func:`polyline_jacobians`) the beam pairs; nearest to violation first."""
        q = np.asarray(q, dtype=float)
        s, world = self.safety, self.safety.world
        world.update(q)
        pin.computeJointJacobians(world.model, world.data, q)
        out = self._arm_rows(q)
        if points is not None:
            P = np.asarray(points, dtype=float)
            out += self._beam_rows(q, P, polyline_jacobians(s, q) if dP is None else dP)
        return sorted(out, key=lambda r: r.distance - r.required)

    def _arm_rows(self, q: Array) -> list[ClearanceRow]:
        s, world = self.safety, self.safety.world
        gm, gd = world.geom_model, self.near
        pin.updateGeometryPlacements(world.model, world.data, gm, gd)
        if not world.pair_kinds or not pin.computeCollisions(gm, gd, False):
            return []
        out = []
        for i, res in enumerate(gd.collisionResults):
            if not res.isCollision():
                continue
            pin.computeDistance(gm, gd, i)
            d = gd.distanceResults[i]
            cp = gm.collisionPairs[i]
            p_a, p_b = np.array(d.getNearestPoint1()), np.array(d.getNearestPoint2())
            n = np.array(d.normal)
            grad = n @ (self._point_jacobian(cp.second, p_b) - self._point_jacobian(cp.first, p_a))
            label = f"{world.parts[cp.first].name} - {world.parts[cp.second].name}"
            req = s.required(world.pair_kinds[i])
            out.append(ClearanceRow(("arm", i), grad, float(d.min_distance), req, q, label))
        return out

    def _beam_rows(self, q: Array, P: Array, dP: Array) -> list[ClearanceRow]:
        s, world = self.safety, self.safety.world
        bp = s.beam_pairs
        bp.place(P)
        gd = self.near_beam
        pin.updateGeometryPlacements(world.model, world.data, bp.model, gd)
        for seg in bp.segments:
            gd.oMg[seg] = bp.data.oMg[seg]
        if not pin.computeCollisions(bp.model, gd, False):
            return []
        out = []
        for i, res in enumerate(gd.collisionResults):
            if not res.isCollision():
                continue
            _, k, j, required = bp.pair_info[i]
            pin.computeDistance(bp.model, gd, i)
            d = gd.distanceResults[i]
            p_part, p_seg = np.array(d.getNearestPoint1()), np.array(d.getNearestPoint2())
            n = -np.array(d.normal)  # segment -> part
            a, b = P[k], P[k + 1]
            L2 = float((b - a) @ (b - a))
            t = 0.0 if L2 <= 0 else float(np.clip((p_seg - a) @ (b - a) / L2, 0.0, 1.0))
            J_seg = (1 - t) * dP[k] + t * dP[k + 1]
            part = bp.parts[j]
            grad = n @ (self._point_jacobian(part.index, p_part) - J_seg)
            label = f"beam {s.labels[k]} - {part.name}"
            out.append(ClearanceRow(("beam", i), grad, float(d.min_distance), required, q, label))
        return out


def cut_matrix(rows: list[ClearanceRow], n_rows: int, nq: int, buffer: float = BUFFER
               ) -> tuple[Array, Array]:  # fmt: skip
    """The first ``n_rows`` rows as (A n_rows x nq, lower bounds n_rows): ``A q >= lb``;
    unused rows are zero with lower bound -inf."""
    A, lb = np.zeros((n_rows, nq)), np.full(n_rows, -np.inf)
    for i, r in enumerate(rows[:n_rows]):
        A[i], lb[i] = r.gradient, r.bound(buffer)
    return A, lb
