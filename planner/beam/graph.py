"""The beam chain as one named CasADi function (paper Eqs. 1-2).

``beam_function(kinematics, surfaces)`` builds, once per chain (the tuple of robot models and
the tuple of their mirrors' surfaces, :class:`planner.model.mirror.Surface`), the function

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

from planner.beam.trace import BeamTrace, mirror_poses
from planner.model.kinematics import RobotKinematics
from planner.model.mirror import Surface
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


def beam_chain(
    q: ca.SX,
    world_T_laser: ca.SX,
    world_T_base: list[ca.SX],
    flange_T_mirror: list[ca.SX],
    kinematics: tuple[RobotKinematics, ...],
    surfaces: tuple[Surface, ...],
) -> tuple[list[ca.SX], list[ca.SX], list[ca.SX], list[ca.SX], list[ca.SX], list[ca.SX]]:
    """Symbolic trace of the chain: (hits, uv, dirs, front, ahead, world_T_mirror) per mirror,
    each mirror's face asked through its surface's CasADi twin (:mod:`planner.model.mirror`)."""
    p = world_T_laser[:3, 3]
    v = world_T_laser[:3, 2]
    hits, uvs, dirs, fronts, aheads, mirrors = [], [], [v], [], [], []
    i0 = 0
    for i, (kin, surface) in enumerate(zip(kinematics, surfaces, strict=True)):
        qi = q[i0 : i0 + kin.nq]
        i0 += kin.nq
        world_T_mirror = ca.mtimes([world_T_base[i], kin.casadi_fk_expr(qi), flange_T_mirror[i]])
        t, h, uv = surface.intersect_sx(world_T_mirror, p, v)
        fronts.append(-ca.dot(surface.normal_sx(world_T_mirror, h), v))
        v = surface.reflect_sx(world_T_mirror, v, h)
        p = h
        hits.append(h)
        uvs.append(uv)
        dirs.append(v)
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
def beam_function(
    kinematics: tuple[RobotKinematics, ...], surfaces: tuple[Surface, ...]
) -> ca.Function:
    """The named beam function for a chain of robot models and their mirrors' surfaces
    (cached per chain)."""
    sym = chain_symbols(kinematics)
    target = ca.SX.sym("target", 3)
    normal = ca.SX.sym("normal", 3)

    hits, uvs, dirs, fronts, aheads, _ = beam_chain(
        sym.q, sym.world_T_laser, sym.bases, sym.mounts, kinematics, surfaces
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
    inputs = {**sym._asdict(), "target": target, "normal": normal}
    outputs = {
        "spot": spot,
        "hits": ca.horzcat(*hits),
        "uv": uv,
        "dirs": ca.horzcat(*dirs),
        "front": ca.horzcat(*fronts),
        "ahead": ca.horzcat(*aheads),
        "roi": sym.roi_half - ca.fabs(uv),
        "target_ahead": s,
        "residual": residual,
        "error": ca.norm_2(residual),
        "incidence": incidence,
    }
    return ca.Function("beam", inputs | outputs, BEAM_INPUTS, BEAM_OUTPUTS)


def system_params(system: System) -> dict[str, Array]:
    """The geometry inputs of :func:`beam_function` for a system, by name (every
    :class:`ChainSymbols` field but ``q``)."""
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
        self.function = beam_function(system.kinematics, system.surfaces)
        self.params = system_params(system)

    def _call(self, q: Array, target: Array, normal: Array) -> dict[str, Array]:
        out = self.function(q=q, **self.params, target=target, normal=normal)
        return {k: np.asarray(x, dtype=float) for k, x in out.items()}

    def trace(
        self, q: Array, target: Array | None = None, normal: Array | None = None
    ) -> BeamTrace:
        """Trace the beam at stacked joints ``q`` (rad) for ``target`` (world, m) with its
        optional unit ``normal``; without ``target`` the spot is the point of the last ray one
        metre beyond the last mirror."""
        q = np.asarray(q, dtype=float)
        if target is None:
            out = self._call(q, np.zeros(3), np.zeros(3))
            target = out["hits"][:, -1] + out["dirs"][:, -1]
        normal_in = np.zeros(3) if normal is None else np.asarray(normal, dtype=float)
        out = self._call(q, np.asarray(target, dtype=float), normal_in)
        return BeamTrace(
            spot=out["spot"].ravel(),
            error=out["error"].item(),
            hits=out["hits"].T,
            uv=out["uv"].T,
            dirs=out["dirs"].T,
            front=out["front"].ravel(),
            ahead=out["ahead"].ravel(),
            roi=out["roi"].T,
            target_ahead=out["target_ahead"].item(),
            incidence=out["incidence"].item(),
            residual=out["residual"].ravel(),
            world_T_mirrors=tuple(self.world_T_mirrors(q)),
        )

    def world_T_mirrors(self, q: Array) -> list[Array]:
        """Pose of each mirror in the world at stacked joints ``q`` (Pinocchio FK)."""
        return mirror_poses(self.system, np.asarray(q, dtype=float))
