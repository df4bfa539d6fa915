"""The simulated world's scene at time t: static objects plus objects that move (``motion:``).

Every object with a motion is a :class:`planner.model.scene.SceneModel` of its own, built at
its rest pose (``world_T_object``, origin ``c``); a ray (o, v) meets the object turned by
``R(t)`` about ``c`` and translated by ``d(t)`` where the ray (R^T (o - c - d) + c, R^T v)
meets it at rest (the normal there turned by R), so moving it costs no rebuild, only a cast
per object. Static objects share one model. World frame, metres, seconds (``t`` on the
simulation clock, see :mod:`planner.model.motion`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from planner.model.motion import ObjectMotion
from planner.model.scene import RayHits, SceneItem, SceneModel, object_mesh
from planner.model.transforms import Array

#: m, margin around a moving object's swept box (the pixels that may see it)
SWEPT_MARGIN = 1e-3


class MovingScene:
    """Raycasts against the scene as it is at time ``t`` (see the module docstring)."""

    def __init__(self, items: Sequence[SceneItem]) -> None:
        self.items = tuple(items)
        self.static_index = [k for k, i in enumerate(self.items) if i.motion is None]
        self.moving_index = [k for k, i in enumerate(self.items) if i.motion is not None]
        self.static = SceneModel([self.items[k] for k in self.static_index])
        self.moving = [
            SceneModel([dataclasses.replace(self.items[k], motion=None)]) for k in self.moving_index
        ]

    @property
    def has_motion(self) -> bool:
        return bool(self.moving_index)

    def motion(self, j: int) -> ObjectMotion:
        """The motion of moving object ``j`` (index into :attr:`moving`)."""
        m = self.items[self.moving_index[j]].motion
        assert m is not None
        return m

    def offsets(self, t: float) -> list[Array]:
        """Each moving object's translation at time ``t`` (m, world)."""
        return [self.motion(j).offset(t) for j in range(len(self.moving))]

    def cast(self, origins: Array, directions: Array, t: float) -> RayHits:
        """First hit of each ray (K x 3, world; ``t_hit`` in units of the direction's length)
        against the scene at time ``t``; ``object`` indexes :attr:`items`."""
        P = np.asarray(origins, dtype=float).reshape(-1, 3)
        V = np.asarray(directions, dtype=float).reshape(-1, 3)
        hits = self.static.cast(P, V)
        best_t = hits.t.copy()
        obj = np.where(
            hits.object >= 0, np.take([*self.static_index, -1], hits.object.astype(np.int64)), -1
        )
        normal = hits.normal.copy()
        for j, model in enumerate(self.moving):
            R = self.motion(j).rotation(t)
            h = model.cast(*self._at_rest(j, P, V, t))
            closer = h.t < best_t
            best_t = np.where(closer, h.t, best_t)
            obj = np.where(closer, self.moving_index[j], obj)
            normal = np.where(closer[:, None], h.normal @ R.T, normal)
        return RayHits(best_t, obj, normal)

    def _at_rest(self, j: int, origins: Array, directions: Array, t: float) -> tuple[Array, Array]:
        """Rays (world) against moving object ``j`` at time ``t`` as rays against it at rest."""
        m = self.motion(j)
        c = self.items[self.moving_index[j]].world_T_object[:3, 3]
        R = m.rotation(t)
        P = np.asarray(origins, dtype=float).reshape(-1, 3)
        V = np.asarray(directions, dtype=float).reshape(-1, 3)
        return (P - c - m.offset(t)) @ R + c, V @ R

    def swept_box(self, j: int) -> SceneItem:
        """A box holding moving object ``j`` at every time (its bounds over the motion)."""
        item = self.items[self.moving_index[j]]
        mesh = object_mesh(dataclasses.replace(item, motion=None))
        lo, hi = np.asarray(mesh.get_min_bound()), np.asarray(mesh.get_max_bound())
        m = self.motion(j)
        if m.turns:  # every turn of the object lies in the ball around its origin
            c = item.world_T_object[:3, 3]
            r = float(np.linalg.norm(np.asarray(mesh.vertices) - c, axis=1).max())
            lo, hi = c - r, c + r
        ends = [m.direction * m.amplitude, -m.direction * m.amplitude]
        if m.kind == "linear":
            ends = [np.zeros(3), m.direction * m.duration]
        lo = lo + np.min(ends, axis=0) - SWEPT_MARGIN
        hi = hi + np.max(ends, axis=0) + SWEPT_MARGIN
        T = np.eye(4)
        T[:3, 3] = (lo + hi) / 2
        return SceneItem(f"{item.name}/swept", "box", T, extents=hi - lo)

    def object_cast(self, j: int, origins: Array, directions: Array, t: float) -> Array:
        """``t_hit`` (inf = miss) of each ray against moving object ``j`` alone at time t."""
        return self.moving[j].cast(*self._at_rest(j, origins, directions, t)).t
