"""The beam chain as one named CasADi function (paper Eqs. 1-2).

``beam_function(kinematics)`` builds, once per tuple of robot models, the function

    inputs : q (nq x 1, all robots stacked), world_T_laser (4x4),
             world_T_base (4 x 4N, horizontally stacked), flange_T_mirror (4 x 4N),
             roi_half (2 x N, half extents of each mirror's ROI), target (3), normal (3;
             zero vector = no normal)
    outputs: spot (3), hits (3 x N), uv (2 x N), dirs (3 x N+1), front (1 x N, -n.v > 0
             on the front face), ahead (1 x N, ray parameter t > 0 when the mirror is ahead),
             roi (2 x N, roi_half - |uv| >= 0 inside), target_ahead (s > 0), residual (3,
             spot - target), error (|residual|), incidence (rad, 0 without normal)

Parameters are inputs, not constants, so calibration and sensitivity studies differentiate
through the same graph as the planner. :class:`BeamModel` binds it to a :class:`System`.
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import casadi as ca
import numpy as np

from planner.model.kinematics import RobotKinematics
from planner.model.system import System
from planner.model.transforms import Array

BEAM_INPUTS = [
    "q",
    "world_T_laser",
    "world_T_base",
    "flange_T_mirror",
    "roi_half",
    "target",
    "normal",
]
BEAM_OUTPUTS = [
    "spot",
    "hits",
    "uv",
    "dirs",
    "front",
    "ahead",
    "roi",
    "target_ahead",
    "residual",
    "error",
    "incidence",
]


def reflect(v: ca.SX, n: ca.SX) -> ca.SX:
    """Mirror reflection of direction v about unit normal n (Eq. 2)."""
    return v - 2 * ca.dot(v, n) * n


def beam_chain(
    q: ca.SX,
    world_T_laser: ca.SX,
    world_T_base: list[ca.SX],
    flange_T_mirror: list[ca.SX],
    kinematics: tuple[RobotKinematics, ...],
) -> tuple[list[ca.SX], list[ca.SX], list[ca.SX], list[ca.SX], list[ca.SX], list[ca.SX]]:
    """Symbolic trace of the chain: (hits, uv, dirs, front, ahead, world_T_mirror) per mirror."""
    p = world_T_laser[:3, 3]
    v = world_T_laser[:3, 2]
    hits, uvs, dirs, fronts, aheads, mirrors = [], [], [v], [], [], []
    i0 = 0
    for i, kin in enumerate(kinematics):
        qi = q[i0 : i0 + kin.nq]
        i0 += kin.nq
        world_T_mirror = ca.mtimes([world_T_base[i], kin.casadi_fk_expr(qi), flange_T_mirror[i]])
        c = world_T_mirror[:3, 3]
        n = world_T_mirror[:3, 2]
        nv = ca.dot(n, v)
        t = ca.dot(n, c - p) / nv
        h = p + t * v
        uv = ca.mtimes(world_T_mirror[:3, :2].T, h - c)
        v = reflect(v, n)
        p = h
        hits.append(h)
        uvs.append(uv)
        dirs.append(v)
        fronts.append(-nv)
        aheads.append(t)
        mirrors.append(world_T_mirror)
    return hits, uvs, dirs, fronts, aheads, mirrors


class ChainSymbols(NamedTuple):
    """Symbolic chain parameters, named and shaped as the beam function's inputs."""

    q: ca.SX  # nq x 1, every robot's joints stacked (rad)
    world_T_laser: ca.SX  # 4 x 4
    world_T_base: ca.SX  # 4 x 4N, horizontally stacked
    flange_T_mirror: ca.SX  # 4 x 4N, horizontally stacked
    roi_half: ca.SX  # 2 x N (m)

    @property
    def bases(self) -> list[ca.SX]:
        """``world_T_base`` of each robot (4 x 4 blocks, chain order)."""
        return [self.world_T_base[:, 4 * i : 4 * i + 4] for i in range(self.roi_half.shape[1])]

    @property
    def mounts(self) -> list[ca.SX]:
        """``flange_T_mirror`` of each robot (4 x 4 blocks, chain order)."""
        return [self.flange_T_mirror[:, 4 * i : 4 * i + 4] for i in range(self.roi_half.shape[1])]


def chain_symbols(kinematics: tuple[RobotKinematics, ...]) -> ChainSymbols:
    """Fresh symbols for a chain's parameters (reuse them in NLPs and residuals)."""
    N = len(kinematics)
    return ChainSymbols(
        ca.SX.sym("q", sum(k.nq for k in kinematics)),
        ca.SX.sym("world_T_laser", 4, 4),
        ca.SX.sym("world_T_base", 4, 4 * N),
        ca.SX.sym("flange_T_mirror", 4, 4 * N),
        ca.SX.sym("roi_half", 2, N),
    )


@lru_cache(maxsize=32)
def beam_function(kinematics: tuple[RobotKinematics, ...]) -> ca.Function:
    """The named beam function for a chain of robot models (cached per chain)."""
    sym = chain_symbols(kinematics)
    q, world_T_laser, world_T_base, flange_T_mirror, roi_half = sym
    target = ca.SX.sym("target", 3)
    normal = ca.SX.sym("normal", 3)

    hits, uvs, dirs, fronts, aheads, _ = beam_chain(
        q, world_T_laser, sym.bases, sym.mounts, kinematics
    )
    p, v = hits[-1], dirs[-1]

    has_normal = ca.dot(normal, normal) > 0
    nn = normal / ca.sqrt(ca.fmax(ca.dot(normal, normal), 1e-300))
    s_plane = ca.dot(nn, target - p) / ca.dot(nn, v)
    s_ray = ca.dot(v, target - p)
    s = ca.if_else(has_normal, s_plane, s_ray)
    spot = p + s * v
    residual = spot - target
    incidence = ca.if_else(has_normal, ca.acos(ca.fmin(ca.fabs(ca.dot(v, nn)), 1.0)), 0.0)
    uv = ca.horzcat(*uvs)
    return ca.Function(
        "beam",
        [q, world_T_laser, world_T_base, flange_T_mirror, roi_half, target, normal],
        [
            spot,
            ca.horzcat(*hits),
            uv,
            ca.horzcat(*dirs),
            ca.horzcat(*fronts),
            ca.horzcat(*aheads),
            roi_half - ca.fabs(uv),
            s,
            residual,
            ca.norm_2(residual),
            incidence,
        ],
        BEAM_INPUTS,
        BEAM_OUTPUTS,
    )


class BeamTrace(NamedTuple):
    """Numeric result of one trace; arrays in the world frame (see module docstring)."""

    spot: Array
    hits: Array  # (N, 3)
    uv: Array  # (N, 2)
    dirs: Array  # (N + 1, 3)
    front: Array  # (N,)
    ahead: Array  # (N,)
    roi: Array  # (N, 2)
    target_ahead: float
    residual: Array
    error: float
    incidence: float

    @property
    def valid(self) -> bool:
        """Every reflection valid (ahead, front face, inside ROI) and the target ahead."""
        return bool(
            np.all(self.front > 0)
            and np.all(self.ahead > 0)
            and np.all(self.roi >= 0)
            and self.target_ahead > 0
        )


def system_params(system: System) -> dict[str, Array]:
    """The parameter inputs of :func:`beam_function` for a system (everything but q/target)."""
    return {
        "world_T_laser": system.world_T_laser,
        "world_T_base": np.hstack([r.world_T_base for r in system.robots]),
        "flange_T_mirror": np.hstack([r.mirror.flange_T_mirror for r in system.robots]),
        "roi_half": np.column_stack([r.mirror.roi_half for r in system.robots]),
    }


class BeamModel:
    """The beam function bound to one system's geometry."""

    def __init__(self, system: System) -> None:
        self.system = system
        self.function = beam_function(tuple(r.kinematics for r in system.robots))
        self.params = system_params(system)

    def trace(
        self, q: Array, target: Array | None = None, normal: Array | None = None
    ) -> BeamTrace:
        """Trace the beam at stacked joints ``q``; without ``target`` the spot is the point
        of the last ray one metre beyond the last mirror."""
        q = np.asarray(q, dtype=float)
        if target is None:
            out = self.function(q, *self.params.values(), np.zeros(3), np.zeros(3))
            hits, dirs = np.asarray(out[1]), np.asarray(out[3])
            target = hits[:, -1] + dirs[:, -1]
        normal_in = np.zeros(3) if normal is None else np.asarray(normal, dtype=float)
        out = self.function(q, *self.params.values(), np.asarray(target, dtype=float), normal_in)
        arr = [np.asarray(o, dtype=float) for o in out]
        return BeamTrace(
            spot=arr[0].ravel(),
            hits=arr[1].T,
            uv=arr[2].T,
            dirs=arr[3].T,
            front=arr[4].ravel(),
            ahead=arr[5].ravel(),
            roi=arr[6].T,
            target_ahead=arr[7].item(),
            residual=arr[8].ravel(),
            error=arr[9].item(),
            incidence=arr[10].item(),
        )

    def world_T_mirrors(self, q: Array) -> list[Array]:
        """Pose of each mirror in the world at stacked joints ``q`` (Pinocchio FK)."""
        out = []
        for r, qi in zip(self.system.robots, self.system.split_q(q).values(), strict=True):
            out.append(r.world_T_base @ r.kinematics.fk(qi) @ r.mirror.flange_T_mirror)
        return out
