"""The beam trace: one result type with one validity rule, and the fast numeric trace.

:class:`BeamTrace` is what every planner-side trace returns, whether computed here with
numpy and Pinocchio (:func:`trace_beam`, the IK hot path) or through the CasADi beam graph
(:meth:`planner.beam.graph.BeamModel.trace`). Its :attr:`BeamTrace.valid` is the rule of
:mod:`planner.model.validity`.

Model: the ray leaves the laser along +z of ``world_T_laser``, meets each robot's mirror in
robot order (:meth:`planner.model.mirror.Mirror.intersect`) and reflects
(:meth:`~planner.model.mirror.Mirror.reflect`). With a target normal the spot is the last
ray's intersection with the target's tangent plane, otherwise the point of the last ray
closest to the target. Everything in the world frame, metres and radians.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from planner.model.system import System
from planner.model.transforms import Array
from planner.model.validity import chain_ok


class BeamTrace(NamedTuple):
    """The beam at one stacked configuration for one target (world frame, metres)."""

    spot: Array  # (3,)
    error: float  # |spot - target|, metres
    hits: Array  # (N, 3)
    uv: Array  # (N, 2) hit in mirror coordinates
    dirs: Array  # (N + 1, 3) unit ray directions, laser first
    front: Array  # (N,) -n.v at each hit, > 0 on the front face
    ahead: Array  # (N,) ray parameter of each hit (m), > 0 when the mirror is ahead
    roi: Array  # (N, 2) roi_half - |uv| (m), >= 0 inside the ROI
    target_ahead: float  # ray parameter (m) of the spot on the last ray
    incidence: float  # rad, angle between the last ray and the target normal (0 without)
    residual: Array  # (3,) spot - target, metres
    world_T_mirrors: tuple[Array, ...]  # pose of each mirror, chain order

    @property
    def valid(self) -> bool:
        """Every reflection valid (front face, ahead, inside the ROI) and the target ahead
        (:func:`planner.model.validity.chain_ok`)."""
        return chain_ok(self.front, self.ahead, self.roi, self.target_ahead)


def mirror_poses(system: System, q: Array) -> list[Array]:
    """``world_T_mirror`` of every robot at stacked joints ``q`` (rad), Pinocchio FK."""
    out, i = [], 0
    for r in system.robots:
        base_T_flange = r.kinematics.fk(q[i : i + r.nq])
        out.append(r.world_T_base @ base_T_flange @ r.mirror.flange_T_mirror)
        i += r.nq
    return out


def beam_vertices(system: System, hits: Array, spot: Array) -> Array:
    """The beam's N + 2 vertices (world, m): laser exit, the N mirror hits, the spot."""
    return np.vstack([system.world_T_laser[:3, 3], np.asarray(hits), np.asarray(spot)])


def spot_on_target(p: Array, v: Array, target: Array, normal: Array | None) -> tuple[float, float]:
    """Ray parameter ``s`` (m) of the spot of the ray ``p + s v`` (unit ``v``) for a target:
    on the target's tangent plane with a ``normal``, else the point closest to the target;
    and the incidence (rad) between the ray and the normal (0 without one)."""
    if normal is None:
        return float(v @ (target - p)), 0.0
    nn = np.asarray(normal, dtype=float)
    s = float(nn @ (target - p)) / float(nn @ v)
    return s, float(np.arccos(min(abs(float(v @ nn)), 1.0)))


def trace_beam(system: System, q: Array, target: Array, normal: Array | None = None) -> BeamTrace:
    """Trace the beam at stacked joints ``q`` (rad) and measure the spot against ``target``
    (world, m), optionally with the target's unit surface ``normal``."""
    mirrors = mirror_poses(system, np.asarray(q, dtype=float))
    p = system.world_T_laser[:3, 3].copy()
    v = system.world_T_laser[:3, 2].copy()
    N = len(mirrors)
    hits, uv, dirs = np.empty((N, 3)), np.empty((N, 2)), np.empty((N + 1, 3))
    front, ahead, roi = np.empty(N), np.empty(N), np.empty((N, 2))
    dirs[0] = v
    for i, (M, r) in enumerate(zip(mirrors, system.robots, strict=True)):
        t, h, uv[i] = r.mirror.intersect(M, p, v)
        roi[i] = r.mirror.roi_half - np.abs(uv[i])
        front[i] = -float(r.mirror.normal(M, h) @ v)
        v = r.mirror.reflect(M, v, h)
        v /= np.linalg.norm(v)
        p = h
        hits[i], dirs[i + 1], ahead[i] = h, v, t
    target = np.asarray(target, dtype=float)
    s, incidence = spot_on_target(p, v, target, normal)
    spot = p + s * v
    return BeamTrace(
        spot=spot,
        error=float(np.linalg.norm(spot - target)),
        hits=hits,
        uv=uv,
        dirs=dirs,
        front=front,
        ahead=ahead,
        roi=roi,
        target_ahead=s,
        incidence=incidence,
        residual=spot - target,
        world_T_mirrors=tuple(mirrors),
    )
