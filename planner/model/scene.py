"""One model of the scenario's scene objects for everything that raycasts them.

:class:`SceneModel` holds the scene objects (:class:`SceneItem`: box, mesh, sphere, cylinder,
world frame, metres; :func:`planner.io.scenario.scene_model` builds one from a scenario) and
answers "where does this ray / segment first meet an object". The planner uses it to reject
blocked beams (status ``occluded``),
the simulated camera to render depth and to stop the beam at the first surface, the studies
to test lines of sight. open3d is imported only when the first ray is cast, and an empty
scene never imports it: every query on it is a miss.

Precision: open3d raycasts in float32 (about 1e-7 relative, i.e. ~0.1 µm at 1 m); spheres and
cylinders are tessellated (``SPHERE_RESOLUTION``, ``CYLINDER_RESOLUTION``), so a hit on them
can be up to r (1 - cos(pi / resolution)) inside the true surface (0.2 mm for r = 0.1 m).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from planner.errors import InputError
from planner.model.motion import ObjectMotion
from planner.model.transforms import Array

SPHERE_RESOLUTION = 48
CYLINDER_RESOLUTION = 96
#: m, default offset of a segment's start off the surface it leaves (mirror, laser exit)
START_MARGIN = 1e-6
#: m, default allowance at a segment's end: a target lying ON a surface is not blocked by it
END_MARGIN = 1e-3
_INVALID = 4294967295  # open3d RaycastingScene.INVALID_ID


@dataclass(frozen=True)
class SceneItem:
    """A scene object in the world. ``shape`` is box | mesh | sphere | cylinder.

    ``extents``: box full size (m); ``radius``/``height``: sphere or cylinder (along the
    object's z, centred); ``mesh_path`` (absolute) scaled by ``scale`` into metres.
    ``motion`` (simulation only) moves it in the simulated world; the planner's scene is
    the object at ``world_T_object``.
    """

    name: str
    shape: str
    world_T_object: Array
    extents: Array | None = None
    radius: float | None = None
    height: float | None = None
    mesh_path: Path | None = None
    scale: float = 1.0
    motion: ObjectMotion | None = None


class RayHits(NamedTuple):
    """First surface along each ray (K rays): distance ``t`` (m along the unit direction,
    inf = miss), ``object`` index into :attr:`SceneModel.names` (-1 = miss), the surface
    ``normal`` (K x 3, world frame, zeros on a miss)."""

    t: Array
    object: Array
    normal: Array


class SegmentHit(NamedTuple):
    """Segment ``segment`` (index in the query) is blocked: it first meets scene object
    ``object`` at world point ``point``, ``distance`` m from its start (of ``length`` m)."""

    segment: int
    object: str
    point: Array
    distance: float
    length: float


def object_mesh(item: SceneItem) -> Any:
    """The open3d legacy ``TriangleMesh`` of one scene object, in the world frame (m)."""
    import open3d as o3d

    G = o3d.geometry.TriangleMesh
    if item.shape == "box":
        if item.extents is None:
            raise InputError("box without extents", f"scene {item.name}")
        m = G.create_box(*item.extents).translate(-np.asarray(item.extents) / 2)
    elif item.shape == "sphere":
        m = G.create_sphere(float(item.radius or 0), resolution=SPHERE_RESOLUTION)
    elif item.shape == "cylinder":
        m = G.create_cylinder(
            float(item.radius or 0), float(item.height or 0), resolution=CYLINDER_RESOLUTION
        )
    elif item.shape == "mesh":
        m = o3d.io.read_triangle_mesh(item.mesh_path)  # type: ignore[arg-type]
        if len(m.triangles) == 0:
            raise InputError(
                "mesh has no triangles (unreadable?)", f"scene {item.name}: {item.mesh_path}"
            )
        m.scale(item.scale, center=np.zeros(3))
    else:
        raise InputError(f"unknown shape {item.shape!r}", f"scene {item.name}")
    return m.transform(item.world_T_object)


class SceneModel:
    """The scene objects as one open3d ``RaycastingScene`` (world frame), built lazily.

    ``items``: scenario scene objects; ``meshes``: further ``(name, legacy TriangleMesh)``
    pairs already in the world frame (the studies' own geometry).
    """

    def __init__(
        self, items: Sequence[SceneItem] = (), meshes: Sequence[tuple[str, Any]] = ()
    ) -> None:
        self.items = tuple(items)
        self.meshes = tuple(meshes)

    @property
    def names(self) -> tuple[str, ...]:
        """Object names, in the order of :attr:`RayHits.object` indices."""
        return tuple(i.name for i in self.items) + tuple(n for n, _ in self.meshes)

    @property
    def empty(self) -> bool:
        return not self.items and not self.meshes

    @cached_property
    def raycasting_scene(self) -> Any:
        """The open3d ``RaycastingScene`` (geometry id k = object k of :attr:`names`)."""
        import open3d as o3d

        scene = o3d.t.geometry.RaycastingScene()
        legacy = [object_mesh(i) for i in self.items] + [m for _, m in self.meshes]
        for k, mesh in enumerate(legacy):
            gid = scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
            if gid != k:  # ids are consecutive from 0 in a fresh scene; the mapping relies on it
                raise RuntimeError(f"open3d gave geometry id {gid} to object {k}")
        return scene

    def cast(self, origins: Array, directions: Array) -> RayHits:
        """First hit of each ray (origins, unit directions: K x 3, world frame, m)."""
        P = np.asarray(origins, dtype=float).reshape(-1, 3)
        V = np.asarray(directions, dtype=float).reshape(-1, 3)
        K = len(P)
        if self.empty or K == 0:
            return RayHits(np.full(K, np.inf), np.full(K, -1), np.zeros((K, 3)))
        import open3d as o3d

        rays = np.hstack([P, V]).astype(np.float32)
        ans = self.raycasting_scene.cast_rays(o3d.core.Tensor.from_numpy(rays))
        gid = ans["geometry_ids"].numpy().astype(np.int64)
        miss = gid == _INVALID
        t = np.where(miss, np.inf, ans["t_hit"].numpy().astype(float))
        normal = np.where(miss[:, None], 0.0, ans["primitive_normals"].numpy().astype(float))
        return RayHits(t, np.where(miss, -1, gid), normal)

    def closest(self, points: Array) -> tuple[Array, Array]:
        """Distance (m) from each point (K x 3, world) to the nearest object surface and that
        object's index into :attr:`names` (inf and -1 in an empty scene)."""
        P = np.asarray(points, dtype=float).reshape(-1, 3)
        if self.empty or len(P) == 0:
            return np.full(len(P), np.inf), np.full(len(P), -1)
        import open3d as o3d

        ans = self.raycasting_scene.compute_closest_points(
            o3d.core.Tensor.from_numpy(P.astype(np.float32))
        )
        near = ans["points"].numpy().astype(float)
        return np.linalg.norm(near - P, axis=1), ans["geometry_ids"].numpy().astype(np.int64)

    def segment_distances(
        self,
        p0: Array,
        p1: Array,
        start_margin: float = START_MARGIN,
        end_margin: float = END_MARGIN,
    ) -> tuple[Array, Array]:
        """Distance (m from ``p0``, inf = clear) at which each segment p0 -> p1 (K x 3, world)
        first meets an object, and that object's index (-1 = clear). Surfaces within
        ``start_margin`` of the start or ``end_margin`` of the end do not count."""
        P0 = np.asarray(p0, dtype=float).reshape(-1, 3)
        P1 = np.asarray(p1, dtype=float).reshape(-1, 3)
        K = len(P0)
        if self.empty or K == 0:
            return np.full(K, np.inf), np.full(K, -1)
        d = P1 - P0
        length = np.linalg.norm(d, axis=1)
        long = length > start_margin + end_margin
        v = d / np.where(length > 0, length, 1.0)[:, None]
        hits = self.cast(P0 + start_margin * v, v)
        dist = hits.t + start_margin
        blocked = long & (dist < length - end_margin)
        return np.where(blocked, dist, np.inf), np.where(blocked, hits.object, -1)

    def segment_hits(
        self,
        p0: Array,
        p1: Array,
        start_margin: float = START_MARGIN,
        end_margin: float = END_MARGIN,
    ) -> float | None:
        """Distance (m from ``p0``) at which the segment p0 -> p1 (world) first meets an
        object, or None if it is clear (margins as in :meth:`segment_distances`)."""
        dist, _ = self.segment_distances(p0, p1, start_margin, end_margin)
        return None if not np.isfinite(dist[0]) else float(dist[0])

    def blocked_segments(
        self,
        p0: Array,
        p1: Array,
        start_margin: float = START_MARGIN,
        end_margin: float = END_MARGIN,
    ) -> list[SegmentHit]:
        """Every blocked segment p0 -> p1 (K x 3, world) with the object and the point."""
        P0 = np.asarray(p0, dtype=float).reshape(-1, 3)
        P1 = np.asarray(p1, dtype=float).reshape(-1, 3)
        dist, obj = self.segment_distances(P0, P1, start_margin, end_margin)
        names = self.names
        out = []
        for k in np.flatnonzero(np.isfinite(dist)):
            d = P1[k] - P0[k]
            length = float(np.linalg.norm(d))
            point = P0[k] + dist[k] * d / length
            out.append(SegmentHit(int(k), names[obj[k]], point, float(dist[k]), length))
        return out

    def nearest_surface(self, points: Array) -> tuple[Array, Array]:
        """Distance (m, inf without objects) from each point (K x 3, world) to the nearest
        object surface, and that object's index in :attr:`names` (-1 without objects): the
        same as :meth:`closest`."""
        return self.closest(points)


#: m: a target this close to a moving object's surface (at rest) moves with it
ON_SURFACE = 1e-3


@dataclass(frozen=True)
class TrackedObject:
    """The targets (world, m, at rest) on one moving scene object."""

    item: SceneItem
    points: Array
    normals: Array | None


def tracked_objects(
    items: list[SceneItem], points: Array, normals: Array | None
) -> list[TrackedObject]:
    """The moving objects that carry some of ``points`` (K x 3, world), with those points."""
    out = []
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    for item in items:
        if item.motion is None:
            continue
        import open3d as o3d

        scene = SceneModel([replace(item, motion=None)]).raycasting_scene
        d = scene.compute_distance(
            o3d.core.Tensor.from_numpy(np.ascontiguousarray(P, dtype=np.float32))
        ).numpy()
        on = d <= ON_SURFACE
        if on.any():
            n = None if normals is None else np.asarray(normals, dtype=float)[on]
            out.append(TrackedObject(item, P[on], n))
    return out
