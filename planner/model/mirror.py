"""The mirror surface behind one seam: where a ray meets it, and how it reflects.

Every computation of the planner that needs the mirror surface goes through
:class:`Mirror` (numpy, one ray) or its CasADi twin :func:`intersect_sx` /
:func:`normal_sx` / :func:`reflect_sx` (the symbolic beam graph of
:mod:`planner.beam.graph`); the independent checker has its own in
:mod:`planner.verify.numpy_beam`. Today's mirror is flat: the reflective face is the
``z = 0`` plane of the mirror frame with its normal along +z, the region of interest a
rectangle centred on the origin. A curved mirror changes this module (and the checker's
twin), nothing else. Poses ``a_T_b`` (4 x 4), points and directions in the world frame,
metres.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from planner.model.transforms import Array
from schemas import defaults

if TYPE_CHECKING:
    import casadi as ca

DEFAULT_MIRROR_SIZE = (0.075, 0.075)  # m
DEFAULT_ROI_MARGIN = defaults.ROI_MARGIN_M  # m


@dataclass(frozen=True)
class Mirror:
    """A flat mirror on a flange: +z of ``flange_T_mirror`` is the reflective face's normal;
    ``size`` (m, along mirror x and y), ``roi_margin`` (m) kept clear along every edge."""

    flange_T_mirror: Array
    size: tuple[float, float] = DEFAULT_MIRROR_SIZE
    roi_margin: float = DEFAULT_ROI_MARGIN

    @property
    def roi_half(self) -> Array:
        """Half extents (u, v) of the region the beam must stay in, metres."""
        return np.array([self.size[0] / 2 - self.roi_margin, self.size[1] / 2 - self.roi_margin])

    def intersect(self, world_T_mirror: Array, p: Array, v: Array) -> tuple[float, Array, Array]:
        """Where the ray ``p + t v`` (world; ``v`` unit) meets the face of the mirror at
        ``world_T_mirror``: (ray parameter t in m, hit point in the world, hit ``uv`` in
        mirror x/y in m). ``t`` is ``inf`` for a ray parallel to the face."""
        n, c = world_T_mirror[:3, 2], world_T_mirror[:3, 3]
        nv = float(n @ v)
        t = float(n @ (c - p)) / nv if nv != 0.0 else np.inf
        hit = p + t * v
        return t, hit, world_T_mirror[:3, :2].T @ (hit - c)

    def normal(self, world_T_mirror: Array, hit: Array) -> Array:
        """Unit normal (world) of the reflective face at world point ``hit``."""
        return np.asarray(world_T_mirror[:3, 2])

    def reflect(self, world_T_mirror: Array, v: Array, hit: Array) -> Array:
        """Direction (world) of the ray ``v`` after reflecting at ``hit``: ``v - 2 (v.n) n``."""
        n = self.normal(world_T_mirror, hit)
        return np.asarray(v - 2.0 * float(n @ v) * n)

    def place(self, hit: Array, normal: Array, x_ref: Array, roll: float, uv: Array) -> Array:
        """``world_T_mirror`` whose face has unit ``normal`` (world) at world point ``hit``,
        which it puts at mirror coordinates ``uv`` (m); the mirror x axis is ``x_ref``
        projected on the face and rolled by ``roll`` (rad) about the normal."""
        n = normal
        x = x_ref - (x_ref @ n) * n
        nx = float(np.linalg.norm(x))
        if nx < 1e-6:
            x = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
            x = x - (x @ n) * n
            nx = float(np.linalg.norm(x))
        x = x / nx
        y = np.array(
            [n[1] * x[2] - n[2] * x[1], n[2] * x[0] - n[0] * x[2], n[0] * x[1] - n[1] * x[0]]
        )
        c, s = np.cos(roll), np.sin(roll)
        x, y = c * x + s * y, c * y - s * x
        T = np.eye(4)
        T[:3, 0], T[:3, 1], T[:3, 2] = x, y, n
        T[:3, 3] = hit - uv[0] * x - uv[1] * y
        return T


def intersect_sx(world_T_mirror: ca.SX, p: ca.SX, v: ca.SX) -> tuple[ca.SX, ca.SX, ca.SX]:
    """Symbolic :meth:`Mirror.intersect`: (t, hit, uv) of the ray ``p + t v``."""
    import casadi as ca

    n, c = world_T_mirror[:3, 2], world_T_mirror[:3, 3]
    t = ca.dot(n, c - p) / ca.dot(n, v)
    hit = p + t * v
    return t, hit, ca.mtimes(world_T_mirror[:3, :2].T, hit - c)


def normal_sx(world_T_mirror: ca.SX, hit: ca.SX) -> ca.SX:
    """Symbolic :meth:`Mirror.normal`: unit face normal at ``hit``."""
    return world_T_mirror[:3, 2]


def reflect_sx(world_T_mirror: ca.SX, v: ca.SX, hit: ca.SX) -> ca.SX:
    """Symbolic :meth:`Mirror.reflect`: ``v - 2 (v.n) n`` at ``hit``."""
    import casadi as ca

    n = normal_sx(world_T_mirror, hit)
    return v - 2 * ca.dot(v, n) * n
