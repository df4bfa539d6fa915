"""What the camera saw of an executed path: the marked spots against the planned path.

Pure: the spots a :class:`~planner.service.client.Recorder` collected while the robots moved
(camera frame, each with the joints at its arrival) and the executed plan. Each
spot is placed on the trajectory by its joints (the nearest trajectory sample in joint
space, so no clock has to be shared with the drivers); it counts as *marked* when that time
lies in one of the plan's ``laser_on`` intervals. The marked spots are compared with the
planned path (the polyline through the plan's resampled targets): their distance to it, and
how much of its length they cover. World frame, metres, seconds.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from planner.io.plan import Plan
from planner.model.transforms import Array, transform_points

#: m: marked spots closer than this along the path cover the stretch between them
COVER_GAP = 0.005


class Sweep(NamedTuple):
    """Figures of one executed path (see the module docstring). ``marked``: world spots (m)
    seen while the laser was planned on, in order; ``unlit``: how many were seen while it
    was planned off (0 with a gated laser: the camera sees no spot then); ``deviation_*``:
    distance of the marked spots to the planned path (m, NaN without any); ``covered`` /
    ``length``: m of the planned path that marked spots cover (gaps < COVER_GAP) / its length."""

    marked: Array
    unlit: int
    deviation_median: float
    deviation_max: float
    covered: float
    length: float


def sweep_of(plan: Plan, spots: list[tuple[Array, dict[str, Array]]],
             world_T_camera: Array) -> Sweep:  # fmt: skip
    """The :class:`Sweep` of ``spots`` (camera-frame point, joints by robot name in rad) seen
    while ``plan`` (with a trajectory) was executed."""
    traj = plan.trajectory
    path = plan.targets.p.reshape(-1, 3)
    length = float(np.sum(np.linalg.norm(np.diff(path, axis=0), axis=1)))
    robots = [] if traj is None else list(traj.q)
    if traj is None or not robots or not spots:
        return Sweep(np.zeros((0, 3)), 0, np.nan, np.nan, 0.0, length)
    t = traj.t
    Q = np.hstack([traj.q[r] for r in robots])
    seen = [(p, q) for p, q in spots if all(r in q for r in robots)]
    if not seen:
        return Sweep(np.zeros((0, 3)), 0, np.nan, np.nan, 0.0, length)
    P = transform_points(world_T_camera, np.array([p for p, _ in seen], dtype=float))
    Qs = np.array([np.concatenate([q[r] for r in robots]) for _, q in seen], dtype=float)
    times = t[_nearest_rows(Q, Qs)]
    lit = _inside(times, traj.laser_on.tolist())
    marked = P[lit]
    if not len(marked):
        return Sweep(marked, int(np.sum(~lit)), np.nan, np.nan, 0.0, length)
    dist, s = polyline_distance(path, marked)
    return Sweep(marked, int(np.sum(~lit)), float(np.median(dist)), float(np.max(dist)),
                 covered_length(s, COVER_GAP), length)  # fmt: skip


def polyline_distance(path: Array, points: Array) -> tuple[Array, Array]:
    """Distance of each point (M x 3) to the polyline ``path`` (K x 3, K >= 1) and the arc
    length (m from ``path[0]``) of its nearest point on it."""
    if len(path) == 1:
        return np.linalg.norm(points - path[0], axis=1), np.zeros(len(points))
    a, b = path[:-1], path[1:]
    ab = b - a
    seg = np.linalg.norm(ab, axis=1)
    s0 = np.concatenate([[0.0], np.cumsum(seg)])[:-1]
    w = points[:, None, :] - a[None, :, :]  # M x (K-1) x 3
    u = np.clip((w * ab).sum(axis=2) / np.maximum(seg**2, 1e-30), 0.0, 1.0)
    d = np.linalg.norm(w - u[:, :, None] * ab[None], axis=2)
    j = np.argmin(d, axis=1)
    rows = np.arange(len(points))
    return d[rows, j], s0[j] + u[rows, j] * seg[j]


def covered_length(s: Array, gap: float) -> float:
    """Length of [min s, max s] covered by consecutive arc positions ``s`` (m) closer than
    ``gap``."""
    if len(s) < 2:
        return 0.0
    d = np.diff(np.sort(s))
    return float(np.sum(d[d < gap]))


def _nearest_rows(Q: Array, Qs: Array, chunk: int = 64) -> Array:
    """Index of the row of Q (T x n) nearest each row of Qs (M x n)."""
    out = np.empty(len(Qs), dtype=int)
    for a in range(0, len(Qs), chunk):
        d = np.sum((Qs[a : a + chunk, None, :] - Q[None, :, :]) ** 2, axis=2)
        out[a : a + chunk] = np.argmin(d, axis=1)
    return out


def _inside(times: Array, intervals: list[list[float]]) -> npt.NDArray[np.bool_]:
    on = np.zeros(len(times), dtype=bool)
    for t0, t1 in intervals:
        on |= (times >= t0) & (times <= t1)
    return on
