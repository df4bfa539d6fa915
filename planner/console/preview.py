"""What a plan reply shows before anything moves: beams, failures, the swept path, timing.

Pure functions of a plan.json dict (docs/conventions.md section 5; world frame, m, s) and the console's
:class:`~planner.model.system.System`: :func:`preview_of` gathers the planned beam of every
solved target (laser exit, mirror hits, spot), the failed targets with their reason, the
spot's path over the trajectory and the duration; :func:`joints_at` interpolates the
trajectory's joints at a time for the scrub slider; :func:`beam_polyline` traces the beam at
joints onto the scene for drawing.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from planner.beam.trace import trace_beam
from planner.io.plan import Plan, Trajectory
from planner.model.scene import SceneModel
from planner.model.status import Status
from planner.model.system import System
from planner.model.transforms import Array

#: the last beam segment is drawn this far (m) when it meets no scene object
FREE_BEAM_LENGTH = 1.0
#: at most this many trajectory samples are traced for the swept path
SWEEP_SAMPLES = 400


class Failure(NamedTuple):
    """A failed target: its index, ``p`` (world, m), ``reason`` (a plan.json reason), the detail text."""

    target: int
    p: Array
    reason: str
    detail: str


class Preview(NamedTuple):
    """Drawable content of a plan: ``beams`` (one (N + 2) x 3 polyline per solved target:
    laser exit, mirror hits, spot), ``failed``, ``sweep`` (the spot's path over the
    trajectory where the laser is on, K x 3; the solved spots in order without a
    trajectory), ``duration`` (s, 0 without a trajectory) and the plan's ``n_ok`` / ``n``."""

    beams: tuple[Array, ...]
    failed: tuple[Failure, ...]
    sweep: Array
    duration: float
    n_ok: int
    n: int


def preview_of(plan: Plan, system: System, scene: SceneModel | None) -> Preview:
    """The :class:`Preview` of a plan reply."""
    laser = system.world_T_laser[:3, 3]
    beams, failed, spots = [], [], []
    for sol in plan.solutions:
        k = sol.target
        if sol.status is Status.OK and sol.spot is not None:
            beams.append(np.vstack([laser, *(h.p for h in sol.hits), sol.spot]))
            spots.append(sol.spot)
        else:
            p = plan.targets.p[int(np.flatnonzero(plan.targets.ids == k)[0])]
            failed.append(Failure(k, p, str(sol.reason or "failed"), ""))
    traj = plan.trajectory
    timed = traj is not None and len(traj.t) > 0
    duration = float(traj.t[-1]) if traj is not None and timed else 0.0
    sweep = sweep_path(traj, system, scene) if traj is not None and timed else np.zeros((0, 3))
    if len(sweep) == 0 and spots:
        sweep = np.asarray(spots)
    return Preview(tuple(beams), tuple(failed), sweep, duration, plan.metrics.n_ok,
                   len(plan.solutions))  # fmt: skip


def joints_at(traj: Trajectory, robots: tuple[str, ...], t: float) -> dict[str, Array]:
    """Each robot's joints (rad) at time ``t`` (s, clamped to the trajectory), linearly
    interpolated between the trajectory's samples."""
    T = traj.t
    t = float(np.clip(t, T[0], T[-1]))
    i = int(np.clip(np.searchsorted(T, t) - 1, 0, max(len(T) - 2, 0)))
    out = {}
    for r in robots:
        Q = traj.q[r]
        if len(T) == 1:
            out[r] = Q[0]
            continue
        w = (t - T[i]) / max(T[i + 1] - T[i], 1e-12)
        out[r] = (1 - w) * Q[i] + w * Q[i + 1]
    return out


def laser_on_mask(traj: Trajectory, t: Array) -> Array:
    """Whether the laser gate is on at each time of ``t`` (s)."""
    on = np.zeros(len(t), dtype=bool)
    for t0, t1 in traj.laser_on:
        on |= (t >= t0) & (t <= t1)
    return on


def sweep_path(traj: Trajectory, system: System, scene: SceneModel | None) -> Array:
    """Where the beam lands (world, m) at up to SWEEP_SAMPLES trajectory times while the
    laser is on (times whose reflection chain is invalid are left out)."""
    T = traj.t
    idx = np.unique(np.linspace(0, len(T) - 1, min(len(T), SWEEP_SAMPLES)).astype(int))
    idx = idx[laser_on_mask(traj, T[idx])]
    rays = []
    for i in idx:
        q = {r: traj.q[r][i] for r in system.robot_names}
        pts, ok, v = _chain(system, q)
        if ok:
            rays.append((pts[-1], v))
    if not rays:
        return np.zeros((0, 3))
    P = np.array([p for p, _ in rays])
    V = np.array([v for _, v in rays])
    return P + _landing(P, V, scene)[:, None] * V


def _chain(system: System, q: dict[str, Array]) -> tuple[list[Array], bool, Array]:
    """Laser exit and mirror hits while the chain is valid; whether all were valid (else
    the list ends FREE_BEAM_LENGTH m along the ray that missed); the last ray's direction."""
    tr = trace_beam(system, system.stack_q(q), np.zeros(3))
    pts = [system.world_T_laser[:3, 3]]
    for i in range(len(tr.hits)):
        if not (tr.ahead[i] > 0 and tr.front[i] > 0 and np.all(tr.roi[i] >= 0)):
            pts.append(pts[-1] + FREE_BEAM_LENGTH * tr.dirs[i])
            return pts, False, tr.dirs[i]
        pts.append(tr.hits[i])
    return pts, True, tr.dirs[-1]


def _landing(P: Array, V: Array, scene: SceneModel | None) -> Array:
    """Distance (m) along each ray (K x 3 starts, unit directions) to the first scene
    surface, FREE_BEAM_LENGTH where it meets none."""
    if scene is None or scene.empty:
        return np.full(len(P), FREE_BEAM_LENGTH)
    t = scene.cast(P + 1e-6 * V, V).t
    return np.where(np.isfinite(t), t, FREE_BEAM_LENGTH)


def beam_polyline(system: System, q: dict[str, Array], scene: SceneModel | None) -> Array:
    """The beam at joints ``q`` (rad per robot) as a polyline (world, m): the laser exit,
    each mirror hit while the chain is valid, then the first scene surface along the last
    ray (or FREE_BEAM_LENGTH m of it). A ray that misses a mirror ends FREE_BEAM_LENGTH m
    along its direction."""
    pts, ok, v = _chain(system, q)
    if not ok:
        return np.asarray(pts)
    p = pts[-1]
    pts.append(p + _landing(p[None], v[None], scene)[0] * v)
    return np.asarray(pts)
