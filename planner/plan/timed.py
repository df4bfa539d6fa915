"""Timing the solved targets (the plan's ``trajectory``) and the figures that describe it.

:func:`time_solutions` makes Ruckig rest-to-rest moves through the solved points (visit order
optimised unless the scenario says ``order: given``), or sweeps each marked stroke of a path
at the scenario's spot speed with sky-writing (:mod:`planner.path.marking`), dense at
``rate``, with the laser gate's ``laser_on`` intervals (:mod:`planner.path.timing`).
:func:`time_safely` does it under the safety rules (:mod:`planner.plan.safe_timing`). The
figures (limit ratios, arm posture, the spot's deviation from the path) go to plan.json
``metrics.extra``. Times in s, joints in rad, world frame, metres.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from planner.beam.graph import beam_function, system_params
from planner.model.polyline import arc_length
from planner.model.system import System, Targets
from planner.model.transforms import Array
from planner.path.marking import mark_runs, marking_trajectory
from planner.path.solve import jacobian_condition
from planner.path.timing import points_trajectory, ruckig_move
from planner.plan.safe_timing import safe_timing
from planner.verify.spot import segment_mask
from planner.verify.trajectory import spot_deviation

if TYPE_CHECKING:
    from planner.ik import Solution
    from planner.model.settings import TrajectorySettings
    from planner.path.result import PathResult
    from planner.path.timing import MoveFn, Trajectory, VisitReport
    from planner.plan.scenario_planner import Progress
    from planner.safety.model import Safety
    from planner.verify.spot import Mask


class Timed(NamedTuple):
    """A timed trajectory and how it was made: ``visit`` for points (durations in the given
    vs the chosen order), ``figures`` for plan.json ``metrics.extra`` (SI units)."""

    trajectory: Trajectory
    visit: VisitReport | None
    figures: dict[str, float]


def time_solutions(
    system: System,
    targets: Targets,
    solutions: list[Solution],
    settings: TrajectorySettings,
    *,
    q_start: Array | None = None,
    order: str = "optimal",
    path: PathResult | None = None,
    progress: Progress | None = None,
    skywriting: bool = True,
    move: MoveFn | None = None,
) -> Timed | None:
    """Time the solved targets from ``q_start`` (stacked rad, default home) at the scenario
    ``rate`` (Hz). Points/grid: rest-to-rest Ruckig moves in the ``optimal`` (or ``given``)
    order with ``dwell`` s on each (laser on while dwelling). Path: each stroke's runs of
    solved samples marked at ``spot_speed`` (m/s) between a run-in and a run-out
    (:func:`planner.path.marking.mark_runs`; ``skywriting=False``: from rest to rest, for
    comparison only), laser on only on the path. None if nothing was solved. ``move`` makes
    every rest-to-rest move: the approach, between point targets and between a path's
    strokes (default Ruckig, :mod:`planner.path.timing`)."""

    rate = settings.rate
    q0 = system.home if q_start is None else np.asarray(q_start, dtype=float)
    Q = np.array([np.full(system.nq, np.nan) if s.q is None else s.q for s in solutions])
    if not len(Q) or not np.isfinite(Q).all(axis=1).any():
        return None
    if targets.kind != "path":
        traj, visit = points_trajectory(
            system, Q, q0, settings.dwell, rate, order, progress=progress, move=move
        )
        figures = {"duration_given_order": visit.duration_given,
                   "duration_chosen_order": visit.duration_optimised}  # fmt: skip
        return Timed(traj, visit, figures | limit_ratios(system, traj) | posture(system, Q))

    arc = path.arc if path is not None else arc_length(targets.points)
    speed = settings.spot_speed
    pieces = mark_runs(system, targets, Q, arc, speed, skywriting=skywriting, rate=rate)
    traj = marking_trajectory(system, pieces, q0, speed, rate, move=move)
    figures = {"path_time": traj.span("path"), "path_length": float(arc[-1]),
               "path_deviation_max": path_deviation(system, targets, traj),
               "slowdowns": float(len(traj.slowdowns)),
               "approach_time": traj.span("approach")}  # fmt: skip
    for key in ("sharp_corners", "blended_corners", "blend_deviation", "vertex_gap"):
        if key in targets.meta:  # how far the targets (blend arcs) are from the polyline, m
            figures[key] = float(targets.meta[key])  # type: ignore[arg-type]
    return Timed(traj, None, figures | limit_ratios(system, traj) | posture(system, Q))


def posture(system: System, Q: Array) -> dict[str, float]:
    """Largest and median condition number of the arms' Jacobians over the solved rows of
    ``Q`` (:func:`planner.path.solve.jacobian_condition`)."""
    cond = jacobian_condition(system, Q)
    if not len(cond):
        return {}
    return {"jacobian_condition_max": float(cond.max()),
            "jacobian_condition_median": float(np.median(cond))}  # fmt: skip


def limit_ratios(system: System, traj: Trajectory) -> dict[str, float]:
    """Largest |qd|, |qdd| of the trajectory as a fraction of each joint's limit."""
    lim = system.limits
    if not len(traj.t):
        return {}
    out = {
        "joint_speed_max_ratio": float((np.abs(traj.qd) / lim.velocity).max()),
        "joint_acceleration_max_ratio": float((np.abs(traj.qdd) / lim.acceleration).max()),
    }
    on_path = _mask(traj, "path")
    if on_path.any():
        out["path_joint_speed_max_ratio"] = float((np.abs(traj.qd[on_path]) / lim.velocity).max())
    return out


def _mask(traj: Trajectory, kind: str) -> Mask:
    """Samples of the trajectory inside segments of one kind."""

    return segment_mask(traj.t, [s._asdict() for s in traj.segments], kind)


def spot_rays(system: System, Q: Array) -> tuple[Array, Array]:
    """Last ray (origin, unit direction), each M x 3 in the world frame, of configurations
    ``Q`` (M x nq) through the planner's beam function."""
    N = system.n_robots
    f = beam_function(tuple(r.kinematics for r in system.robots)).map(len(Q))
    zeros = np.zeros((3, len(Q)))
    out = f(q=Q.T, **system_params(system), target=zeros, normal=zeros)
    hits, dirs = np.asarray(out["hits"]), np.asarray(out["dirs"])
    return hits[:, N - 1 :: N].T, dirs[:, N :: N + 1].T


def path_deviation(system: System, targets: Targets, traj: Trajectory) -> float:
    """Largest distance (m) of the spot from the target polyline over the ``path`` segments
    (the spot is where the ray meets the nearest sample's plane)."""

    mask = _mask(traj, "path")
    if not mask.any():
        return 0.0
    p, v = spot_rays(system, traj.q[mask])
    dev = spot_deviation(p, v, targets.points, targets.normals, bool(targets.closed))
    return float(dev.max())


def time_safely(
    system: System, targets: Targets, solutions: list[Solution], settings: TrajectorySettings, *,
    safety: Safety | None, order: str, path: PathResult | None, progress: Progress | None,
    q_start: Array | None = None,
) -> tuple[Timed | None, list[Solution], PathResult | None, dict[str, float]]:  # fmt: skip
    """:func:`time_solutions` (from ``q_start``, default home) under the ``safety`` rules
    (:func:`planner.plan.safe_timing.safe_timing`: collision-free moves, the whole trajectory
    checked densely, unsafe targets dropped); returns (timed, solutions, path, figures)."""
    q0 = system.home if q_start is None else np.asarray(q_start, dtype=float)
    if safety is None:
        timed = time_solutions(system, targets, solutions, settings, order=order, path=path,
                               progress=progress, q_start=q0)  # fmt: skip
        return timed, solutions, path, {}

    def time_fn(sols: list[Solution], pth: PathResult | None, mover: MoveFn) -> Timed | None:
        return time_solutions(system, targets, sols, settings, order=order, path=pth,
                              progress=progress, move=mover, q_start=q0)  # fmt: skip

    meta = targets.meta.get("strokes") if targets.kind == "path" else None
    strokes = [list(s) for s in meta] if isinstance(meta, (list, tuple)) else None
    res = safe_timing(safety, solutions, path, targets.points, time_fn, ruckig_move, q0,
                      strokes=strokes)  # fmt: skip
    return res.timed, res.solutions, res.path, res.figures
