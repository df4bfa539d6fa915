"""A path's marked strokes: where the laser is on, sampled for the path solver.

A polyline is cut at every vertex where the direction turns by more than ``corner_deg``
(the corner is marked sharp: the laser goes off at the vertex and the spot runs out, turns
and runs in along the next edge). Each piece between sharp corners is a *stroke*, marked in
one go at constant speed. Smaller turns inside a stroke are rounded by a circular blend arc
tangent to both edges whose radius keeps the arc within :data:`BLEND_SHARE` of the path
tolerance of the vertex, so the spot can sweep them at constant speed without leaving the
polyline. ``smooth`` reads the points as samples of a smooth curve instead: a cubic spline
through them (chord-length parameter; periodic when closed), one stroke.

Every stroke is sampled at one spacing (at most the requested ``spacing``, finer where a
blend arc or the curve bends so that the chord between two samples stays within
:data:`CHORD_SHARE` of the tolerance of the curve), uniform between its knots: its end
vertices and the midpoint of every blend arc (the arc's point nearest its vertex), so every
vertex of the polyline has a sample: exactly at the stroke ends, within
:data:`BLEND_SHARE` of the tolerance of the polyline at a blended vertex
(``MarkedPath.vertex_gap`` is the largest distance of a vertex from its sample).
Consecutive strokes share their vertex sample; a closed path's last stroke ends on sample 0. Coordinates in the polyline's own
frame (any rigid frame), metres; angles in degrees only where the name says so.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import pairwise

import numpy as np

from planner.errors import InputError
from planner.model.transforms import Array

DEFAULT_CORNER_DEG = 20.0
DEFAULT_PATH_TOLERANCE = 5e-5  # m
BLEND_SHARE = 0.4  # of the path tolerance: how far a blend arc may cut a swept corner
CHORD_SHARE = 0.2  # of the path tolerance: sagitta of a blend arc between two samples
MIN_SPACING_SHARE = 1 / 16  # samples are never closer than this share of the spacing
_TINY_TURN = 1e-9  # rad: straighter vertices are not blended


@dataclass(frozen=True)
class MarkedPath:
    """Samples of a path (``points`` K x 3, unit ``normals`` K x 3 or None) and its
    ``strokes``: sample index sequences marked in one go, in order (consecutive strokes
    share their vertex sample; a closed path's last stroke ends on index 0). ``spacing`` (m)
    is the largest distance between consecutive samples of a stroke; ``sharp`` the corners
    marked sharp, ``blended`` the vertices swept through a blend arc; ``blend_deviation``
    (m) the largest distance of a blend arc from the polyline and ``vertex_gap`` (m) the
    largest distance of a vertex from its sample (0 without blend arcs)."""

    points: Array
    normals: Array | None
    strokes: tuple[tuple[int, ...], ...]
    spacing: float
    sharp: int
    blended: int
    blend_deviation: float = 0.0
    vertex_gap: float = 0.0

    def meta(self) -> dict[str, object]:
        """The ``Targets.meta`` entries of a marked path (the plan reports the figures)."""
        return {"strokes": self.strokes, "sample_spacing": self.spacing,
                "sharp_corners": self.sharp, "blended_corners": self.blended,
                "blend_deviation": self.blend_deviation, "vertex_gap": self.vertex_gap}  # fmt: skip


def turn_angles(vertices: Array, closed: bool = False) -> Array:
    """Turn angle (rad, 0 = straight on, pi = back) at every interior vertex of a polyline
    (n - 2 values), or at every vertex of a closed one (n values, vertex i between edges
    i-1 -> i and i -> i+1)."""
    V = np.asarray(vertices, dtype=float)
    E = np.diff(np.vstack([V, V[:1]]) if closed else V, axis=0)
    U = E / np.linalg.norm(E, axis=1, keepdims=True)
    a, b = (np.roll(U, 1, axis=0), U) if closed else (U[:-1], U[1:])
    return np.asarray(np.arccos(np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0)))


def _dedup(V: Array, N: Array | None, closed: bool) -> tuple[Array, Array | None]:
    """Drop vertices that repeat the previous one (zero-length edges)."""
    keep = np.concatenate([[True], np.linalg.norm(np.diff(V, axis=0), axis=1) > 1e-12])
    if closed and keep.sum() > 1 and np.linalg.norm(V[keep][-1] - V[0]) <= 1e-12:
        keep[np.flatnonzero(keep)[-1]] = False
    return V[keep], None if N is None else N[keep]


class _Stroke:
    """One stroke: a polyline of vertices with blend arcs at its interior vertices,
    evaluated by arc length s (m). ``u`` is each vertex's arc length along the polyline
    itself (for normal interpolation)."""

    def __init__(self, V: Array, u: Array, tolerance: float) -> None:
        E = np.diff(V, axis=0)
        lengths = np.linalg.norm(E, axis=1)
        U = E / lengths[:, None]
        pieces: list[tuple[str, float, tuple[Array, ...], tuple[float, float]]] = []
        start, s_poly = V[0], float(u[0])
        self.min_radius = np.inf
        self.blended = 0
        self.deviation, self.gap = 0.0, 0.0  # m: arc from the polyline, vertex from its arc
        for i in range(1, len(V) - 1):
            theta = float(np.arccos(np.clip(U[i - 1] @ U[i], -1.0, 1.0)))
            if theta <= _TINY_TURN:
                continue
            half = np.tan(theta / 2)
            r = BLEND_SHARE * tolerance / (1 - np.cos(theta / 2))
            r = min(r, 0.5 * min(lengths[i - 1], lengths[i]) / half)
            d = r * half
            t1, t2 = V[i] - d * U[i - 1], V[i] + d * U[i]
            pieces.append(("line", float(np.linalg.norm(t1 - start)), (start, U[i - 1]),
                           (s_poly, float(u[i]) - d)))  # fmt: skip
            centre = V[i] + (U[i] - U[i - 1]) / np.linalg.norm(U[i] - U[i - 1]) * r / np.cos(
                theta / 2
            )
            a = (t1 - centre) / r
            pieces.append(("arc", r * theta, (centre, a, U[i - 1], np.array([r, theta])),
                           (float(u[i]) - d, float(u[i]) + d)))  # fmt: skip
            self.min_radius = min(self.min_radius, r)
            self.blended += 1
            self.deviation = max(self.deviation, r * (1 - np.cos(theta / 2)))
            self.gap = max(self.gap, r * (1 / np.cos(theta / 2) - 1))
            start, s_poly = t2, float(u[i]) + d
        pieces.append(("line", float(np.linalg.norm(V[-1] - start)), (start, U[-1]),
                       (s_poly, float(u[-1]))))  # fmt: skip
        self.pieces = pieces
        self.edges = np.concatenate([[0.0], np.cumsum([p[1] for p in pieces])])
        self.end = V[-1]

    @property
    def length(self) -> float:
        return float(self.edges[-1])

    def knots(self) -> Array:
        """Arc lengths (m) that are samples: 0, every blend arc's midpoint, the length."""
        mids = [self.edges[j] + 0.5 * p[1] for j, p in enumerate(self.pieces) if p[0] == "arc"]
        return np.array([0.0, *mids, self.length])

    def sample(self, n: int) -> Array:
        """Arc lengths (m) of about ``n`` intervals: each knot interval cut uniformly, no
        interval longer than length / n."""
        k = self.knots()
        h = self.length / n
        parts = [np.linspace(a, b, max(1, int(np.ceil((b - a) / h - 1e-9))) + 1)[:-1]
                 for a, b in pairwise(k)]  # fmt: skip
        return np.concatenate([*parts, [self.length]])

    def at(self, s: Array) -> tuple[Array, Array]:
        """Points (M x 3) at arc lengths ``s`` (m) and their polyline arc length (M,)."""
        idx = np.clip(np.searchsorted(self.edges, s, side="right") - 1, 0, len(self.pieces) - 1)
        P, W = np.empty((len(s), 3)), np.empty(len(s))
        for j, (kind, length, geo, (w0, w1)) in enumerate(self.pieces):
            m = idx == j
            x = np.clip(s[m] - self.edges[j], 0.0, length)
            f = x / length if length > 0 else np.zeros_like(x)
            W[m] = w0 + f * (w1 - w0)
            if kind == "line":
                P[m] = geo[0] + x[:, None] * geo[1]
            else:
                centre, a, b, (r, theta) = geo
                phi = f * theta
                P[m] = centre + r * (np.cos(phi)[:, None] * a + np.sin(phi)[:, None] * b)
        P[s >= self.edges[-1]] = self.end
        return P, W


def _spacing(length: float, spacing: float, tolerance: float, radius: float) -> int:
    """Number of equal intervals over ``length`` (m): at most ``spacing`` apart, and close
    enough on a curve of ``radius`` (m) for the chord to stay within the chord share."""
    h = spacing
    if np.isfinite(radius):
        h = min(h, float(np.sqrt(8 * radius * CHORD_SHARE * tolerance)))
    h = max(h, spacing * MIN_SPACING_SHARE)
    return max(1, int(np.ceil(length / h - 1e-9)))


def _normals_at(u: Array, s_vertex: Array, N: Array | None) -> Array | None:
    if N is None:
        return None
    out = np.column_stack([np.interp(u, s_vertex, N[:, i]) for i in range(3)])
    return np.asarray(out / np.linalg.norm(out, axis=1, keepdims=True))


def _open_polyline(V: Array, N: Array | None, closed: bool, corner: float
                   ) -> tuple[Array, Array | None]:  # fmt: skip
    """A closed polyline as an open one that starts and ends at the same point: at its
    first sharp corner, else at the middle of its longest edge (a straight point)."""
    if not closed:
        return V, N
    sharp = np.flatnonzero(turn_angles(V, closed=True) > corner)
    if len(sharp):
        k = int(sharp[0])
        V, N = np.roll(V, -k, axis=0), None if N is None else np.roll(N, -k, axis=0)
    else:
        E = np.diff(np.vstack([V, V[:1]]), axis=0)
        k = int(np.argmax(np.linalg.norm(E, axis=1)))
        V = np.vstack([0.5 * (V[k] + V[(k + 1) % len(V)]), np.roll(V, -k - 1, axis=0)])
        if N is not None:
            mid = N[k] + N[(k + 1) % len(N)]
            N = np.vstack([mid / np.linalg.norm(mid), np.roll(N, -k - 1, axis=0)])
    return np.vstack([V, V[:1]]), None if N is None else np.vstack([N, N[:1]])


def mark_path(
    points: object, spacing: float, *, normals: object = None, closed: bool = False,
    corner_deg: float = DEFAULT_CORNER_DEG, smooth: bool = False,
    tolerance: float = DEFAULT_PATH_TOLERANCE,
) -> MarkedPath:  # fmt: skip
    """Sample a path (vertices n x 3, m; per-vertex ``normals``) into marked strokes.

    Raises :class:`~planner.errors.InputError` naming the field (``points``: a path of zero
    length; ``normals``: opposite normals on one edge)."""
    V = np.asarray(points, dtype=float).reshape(-1, 3)
    N = None if normals is None else np.asarray(normals, dtype=float).reshape(-1, 3)
    N = None if N is None else N / np.linalg.norm(N, axis=1, keepdims=True)
    V, N = _dedup(V, N, closed)
    if len(V) < 2:
        raise InputError("path has zero length", "points")
    if smooth and len(V) >= 3:
        return _smooth(V, N, spacing, closed, tolerance)
    corner = float(np.radians(corner_deg))
    loop = closed and len(V) >= 3
    loop_sharp = loop and bool(np.any(turn_angles(V, closed=True) > corner))
    V, N = _open_polyline(V, N, loop, corner)
    if N is not None:
        for v in np.flatnonzero(np.einsum("ij,ij->i", N[:-1], N[1:]) < -1 + 1e-9):
            raise InputError(
                f"normals of vertices {v} and {v + 1} are opposite; cannot interpolate", "normals"
            )
    u = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(V, axis=0), axis=1))])
    cuts = [0, *(np.flatnonzero(turn_angles(V) > corner) + 1).tolist(), len(V) - 1]
    pts: list[Array] = []
    wts: list[Array] = []
    strokes: list[tuple[int, ...]] = []
    h_max, blended, k0, dev, gap = 0.0, 0, 0, 0.0, 0.0
    for a, b in pairwise(cuts):
        st = _Stroke(V[a : b + 1], u[a : b + 1], tolerance)
        x = st.sample(_spacing(st.length, spacing, tolerance, st.min_radius))
        n = len(x) - 1
        P, W = st.at(x)
        first = 0 if not pts else 1  # the shared vertex sample is already there
        pts.append(P[first:])
        wts.append(W[first:])
        strokes.append(tuple(range(k0, k0 + n + 1)))
        k0 += n
        h_max, blended = max(h_max, float(np.diff(x).max())), blended + st.blended
        dev, gap = max(dev, st.deviation), max(gap, st.gap)
    P, W = np.vstack(pts), np.concatenate(wts)
    if loop:  # the last sample repeats the first: the loop ends on 0
        P, W = P[:-1], W[:-1]
        strokes[-1] = (*strokes[-1][:-1], 0)
    sharp = len(cuts) - 2 + int(loop_sharp)
    return MarkedPath(P, _normals_at(W, u, N), tuple(strokes), h_max, sharp, blended, dev, gap)


def _smooth(V: Array, N: Array | None, spacing: float, closed: bool, tolerance: float
            ) -> MarkedPath:  # fmt: skip
    """One stroke along a cubic spline through the vertices, uniform in arc length."""
    from scipy.interpolate import CubicSpline

    W = np.vstack([V, V[:1]]) if closed else V
    u = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(W, axis=0), axis=1))])
    spline = CubicSpline(u, W, axis=0, bc_type="periodic" if closed else "not-a-knot")
    x = np.linspace(0.0, u[-1], 64 * len(W) + 1)
    d1, d2 = spline(x, 1), spline(x, 2)
    speed = np.linalg.norm(d1, axis=1)
    kappa = np.linalg.norm(np.cross(d1, d2), axis=1) / speed**3
    arc = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(x))])
    n = _spacing(float(arc[-1]), spacing, tolerance, 1.0 / max(float(kappa.max()), 1e-12))
    x_new = np.interp(np.linspace(0.0, arc[-1], n + 1), arc, x)
    P = spline(x_new)
    normals = None
    if N is not None:
        Nw = np.vstack([N, N[:1]]) if closed else N
        normals = _normals_at(x_new, u, Nw)
    K = len(P) - 1 if closed else len(P)
    stroke = (*range(K), 0) if closed else tuple(range(K))
    return MarkedPath(P[:K], None if normals is None else normals[:K], (stroke,),
                      float(arc[-1] / n), 0, 0)  # fmt: skip
