"""Fast numeric beam trace for the IK hot path (numpy + Pinocchio FK, no CasADi call).

Same model as :mod:`planner.beam.graph` (SPEC section 3): the ray leaves the laser along +z of
``world_T_laser``, hits each mirror plane in robot order and reflects ``v' = v - 2 (v.n) n``.
Everything is in the world frame, metres and radians.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from planner.model.system import System
from planner.model.transforms import Array

#: smallest accepted ``-n.v`` (front-face cosine) and ray parameters (metres)
MIN_FRONT = 1e-9
MIN_AHEAD = 1e-6


class Evaluation(NamedTuple):
    """Beam at one stacked configuration for one target (world frame, metres)."""

    spot: Array  # (3,)
    error: float  # |spot - target|, metres
    hits: Array  # (N, 3)
    uv: Array  # (N, 2) hit in mirror coordinates
    dirs: Array  # (N + 1, 3) unit ray directions, laser first
    front: Array  # (N,) -n.v, > 0 on the front face
    ahead: Array  # (N,) ray parameter of each hit, > 0 when the mirror is ahead
    roi: Array  # (N, 2) roi_half - |uv|, >= 0 inside the ROI
    target_ahead: float  # ray parameter of the spot on the last ray
    incidence: float  # rad, angle between last ray and the target normal (0 without)
    world_T_mirrors: list[Array]

    @property
    def valid(self) -> bool:
        """Every reflection valid (ahead, front face, inside ROI) and the target ahead."""
        return bool(
            np.all(self.front > MIN_FRONT)
            and np.all(self.ahead > MIN_AHEAD)
            and np.all(self.roi >= 0)
            and self.target_ahead > MIN_AHEAD
        )


def mirror_poses(system: System, q: Array) -> list[Array]:
    """``world_T_mirror`` of every robot at stacked joints ``q``."""
    out, i = [], 0
    for r in system.robots:
        base_T_flange = r.kinematics.fk(q[i : i + r.nq])
        out.append(r.world_T_base @ base_T_flange @ r.mirror.flange_T_mirror)
        i += r.nq
    return out


def evaluate(system: System, q: Array, target: Array, normal: Array | None = None) -> Evaluation:
    """Trace the beam at stacked joints ``q`` and measure the spot against ``target``.

    With a target ``normal`` the spot is the ray's intersection with the target's tangent
    plane, otherwise the point of the last ray closest to the target (SPEC section 3).
    """
    mirrors = mirror_poses(system, np.asarray(q, dtype=float))
    p = system.world_T_laser[:3, 3].copy()
    v = system.world_T_laser[:3, 2].copy()
    N = len(mirrors)
    hits, uv, dirs = np.empty((N, 3)), np.empty((N, 2)), np.empty((N + 1, 3))
    front, ahead, roi = np.empty(N), np.empty(N), np.empty((N, 2))
    dirs[0] = v
    for i, (M, r) in enumerate(zip(mirrors, system.robots, strict=True)):
        n, c = M[:3, 2], M[:3, 3]
        nv = float(n @ v)
        t = float(n @ (c - p)) / nv if nv != 0.0 else np.inf
        h = p + t * v
        uv[i] = M[:3, :2].T @ (h - c)
        roi[i] = r.mirror.roi_half - np.abs(uv[i])
        v = v - 2.0 * nv * n
        v /= np.linalg.norm(v)
        p = h
        hits[i], dirs[i + 1], front[i], ahead[i] = h, v, -nv, t
    target = np.asarray(target, dtype=float)
    incidence = 0.0
    if normal is not None:
        nn = np.asarray(normal, dtype=float)
        s = float(nn @ (target - p)) / float(nn @ v)
        incidence = float(np.arccos(min(abs(float(v @ nn)), 1.0)))
    else:
        s = float(v @ (target - p))
    spot = p + s * v
    return Evaluation(
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
        world_T_mirrors=mirrors,
    )
