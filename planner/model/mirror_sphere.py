"""A spherical mirror face: the second shape behind the mirror seam (:mod:`planner.model.mirror`).

The face is the cap of a sphere of signed radius ``R`` whose vertex is the mirror-frame
origin and whose axis is +z: centre of curvature ``C = (0, 0, R)``; ``R > 0`` is concave
(C in front of the face, where the light comes from), ``R < 0`` convex. Its sag over mirror
x/y ``(u, v)`` is ``z = r^2 / (R + sign(R) sqrt(R^2 - r^2))`` with ``r^2 = u^2 + v^2``, its
outward normal at a point ``h`` (mirror frame) is ``(C - h) / R``. A ray meets the cap where
``|p + t v - C| = |R|`` on the vertex's side (the root whose normal has the larger z), each
root taken in the form that keeps its digits (also for a nearly flat face). ``uv`` is the hit's mirror x/y, as for every
shape. Built in code, as a lab would::

    Mirror(flange_T_mirror, size=(0.075, 0.075), surface=Sphere(radius=0.5))

Metres, world frame unless said.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from planner.model.mirror import Surface
from planner.model.transforms import Array

if TYPE_CHECKING:
    import casadi as ca


@dataclass(frozen=True)
class Sphere(Surface):
    """Spherical cap of signed radius ``radius`` (m; > 0 concave, < 0 convex)."""

    radius: float

    def __post_init__(self) -> None:
        if not (np.isfinite(self.radius) and self.radius != 0.0):
            raise ValueError(
                f"a spherical mirror needs a finite non-zero radius, got {self.radius!r} m"
            )

    @property
    def spec(self) -> dict[str, Any]:
        return {"shape": "sphere", "radius": float(self.radius)}

    def _t(self, pl: Array, vl: Array) -> float:
        """Ray parameter of the cap hit of the mirror-frame ray ``pl + t vl`` (inf: a miss)."""
        R = self.radius
        a = float(vl @ vl)
        b = float(vl @ pl) - R * vl[2]
        c = float(pl @ pl) - 2.0 * R * pl[2]  # = |pl - C|^2 - R^2, the R^2 cancelled exactly
        disc = b * b - a * c
        if disc < 0.0:
            return np.inf
        sb = 1.0 if b >= 0.0 else -1.0
        q = -(b + sb * np.sqrt(disc))  # roots q / a and c / q, each without cancellation
        if q == 0.0:
            return np.inf
        return q / a if np.sign(vl[2] * R) == sb else c / q

    def intersect(self, world_T_mirror: Array, p: Array, v: Array) -> tuple[float, Array, Array]:
        Rm, c = world_T_mirror[:3, :3], world_T_mirror[:3, 3]
        t = self._t(Rm.T @ (p - c), Rm.T @ v)
        if not np.isfinite(t):
            return np.inf, np.full(3, np.nan), np.full(2, np.nan)
        hit = p + t * v
        return t, hit, world_T_mirror[:3, :2].T @ (hit - c)

    def normal(self, world_T_mirror: Array, hit: Array) -> Array:
        Rm = world_T_mirror[:3, :3]
        h = Rm.T @ (hit - world_T_mirror[:3, 3])
        n = Rm @ (np.array([0.0, 0.0, self.radius]) - h) / self.radius
        return np.asarray(n / np.linalg.norm(n))

    def intersect_sx(self, world_T_mirror: ca.SX, p: ca.SX, v: ca.SX) -> tuple[ca.SX, ca.SX, ca.SX]:
        import casadi as ca

        R = self.radius
        Rm, c = world_T_mirror[:3, :3], world_T_mirror[:3, 3]
        pl, vl = ca.mtimes(Rm.T, p - c), ca.mtimes(Rm.T, v)
        a = ca.dot(vl, vl)
        b = ca.dot(vl, pl) - R * vl[2]
        cc = ca.dot(pl, pl) - 2.0 * R * pl[2]
        sb = ca.if_else(b >= 0, 1.0, -1.0)
        q = -(b + sb * ca.sqrt(b * b - a * cc))
        t = ca.if_else(ca.sign(vl[2] * R) == sb, q / a, cc / q)
        hit = p + t * v
        return t, hit, ca.mtimes(world_T_mirror[:3, :2].T, hit - c)

    def normal_sx(self, world_T_mirror: ca.SX, hit: ca.SX) -> ca.SX:
        import casadi as ca

        Rm = world_T_mirror[:3, :3]
        h = ca.mtimes(Rm.T, hit - world_T_mirror[:3, 3])
        n = ca.mtimes(Rm, ca.vertcat(0.0, 0.0, self.radius) - h) / self.radius
        return n / ca.norm_2(n)

    def mirror_T_tangent(self, uv: Array) -> Array:
        R = self.radius
        u, v = float(uv[0]), float(uv[1])
        r2 = u * u + v * v
        if r2 >= R * R:
            return np.full((4, 4), np.nan)
        w = np.sqrt(R * R - r2)
        a, b, cz = -u / R, -v / R, w / abs(R)  # unit normal m at the point
        k = 1.0 / (1.0 + cz)  # the smallest rotation taking +z onto m
        T = np.eye(4)
        T[:3, :3] = [[1 - a * a * k, -a * b * k, a], [-a * b * k, 1 - b * b * k, b], [-a, -b, cz]]
        T[:3, 3] = [u, v, r2 / (R + np.sign(R) * w)]
        return T

    def depth(self, size: tuple[float, float]) -> tuple[float, float]:
        corner = np.array([size[0] / 2, size[1] / 2])
        z = self.mirror_T_tangent(corner)[2, 3]
        if not np.isfinite(z):
            raise ValueError(f"a sphere of radius {self.radius:g} m cannot hold a"
                             f" {size[0]:g} x {size[1]:g} m mirror (its half-diagonal is"
                             f" {float(np.linalg.norm(corner)):g} m)")  # fmt: skip
        return min(0.0, float(z)), max(0.0, float(z))
