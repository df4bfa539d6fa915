"""Scene objects and keep-out volumes as coal collision shapes, world frame, metres.

:class:`Volume` is a named solid at ``world_T_object``: ``sphere`` (radius), ``box`` (full
extents, centred), ``cylinder`` (radius, height along z, centred) or ``mesh`` (a triangle
mesh file in the object frame, times ``scale``). Scene objects become coal shapes as they
are: a mesh is its triangle surface (a BVH), so a link completely inside a closed scene mesh
is not seen. Keep-out volumes are solids the beam must never enter, so a keep-out mesh is
its convex hull (conservative: the hull contains the mesh).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import coal
import numpy as np

from planner.errors import InputError
from planner.model.transforms import Array

SHAPES = ("sphere", "box", "cylinder", "mesh")


@dataclass(frozen=True)
class Volume:
    """A named solid in the world: ``shape`` in :data:`SHAPES`; ``dims`` = (r,) for a
    sphere, (x, y, z) for a box, (r, h) for a cylinder, () for a mesh (``mesh_path``,
    ``scale``); ``world_T_object`` 4x4 (m)."""

    name: str
    shape: str
    world_T_object: Array
    dims: tuple[float, ...] = ()
    mesh_path: Path | None = None
    scale: float = 1.0

    def __post_init__(self) -> None:
        want = {"sphere": 1, "box": 3, "cylinder": 2, "mesh": 0}.get(self.shape)
        if want is None:
            raise InputError(
                f"unknown shape {self.shape!r} (one of {', '.join(SHAPES)})", self.name
            )
        if len(self.dims) != want:
            raise InputError(f"{self.shape} needs {want} dimensions, got {self.dims}", self.name)
        if not all(np.isfinite(d) and d > 0 for d in self.dims):
            raise InputError(f"dimensions must be finite and > 0 m, got {self.dims}", self.name)
        T = np.asarray(self.world_T_object, dtype=float)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise InputError("world_T_object must be a finite 4x4 matrix", self.name)
        if self.shape == "mesh" and self.mesh_path is None:
            raise InputError("mesh volume without a mesh file", self.name)


def sphere(name: str, radius: float, world_T_object: Array) -> Volume:
    return Volume(name, "sphere", np.asarray(world_T_object, dtype=float), (float(radius),))


def box(name: str, extents: Sequence[float], world_T_object: Array) -> Volume:
    dims = tuple(float(e) for e in extents)
    return Volume(name, "box", np.asarray(world_T_object, dtype=float), dims)


class _SceneItemLike(Protocol):
    @property
    def name(self) -> str: ...
    @property
    def shape(self) -> str: ...
    @property
    def world_T_object(self) -> Array: ...
    @property
    def extents(self) -> Array | None: ...
    @property
    def radius(self) -> float | None: ...
    @property
    def height(self) -> float | None: ...
    @property
    def mesh_path(self) -> Path | None: ...
    @property
    def scale(self) -> float: ...


def volumes_from_scene_items(items: Iterable[_SceneItemLike]) -> tuple[Volume, ...]:
    """The scenario's scene objects (:class:`planner.io.scenario.SceneItem`) as volumes."""
    out = []
    for it in items:
        dims: tuple[float, ...] = ()
        if it.shape == "box" and it.extents is not None:
            dims = tuple(float(e) for e in it.extents)
        elif it.shape == "sphere":
            dims = (float(it.radius or 0.0),)
        elif it.shape == "cylinder":
            dims = (float(it.radius or 0.0), float(it.height or 0.0))
        out.append(Volume(it.name, it.shape, it.world_T_object, dims, it.mesh_path, it.scale))
    return tuple(out)


def _mesh_arrays(v: Volume) -> tuple[Array, Any]:
    import open3d as o3d

    mesh = o3d.io.read_triangle_mesh(v.mesh_path)  # type: ignore[arg-type]
    if len(mesh.triangles) == 0:
        raise InputError("mesh has no triangles (unreadable?)", f"{v.name}: {v.mesh_path}")
    verts = np.asarray(mesh.vertices, dtype=float) * v.scale
    return verts, np.asarray(mesh.triangles, dtype=np.int64)


def coal_shape(v: Volume, *, solid: bool) -> coal.CollisionGeometry:
    """The coal geometry of ``v`` in its object frame. ``solid``: a mesh becomes its convex
    hull (a keep-out solid) instead of its triangle surface."""
    if v.shape == "sphere":
        return coal.Sphere(v.dims[0])
    if v.shape == "box":
        return coal.Box(*v.dims)
    if v.shape == "cylinder":
        return coal.Cylinder(*v.dims)
    verts, tris = _mesh_arrays(v)
    if solid:
        from scipy.spatial import ConvexHull

        hull = ConvexHull(verts)
        pts = verts[hull.vertices]
        index = {int(k): i for i, k in enumerate(hull.vertices)}
        points, faces = coal.StdVec_Vec3s(), coal.StdVec_Triangle()
        points.extend(list(pts))
        faces.extend([coal.Triangle(*(index[int(k)] for k in s)) for s in hull.simplices])
        return coal.Convex(points, faces)
    bvh = coal.BVHModelOBBRSS()
    bvh.beginModel(len(tris), len(verts))
    bvh.addVertices(verts)
    bvh.addTriangles(tris)
    bvh.endModel()
    return bvh
