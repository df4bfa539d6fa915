"""Distances between primitive shapes for many configurations at once (plain numpy).

Every function takes arrays with a leading batch axis M (or broadcastable to it): points
``(M, 3)``, boxes as poses ``(M, 4, 4)`` with full ``extents`` (3,), world frame, metres.
Distances are >= 0 and 0 when the shapes meet (no penetration depth), which is all a
clearance check needs. Written from the geometry (closest points of segments after Ericson,
Real-Time Collision Detection 5.1.9; the closest pair of a segment and a box involves an
end point or a box edge unless they intersect), independent of coal.
"""

from __future__ import annotations

import itertools

import numpy as np

from planner.model.transforms import Array

_SIGNS = np.array(list(itertools.product((-1.0, 1.0), repeat=3)))
#: the 12 box edges as pairs of corner indices into _SIGNS (corners differing in one sign)
_EDGES = [(i, j) for i in range(8) for j in range(i + 1, 8) if np.sum(_SIGNS[i] != _SIGNS[j]) == 1]


def _dot(a: Array, b: Array) -> Array:
    return (a * b).sum(axis=-1)


def segment_segment(A: Array, B: Array, C: Array, D: Array) -> Array:
    """Distances (M,) between segments A-B and C-D (each (M, 3) or broadcastable)."""
    d1, d2, r = B - A, D - C, A - C
    a, e = _dot(d1, d1), _dot(d2, d2)
    b, c, f = _dot(d1, d2), _dot(d1, r), _dot(d2, r)
    a_ok, e_ok = a > 1e-24, e > 1e-24
    a_, e_ = np.where(a_ok, a, 1.0), np.where(e_ok, e, 1.0)
    denom = a * e - b * b
    s = np.where(
        denom > 1e-12 * a_ * e_,
        np.clip((b * f - c * e) / np.where(denom > 0, denom, 1.0), 0.0, 1.0),
        0.0,
    )
    t = np.where(e_ok, (b * s + f) / e_, 0.0)
    s = np.where(
        t < 0.0, np.clip(-c / a_, 0.0, 1.0), np.where(t > 1.0, np.clip((b - c) / a_, 0.0, 1.0), s)
    )
    s = np.where(e_ok, s, np.clip(-c / a_, 0.0, 1.0))  # C-D a point: nearest point of A-B
    s = np.where(a_ok, s, 0.0)
    t = np.where(e_ok, np.clip((b * s + f) / e_, 0.0, 1.0), 0.0)
    x = r + s[..., None] * d1 - t[..., None] * d2
    return np.sqrt(_dot(x, x))


def point_segment(X: Array, A: Array, B: Array) -> Array:
    """Distances (M,) from points X to segments A-B."""
    d = B - A
    L2 = _dot(d, d)
    s = np.clip(_dot(X - A, d) / np.where(L2 > 0, L2, 1.0), 0.0, 1.0)
    x = A + s[..., None] * d - X
    return np.sqrt(_dot(x, x))


def _local(T: Array, X: Array) -> Array:
    """Points X (M, 3) in the frames T (M, 4, 4)."""
    return np.einsum("...ji,...j->...i", T[..., :3, :3], X - T[..., :3, 3])


def point_box(X: Array, T: Array, extents: Array) -> Array:
    """Distances (M,) from points X to boxes (0 inside)."""
    h = np.asarray(extents, dtype=float) / 2
    u = _local(T, X)
    g = np.abs(u) - h
    g = np.maximum(g, 0.0)
    return np.sqrt(_dot(g, g))


def segment_box(A: Array, B: Array, T: Array, extents: Array) -> Array:
    """Distances (M,) from segments A-B to boxes (0 when they meet)."""
    h = np.asarray(extents, dtype=float) / 2
    a, b = _local(T, A), _local(T, B)
    d = b - a
    lo, hi = np.zeros(a.shape[:-1]), np.ones(a.shape[:-1])
    for i in range(3):
        still = np.abs(d[..., i]) <= 1e-15
        outside = still & (np.abs(a[..., i]) > h[i])
        dd = np.where(still, 1.0, d[..., i])
        t0, t1 = (-h[i] - a[..., i]) / dd, (h[i] - a[..., i]) / dd
        lo = np.where(still, np.where(outside, 2.0, lo), np.maximum(lo, np.minimum(t0, t1)))
        hi = np.where(still, hi, np.minimum(hi, np.maximum(t0, t1)))
    meet = lo <= hi
    corners = _SIGNS * h
    best = np.minimum(point_box(A, T, extents), point_box(B, T, extents))
    for i, j in _EDGES:
        best = np.minimum(best, segment_segment(a, b, corners[i], corners[j]))
    return np.where(meet, 0.0, best)


def box_edges(T: Array, extents: Array) -> list[tuple[Array, Array]]:
    """The 12 edges (pairs of (M, 3) world points) of boxes T with ``extents``."""
    h = np.asarray(extents, dtype=float) / 2
    C = np.einsum("...ij,kj->...ki", T[..., :3, :3], _SIGNS * h) + T[..., None, :3, 3]
    return [(C[..., i, :], C[..., j, :]) for i, j in _EDGES]


def box_box(T1: Array, e1: Array, T2: Array, e2: Array) -> Array:
    """Distances (M,) between boxes (0 when they meet): the closest pair of two disjoint
    boxes involves an edge of one of them, and two meeting boxes have an edge of one meeting
    the other."""
    best = np.full(np.broadcast_shapes(T1.shape, T2.shape)[:-2], np.inf)
    for p, q in box_edges(T1, e1):
        best = np.minimum(best, segment_box(p, q, T2, e2))
    for p, q in box_edges(T2, e2):
        best = np.minimum(best, segment_box(p, q, T1, e1))
    return best


def segment_hull_meets(A: Array, B: Array, planes: Array, margin: float = 0.0) -> Array:
    """(M,) True where segment A-B enters a convex polytope given by ``planes`` (F x 4:
    n . x + d <= -margin inside, world; unit n), by clipping the segment against every
    plane."""
    n, off = planes[:, :3], planes[:, 3] + margin
    fa = A @ n.T + off  # (M, F)
    fb = B @ n.T + off
    lo, hi = np.zeros(len(A)), np.ones(len(A))
    both_out = np.any((fa > 0) & (fb > 0), axis=1)
    cross = (fa > 0) != (fb > 0)
    t = np.where(cross, fa / np.where(cross, fa - fb, 1.0), 0.0)
    lo = np.maximum(lo, np.where(cross & (fa > 0), t, 0.0).max(axis=1))
    hi = np.minimum(hi, np.where(cross & (fb > 0), t, 1.0).min(axis=1))
    return ~both_out & (lo <= hi)
