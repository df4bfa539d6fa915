"""The mirror surface behind one seam: where a ray meets it, and how it reflects.

A :class:`Mirror` carries its face's shape, a :class:`Surface`. Every computation of the
planner that needs the face asks the mirror's surface: numpy, one ray
(:meth:`Surface.intersect` / :meth:`~Surface.normal` / :meth:`~Surface.reflect`, also
reachable as :meth:`Mirror.intersect` ...), or its CasADi twin (:meth:`Surface.intersect_sx`
/ :meth:`~Surface.normal_sx` / :meth:`~Surface.reflect_sx`, used by the symbolic beam graph
of :mod:`planner.beam.graph`). The independent checker has its own numpy shapes in
:mod:`planner.verify.faces`, chosen by :attr:`Surface.spec`.

Every shape keeps one invariant: its face passes through the mirror-frame origin (the
mirror's centre) with normal +z there, so the frame's +z is the mirror's axis and the
region of interest (a rectangle of mirror x/y, ``uv``) is measured from it. :class:`Flat`
(the default) is the ``z = 0`` plane; a curved shape lives in its own module
(:mod:`planner.model.mirror_sphere`). Code that only holds for a plane asks
:attr:`Surface.is_flat` and says what it does otherwise. Poses ``a_T_b`` (4 x 4), points
and directions in the world frame, metres.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from planner.model.transforms import Array, inv_T
from schemas import defaults

if TYPE_CHECKING:
    import casadi as ca

DEFAULT_MIRROR_SIZE = (0.075, 0.075)  # m
DEFAULT_ROI_MARGIN = defaults.ROI_MARGIN_M  # m


class Surface(ABC):
    """The shape of a reflective face in its mirror frame (see the module docstring).

    Subclasses are frozen dataclasses (hashable: the CasADi functions built on a chain are
    cached per tuple of surfaces). ``is_flat`` is the capability that plane-only code asks
    for; ``spec`` names the shape and its numbers for the independent checker."""

    is_flat: ClassVar[bool] = False

    @property
    @abstractmethod
    def spec(self) -> dict[str, Any]:
        """Plain description, ``{"shape": name, ...numbers in SI}`` (the checker's input)."""

    @abstractmethod
    def intersect(self, world_T_mirror: Array, p: Array, v: Array) -> tuple[float, Array, Array]:
        """Where the ray ``p + t v`` (world) meets the face of the mirror at
        ``world_T_mirror``: (ray parameter t, hit point in the world, hit ``uv`` = its mirror
        x/y in m). A ray that misses the face gives ``t = inf`` and a non-finite hit."""

    @abstractmethod
    def normal(self, world_T_mirror: Array, hit: Array) -> Array:
        """Unit outward normal (world) of the face at the world point ``hit`` on it."""

    @abstractmethod
    def intersect_sx(self, world_T_mirror: ca.SX, p: ca.SX, v: ca.SX) -> tuple[ca.SX, ca.SX, ca.SX]:
        """Symbolic :meth:`intersect`: (t, hit, uv) of the ray ``p + t v``."""

    @abstractmethod
    def normal_sx(self, world_T_mirror: ca.SX, hit: ca.SX) -> ca.SX:
        """Symbolic :meth:`normal` at ``hit``."""

    @abstractmethod
    def mirror_T_tangent(self, uv: Array) -> Array:
        """The face's tangent frame over mirror x/y ``uv`` (m), in the mirror frame: origin on
        the face, +z its normal there (all NaN where the face has no point over ``uv``)."""

    @abstractmethod
    def depth(self, size: tuple[float, float]) -> tuple[float, float]:
        """Lowest and highest mirror z (m) of the face over the ``size`` rectangle (the
        collision plate's extent); ValueError when the face does not cover it."""

    def reflect(self, world_T_mirror: Array, v: Array, hit: Array) -> Array:
        """Direction (world) of the ray ``v`` after reflecting at ``hit``: ``v - 2 (v.n) n``."""
        n = self.normal(world_T_mirror, hit)
        return np.asarray(v - 2.0 * float(n @ v) * n)

    def reflect_sx(self, world_T_mirror: ca.SX, v: ca.SX, hit: ca.SX) -> ca.SX:
        """Symbolic :meth:`reflect`: ``v - 2 (v.n) n`` at ``hit``."""
        import casadi as ca

        n = self.normal_sx(world_T_mirror, hit)
        return v - 2 * ca.dot(v, n) * n

    def place(self, world_T_tangent: Array, uv: Array) -> Array:
        """``world_T_mirror`` whose tangent frame over ``uv`` is ``world_T_tangent``."""
        return np.asarray(world_T_tangent @ inv_T(self.mirror_T_tangent(uv)))


@dataclass(frozen=True)
class Flat(Surface):
    """The plane ``z = 0`` of the mirror frame, normal +z everywhere."""

    is_flat: ClassVar[bool] = True

    @property
    def spec(self) -> dict[str, Any]:
        return {"shape": "flat"}

    def intersect(self, world_T_mirror: Array, p: Array, v: Array) -> tuple[float, Array, Array]:
        n, c = world_T_mirror[:3, 2], world_T_mirror[:3, 3]
        nv = float(n @ v)
        t = float(n @ (c - p)) / nv if nv != 0.0 else np.inf
        hit = p + t * v
        return t, hit, world_T_mirror[:3, :2].T @ (hit - c)

    def normal(self, world_T_mirror: Array, hit: Array) -> Array:
        return np.asarray(world_T_mirror[:3, 2])

    def intersect_sx(self, world_T_mirror: ca.SX, p: ca.SX, v: ca.SX) -> tuple[ca.SX, ca.SX, ca.SX]:
        import casadi as ca

        n, c = world_T_mirror[:3, 2], world_T_mirror[:3, 3]
        t = ca.dot(n, c - p) / ca.dot(n, v)
        hit = p + t * v
        return t, hit, ca.mtimes(world_T_mirror[:3, :2].T, hit - c)

    def normal_sx(self, world_T_mirror: ca.SX, hit: ca.SX) -> ca.SX:
        return world_T_mirror[:3, 2]

    def mirror_T_tangent(self, uv: Array) -> Array:
        T = np.eye(4)
        T[:2, 3] = uv
        return T

    def depth(self, size: tuple[float, float]) -> tuple[float, float]:
        return 0.0, 0.0

    def place(self, world_T_tangent: Array, uv: Array) -> Array:
        T = np.array(world_T_tangent, dtype=float)
        T[:3, 3] = T[:3, 3] - uv[0] * T[:3, 0] - uv[1] * T[:3, 1]
        return T


FLAT = Flat()


@dataclass(frozen=True)
class Mirror:
    """A mirror on a flange: ``flange_T_mirror`` is its frame (centre, +z the face's normal
    there), ``size`` (m, along mirror x and y), ``roi_margin`` (m) kept clear along every
    edge, ``surface`` the face's shape (flat unless given)."""

    flange_T_mirror: Array
    size: tuple[float, float] = DEFAULT_MIRROR_SIZE
    roi_margin: float = DEFAULT_ROI_MARGIN
    surface: Surface = FLAT

    def __post_init__(self) -> None:
        self.surface.depth(self.size)  # the face covers the mirror, or a ValueError says why

    @property
    def roi_half(self) -> Array:
        """Half extents (u, v) of the region the beam must stay in, metres."""
        return np.array([self.size[0] / 2 - self.roi_margin, self.size[1] / 2 - self.roi_margin])

    def intersect(self, world_T_mirror: Array, p: Array, v: Array) -> tuple[float, Array, Array]:
        """:meth:`Surface.intersect` of this mirror's face."""
        return self.surface.intersect(world_T_mirror, p, v)

    def normal(self, world_T_mirror: Array, hit: Array) -> Array:
        """:meth:`Surface.normal` of this mirror's face."""
        return self.surface.normal(world_T_mirror, hit)

    def reflect(self, world_T_mirror: Array, v: Array, hit: Array) -> Array:
        """:meth:`Surface.reflect` off this mirror's face."""
        return self.surface.reflect(world_T_mirror, v, hit)

    def place(self, hit: Array, normal: Array, x_ref: Array, roll: float, uv: Array) -> Array:
        """``world_T_mirror`` whose face has unit ``normal`` (world) at world point ``hit``,
        which it puts at mirror coordinates ``uv`` (m); the face's tangent x axis there is
        ``x_ref`` projected on the tangent plane and rolled by ``roll`` (rad) about the
        normal (for a flat face: the mirror x axis). NaN where the face has no point over
        ``uv``."""
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
        T[:3, 3] = hit
        return self.surface.place(T, uv)
