"""Plain-numpy beam geometry for the independent checkers (no CasADi, no Pinocchio).

Shared by :mod:`planner.verify.check` (solved targets) and :mod:`planner.verify.trajectory` (dense
trajectories): the UR5e forward kinematics by standard DH, the pose
mappings, the robots' joint limits as written in a resolved scenario, and the reflection
chain over the checker's own mirror faces (:mod:`planner.verify.faces`), written again from
the conventions rather than taken from the planner's CasADi graph. Units SI, poses
``a_T_b``, all rays in the world frame.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from planner.errors import InputError
from planner.model.limits import Limits
from planner.model.transforms import Array, make_T, quat_to_matrix, rpy_to_matrix
from planner.verify.faces import FLAT_FACE, Face, reflect

UR5E_D = (0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996)  # m
UR5E_A = (0.0, -0.425, -0.3922, 0.0, 0.0, 0.0)  # m
UR5E_ALPHA = (np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0)  # rad


def ur5e_dh_fk(q: Array) -> Array:
    """``base_T_flange`` of the nominal UR5e by standard DH, Rz(q) Tz(d) Tx(a) Rx(alpha):
    joints ``q`` (6,) rad -> (4, 4), or (M, 6) -> (M, 4, 4)."""
    q = np.asarray(q, dtype=float)
    Q = np.atleast_2d(q)
    T = np.tile(np.eye(4), (len(Q), 1, 1))
    for i, (d, a, al) in enumerate(zip(UR5E_D, UR5E_A, UR5E_ALPHA, strict=True)):
        ct, st, ca, sa = np.cos(Q[:, i]), np.sin(Q[:, i]), np.cos(al), np.sin(al)
        A = np.zeros((len(Q), 4, 4))
        A[:, 0, 0], A[:, 0, 1], A[:, 0, 2], A[:, 0, 3] = ct, -st * ca, st * sa, a * ct
        A[:, 1, 0], A[:, 1, 1], A[:, 1, 2], A[:, 1, 3] = st, ct * ca, -ct * sa, a * st
        A[:, 2, 1], A[:, 2, 2], A[:, 2, 3] = sa, ca, d
        A[:, 3, 3] = 1.0
        T = T @ A
    return T[0] if q.ndim == 1 else T


def pose_matrix(d: Any, where: str = "pose") -> Array:
    """A pose mapping (``{matrix}`` | ``{xyz, rpy | rpy_deg | quat}``) as a
    4x4; ``xyz`` defaults to zeros, the rotation to identity. InputError names ``where``."""
    if not isinstance(d, dict):
        raise InputError("expected a pose mapping", where)
    if "matrix" in d:
        T = np.asarray(d["matrix"], dtype=float)
        if T.shape != (4, 4):
            raise InputError(f"matrix must be 4x4, got {T.shape}", where)
        return T
    R = np.eye(3)
    if "rpy" in d:
        R = rpy_to_matrix(d["rpy"])
    elif "rpy_deg" in d:
        R = rpy_to_matrix(np.radians(d["rpy_deg"]))
    elif "quat" in d:
        R = quat_to_matrix(d["quat"])
    return make_T(R, d.get("xyz", [0.0, 0.0, 0.0]))


def limits_from_dict(lim: dict[str, Any] | None, n: int) -> Limits:
    """A robot's ``limits`` mapping (any key may be missing or null) over the documented defaults
    for ``n`` joints (:meth:`Limits.ur_default`)."""
    lim = lim or {}
    default = Limits.ur_default(n)
    return Limits(
        **{
            k: np.asarray(lim[k] if lim.get(k) is not None else getattr(default, k), dtype=float)
            for k in ("lower", "upper", "velocity", "acceleration", "jerk")
        }
    )


class BeamRays(NamedTuple):
    """A batch of M traces through the mirror chain, world frame: the last ray's origin
    ``p`` and unit direction ``v`` (M x 3); per mirror (lists in chain order) the hit point
    (M x 3), its mirror coordinates ``uv`` (M x 2, m), ``front`` = -n.v (> 0 on the front
    face) and ``ahead`` = ray parameter t (m, > 0 when the mirror is ahead)."""

    p: Array
    v: Array
    hits: list[Array]
    uv: list[Array]
    front: list[Array]
    ahead: list[Array]


def trace_rays(
    world_T_laser: Array, world_T_mirrors: Sequence[Array], faces: Sequence[Face] | None = None
) -> BeamRays:
    """Reflect the laser beam off each mirror in turn, each through its own face of
    :mod:`planner.verify.faces` (``faces``, chain order; None: all flat, as every mirror a
    plan document describes); ``world_T_mirrors`` holds one (M, 4, 4) stack per mirror, the
    M configurations traced side by side."""
    M = len(world_T_mirrors[0]) if len(world_T_mirrors) else 1
    p = np.tile(world_T_laser[:3, 3], (M, 1))
    v = np.tile(world_T_laser[:3, 2] / np.linalg.norm(world_T_laser[:3, 2]), (M, 1))
    rays = BeamRays(p, v, [], [], [], [])
    faces = [FLAT_FACE] * len(world_T_mirrors) if faces is None else faces
    for wTm, face in zip(world_T_mirrors, faces, strict=True):
        t, h, uv = face.intersect(wTm, p, v)
        rays.hits.append(h)
        rays.uv.append(uv)
        rays.front.append(-np.einsum("ij,ij->i", face.normal(wTm, h), v))
        rays.ahead.append(t)
        v = reflect(face, wTm, v, h)
        p = h
    return rays._replace(p=p, v=v)
