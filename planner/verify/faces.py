"""The checker's own mirror faces: plain numpy, batched over M rays, written again from the
conventions (a mirror's face passes through its frame's origin with normal +z there) rather
than taken from the planner's :mod:`planner.model.mirror`.

A face is chosen by a plain description, ``{"shape": name, ...numbers}`` (what the planner's
``Surface.spec`` gives; no spec: flat), through :data:`FACES`; a shape without an entry has
no independent check and is refused, as an arm without checker kinematics is. Poses are
stacks (M x 4 x 4) ``world_T_mirror``, rays (M x 3) in the world frame, metres.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.errors import InputError
from planner.model.transforms import Array


def _dot(a: Array, b: Array) -> Array:
    """Row-wise dot products of two (M, 3) arrays."""
    return np.einsum("ij,ij->i", a, b)


def _uv(world_T_mirror: Array, hit: Array) -> Array:
    """Mirror x/y (M x 2, m) of world points ``hit`` (M x 3)."""
    d = hit - world_T_mirror[:, :3, 3]
    return np.stack([_dot(world_T_mirror[:, :3, k], d) for k in (0, 1)], axis=1)


@dataclass(frozen=True)
class FlatFace:
    """The z = 0 plane of the mirror frame."""

    def intersect(self, world_T_mirror: Array, p: Array, v: Array) -> tuple[Array, Array, Array]:
        """(t (M,) m, hit (M x 3) world, uv (M x 2) m) of the rays ``p + t v``."""
        c, n = world_T_mirror[:, :3, 3], world_T_mirror[:, :3, 2]
        t = _dot(n, c - p) / _dot(n, v)
        h = p + t[:, None] * v
        return t, h, _uv(world_T_mirror, h)

    def normal(self, world_T_mirror: Array, hit: Array) -> Array:
        """Unit face normals (M x 3, world) at the hits: mirror +z."""
        return np.asarray(world_T_mirror[:, :3, 2])


@dataclass(frozen=True)
class SphereFace:
    """The cap through the mirror origin of the sphere centred ``radius`` (m, signed: > 0
    concave) along mirror +z; its outward normal is ``(centre - x) / radius``."""

    radius: float

    def intersect(self, world_T_mirror: Array, p: Array, v: Array) -> tuple[Array, Array, Array]:
        """Both roots of ``|p + t v - centre| = |radius|``; the one on the cap (outward
        normal along mirror +z there) is the hit; a miss gives inf and NaN."""
        axis = world_T_mirror[:, :3, 2]
        centre = world_T_mirror[:, :3, 3] + self.radius * axis
        w = p - centre
        a, b, c = _dot(v, v), _dot(v, w), _dot(w, w) - self.radius**2
        disc = b * b - a * c
        root = np.sqrt(np.where(disc >= 0.0, disc, np.nan))
        ts = np.stack([(-b - root) / a, (-b + root) / a], axis=1)  # (M, 2)
        hits = p[:, None, :] + ts[..., None] * v[:, None, :]
        up = np.einsum("mkj,mj->mk", centre[:, None, :] - hits, axis) / self.radius
        k = np.argmax(np.where(np.isfinite(up), up, -np.inf), axis=1)
        t = np.where(disc >= 0.0, ts[np.arange(len(k)), k], np.inf)
        h = hits[np.arange(len(k)), k]
        return t, h, _uv(world_T_mirror, h)

    def normal(self, world_T_mirror: Array, hit: Array) -> Array:
        """Unit outward normals (M x 3, world) at the hits."""
        centre = world_T_mirror[:, :3, 3] + self.radius * world_T_mirror[:, :3, 2]
        n = (centre - hit) / self.radius
        return np.asarray(n / np.linalg.norm(n, axis=1, keepdims=True))


Face = FlatFace | SphereFace
FLAT_FACE = FlatFace()

#: shape name -> the checker's face for a spec of that shape
FACES: dict[str, Callable[[Mapping[str, Any]], Face]] = {
    "flat": lambda spec: FLAT_FACE,
    "sphere": lambda spec: SphereFace(float(spec["radius"])),
}


def face_from_spec(spec: Mapping[str, Any] | None, where: str = "mirror") -> Face:
    """The checker's face for a mirror described by ``spec`` (None: flat)."""
    if spec is None:
        return FLAT_FACE
    make = FACES.get(str(spec.get("shape")))
    if make is None:
        raise InputError(f"no independent check for a mirror of shape {spec.get('shape')!r}"
                         f" (known: {', '.join(FACES)})", where)  # fmt: skip
    try:
        return make(spec)
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"bad mirror shape {dict(spec)!r}: {exc!r}", where) from exc


def reflect(face: Face, world_T_mirror: Array, v: Array, hit: Array) -> Array:
    """Directions (M x 3) of the rays ``v`` reflected at ``hit`` on ``face``: v - 2 (v.n) n."""
    n = face.normal(world_T_mirror, hit)
    return np.asarray(v - 2 * _dot(v, n)[:, None] * n)
