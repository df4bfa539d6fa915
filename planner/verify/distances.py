"""Closed-form distances in plain numpy, independent of coal and Pinocchio.

Segments are ``(p0, p1)`` pairs of 3-vectors; capsules are segments with a radius; boxes are
``(world_T_box, full extents)``; spheres ``(centre, radius)``. All in one frame (the world),
metres. Signed distances are negative inside (penetration depth for a point in a box or
sphere; for capsules, radius sum minus the axis distance).
"""

from __future__ import annotations

import numpy as np

from planner.model.transforms import Array

_EPS = 1e-15


def point_segment(x: Array, p0: Array, p1: Array) -> tuple[float, Array]:
    """Distance from point ``x`` to segment p0-p1 and the closest point on the segment."""
    d = p1 - p0
    L2 = float(d @ d)
    s = 0.0 if L2 <= _EPS else float(np.clip((x - p0) @ d / L2, 0.0, 1.0))
    c = p0 + s * d
    return float(np.linalg.norm(x - c)), c


def segment_segment(p0: Array, p1: Array, q0: Array, q1: Array) -> tuple[float, Array, Array]:
    """Distance between segments p0-p1 and q0-q1 and the closest points on each.

    Minimises |p(s) - q(t)| over the unit square: the interior stationary point when the
    segments are not parallel, else the best of the four edge cases (each a point-segment
    distance), which also covers parallel and degenerate segments exactly.
    """
    p0, p1, q0, q1 = (np.asarray(v, dtype=float) for v in (p0, p1, q0, q1))
    d1, d2, r = p1 - p0, q1 - q0, p0 - q0
    a, e, b = float(d1 @ d1), float(d2 @ d2), float(d1 @ d2)
    c, f = float(d1 @ r), float(d2 @ r)
    dist, y = point_segment(p0, q0, q1)
    best: tuple[float, Array, Array] = (dist, p0, y)
    den = a * e - b * b
    if a > _EPS and e > _EPS and den > 1e-12 * a * e:
        s, t = (b * f - c * e) / den, (a * f - b * c) / den
        if 0.0 <= s <= 1.0 and 0.0 <= t <= 1.0:
            x, y = p0 + s * d1, q0 + t * d2
            best = (float(np.linalg.norm(x - y)), x, y)
    for x in (p0, p1):
        dist, y = point_segment(x, q0, q1)
        if dist < best[0]:
            best = (dist, x, y)
    for y in (q0, q1):
        dist, x = point_segment(y, p0, p1)
        if dist < best[0]:
            best = (dist, x, y)
    return best


def capsule_capsule(
    p0: Array, p1: Array, rp: float, q0: Array, q1: Array, rq: float
) -> tuple[float, Array, Array]:
    """Signed distance between two capsules and the witness points on their surfaces (on the
    axes' closest points when the axes are closer than 1e-15 m)."""
    d, x, y = segment_segment(p0, p1, q0, q1)
    n = (y - x) / d if d > _EPS else np.zeros(3)
    return d - rp - rq, x + rp * n, y - rq * n


def point_box(x: Array, world_T_box: Array, extents: Array) -> tuple[float, Array]:
    """Signed distance from point ``x`` to a box (negative inside: minus the depth below the
    nearest face) and the closest point of the box surface."""
    R, c = world_T_box[:3, :3], world_T_box[:3, 3]
    h = np.asarray(extents, dtype=float) / 2
    u = R.T @ (np.asarray(x, dtype=float) - c)
    clamped = np.clip(u, -h, h)
    if np.any(np.abs(u) > h):
        return float(np.linalg.norm(u - clamped)), c + R @ clamped
    gap = h - np.abs(u)
    i = int(np.argmin(gap))
    face = u.copy()
    face[i] = np.copysign(h[i], u[i]) if u[i] != 0 else h[i]
    return -float(gap[i]), c + R @ face


def point_sphere(x: Array, centre: Array, radius: float) -> tuple[float, Array]:
    """Signed distance from ``x`` to a sphere and the closest surface point."""
    v = np.asarray(x, dtype=float) - centre
    n = float(np.linalg.norm(v))
    u = v / n if n > _EPS else np.array([0.0, 0.0, 1.0])
    return n - radius, centre + radius * u


def segment_sphere(p0: Array, p1: Array, centre: Array, radius: float) -> tuple[float, Array]:
    """Signed distance from segment p0-p1 to a sphere and the closest segment point."""
    d, x = point_segment(np.asarray(centre, dtype=float), p0, p1)
    return d - radius, x


def segment_box(
    p0: Array, p1: Array, world_T_box: Array, extents: Array, iterations: int = 90
) -> tuple[float, Array]:
    """Distance (>= 0; 0 when they meet) from segment p0-p1 to a box and the closest
    segment point. The distance from p(s) to a convex set is convex in s, so a golden-section
    search on s in [0, 1] finds its minimum; intersections are found exactly first (slab
    clipping), so a segment through the box gives 0."""
    p0, p1 = np.asarray(p0, dtype=float), np.asarray(p1, dtype=float)
    R, c = world_T_box[:3, :3], world_T_box[:3, 3]
    h = np.asarray(extents, dtype=float) / 2
    a, b = R.T @ (p0 - c), R.T @ (p1 - c)
    lo, hi, d = 0.0, 1.0, b - a
    for i in range(3):
        if abs(d[i]) <= _EPS:
            if abs(a[i]) > h[i]:
                lo, hi = 1.0, 0.0
                break
            continue
        t0, t1 = sorted(((-h[i] - a[i]) / d[i], (h[i] - a[i]) / d[i]))
        lo, hi = max(lo, t0), min(hi, t1)
    if lo <= hi:
        return 0.0, p0 + lo * (p1 - p0)

    def f(s: float) -> float:
        u = a + s * d
        return float(np.linalg.norm(u - np.clip(u, -h, h)))

    g = (np.sqrt(5.0) - 1) / 2
    x0, x1 = 0.0, 1.0
    for _ in range(iterations):
        m0, m1 = x1 - g * (x1 - x0), x0 + g * (x1 - x0)
        if f(m0) <= f(m1):
            x1 = m1
        else:
            x0 = m0
    s = min((0.0, 1.0, (x0 + x1) / 2), key=f)
    return f(s), p0 + s * (p1 - p0)


def box_corners(world_T_box: Array, extents: Array) -> Array:
    """The 8 corners (8 x 3) of a box."""
    h = np.asarray(extents, dtype=float) / 2
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    return (signs * h) @ world_T_box[:3, :3].T + world_T_box[:3, 3]


def box_edges(world_T_box: Array, extents: Array) -> list[tuple[Array, Array]]:
    """The 12 edges of a box as segments."""
    C = box_corners(world_T_box, extents)
    return [(C[i], C[j]) for i in range(8) for j in range(i + 1, 8) if bin(i ^ j).count("1") == 1]


def capsule_box(p0: Array, p1: Array, r: float, world_T_box: Array, extents: Array) -> float:
    """Distance from a capsule to a box (<= 0 when they meet; not a penetration depth)."""
    return segment_box(p0, p1, world_T_box, extents)[0] - r


def box_box(T_a: Array, ext_a: Array, T_b: Array, ext_b: Array) -> float:
    """Distance between two boxes (0 when they meet): the closest pair of two disjoint convex
    polyhedra involves an edge of one of them, and two meeting boxes have an edge of one
    inside the other, so the least edge-to-box distance is exact."""
    d = [segment_box(p, q, T_b, ext_b)[0] for p, q in box_edges(T_a, ext_a)]
    d += [segment_box(p, q, T_a, ext_a)[0] for p, q in box_edges(T_b, ext_b)]
    return min(d)
