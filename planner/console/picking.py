"""Picking a target on the cloud: the click's ray, the nearest cloud point, its normal.

The browser gives a click as a ray (origin, unit direction, world frame). The picked point
is the cloud point nearest to that ray among those ahead of the origin, within
``max_distance`` of it (m); ties in distance to the ray go to the point nearer the viewer,
so a click never picks through a surface to the points behind it. Its normal comes from a
plane fitted (SVD, as in the paper) to the cloud points within ``radius`` of it, turned to
face the viewer (docs/conventions.md: a normal points out of the surface toward the side the beam arrives
from, which for a surface the camera sees is the camera's side). The target is the picked
point moved onto that plane: a single cloud point is off the surface by the depth noise
(1.3 mm at 0.6 m for a D435), the plane of ~75 neighbours by about a tenth of that, and a
target below the surface would be hidden behind it.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from planner.errors import InputError
from planner.model.transforms import Array

#: a click farther than this from every cloud point (m) picks nothing
MAX_RAY_DISTANCE = 0.01
#: neighbours within this radius (m) give the plane of a picked point
NORMAL_RADIUS = 0.01
#: fewest neighbours for a plane fit
MIN_NEIGHBOURS = 6


class Pick(NamedTuple):
    """A picked cloud point ``p`` (world, m), its ``row`` in the cloud, its distance to the ray (m)."""

    p: Array
    row: int
    ray_distance: float


class PlaneFit(NamedTuple):
    """A fitted plane: unit ``normal`` (world), ``rms`` distance of the points to it (m),
    ``n_points`` used, and their ``centroid`` (world, m), a point of the plane."""

    normal: Array
    rms: float
    n_points: int
    centroid: Array

    def project(self, p: Array) -> Array:
        """``p`` (world, m) moved along the normal onto the plane."""
        p = np.asarray(p, dtype=float)
        return p - float((p - self.centroid) @ self.normal) * self.normal


def pick_point(
    points: Array, origin: Array, direction: Array, max_distance: float = MAX_RAY_DISTANCE
) -> Pick | None:
    """The cloud point (M x 3, world, m) the click ray ``origin + s direction`` picks, or
    None when no point ahead lies within ``max_distance`` m of the ray.

    Among the points within ``max_distance`` of the ray the one closest to the origin along
    the ray wins (the first surface the ray meets)."""
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    o, d = _ray(origin, direction)
    rel = P - o
    s = rel @ d
    perp = np.linalg.norm(rel - s[:, None] * d, axis=1)
    near = np.flatnonzero((s > 0) & (perp <= max_distance) & np.all(np.isfinite(P), axis=1))
    if len(near) == 0:
        return None
    # the first surface along the ray: the nearest s among near points, within one
    # max_distance slab, then the one closest to the ray inside that slab
    s_first = float(np.min(s[near]))
    slab = near[s[near] <= s_first + 2 * max_distance]
    k = int(slab[np.argmin(perp[slab])])
    return Pick(P[k].copy(), k, float(perp[k]))


def fit_plane(points: Array) -> PlaneFit:
    """Least-squares plane through ``points`` (K x 3, m): the right singular vector of the
    centred points with the smallest singular value. InputError for fewer than 3 points."""
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    if len(P) < 3:
        raise InputError(f"a plane needs >= 3 points, got {len(P)}", "cloud")
    C = P - P.mean(axis=0)
    _, sv, Vt = np.linalg.svd(C, full_matrices=False)
    n = Vt[-1] / np.linalg.norm(Vt[-1])
    return PlaneFit(n, float(sv[-1] / np.sqrt(len(P))), len(P), P.mean(axis=0))


def surface_normal(
    points: Array, p: Array, towards: Array, radius: float = NORMAL_RADIUS
) -> PlaneFit:
    """Normal at ``p`` (world, m) of the cloud ``points``: a plane fit of the points within
    ``radius`` m of ``p``, turned so that it points toward the point ``towards`` (the viewer
    or camera). InputError when fewer than MIN_NEIGHBOURS points are that close."""
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    p = np.asarray(p, dtype=float)
    near = P[np.linalg.norm(P - p, axis=1) <= radius]
    if len(near) < MIN_NEIGHBOURS:
        raise InputError(
            f"only {len(near)} cloud points within {1e3 * radius:g} mm of the pick "
            f"(need {MIN_NEIGHBOURS}) to estimate its normal",
            "cloud",
        )
    fit = fit_plane(near)
    n = fit.normal if fit.normal @ (np.asarray(towards, dtype=float) - p) >= 0 else -fit.normal
    return PlaneFit(n, fit.rms, fit.n_points, fit.centroid)


def _ray(origin: Array, direction: Array) -> tuple[Array, Array]:
    o = np.asarray(origin, dtype=float).reshape(3)
    d = np.asarray(direction, dtype=float).reshape(3)
    norm = float(np.linalg.norm(d))
    if not (np.all(np.isfinite(o)) and np.isfinite(norm)) or norm < 1e-12:
        raise InputError(
            f"click ray origin {o.tolist()} direction {d.tolist()} is not a ray", "ray"
        )
    return o, d / norm
