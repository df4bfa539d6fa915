"""Batch planning: a scenario's targets -> the plan.json document.

Point and grid targets are solved one by one with :class:`planner.ik.BeamIK`, each seeded by
the previous solution (smooth sequences); paths go to :func:`planner.path.solve.plan_path`. The
``trajectory`` field comes from :mod:`planner.path.timing` (:func:`time_solutions`): Ruckig
rest-to-rest moves through the solved points (visit order optimised unless the scenario says
``order: given``), or each marked stroke of a path swept at the scenario's spot speed with
sky-writing (:mod:`planner.path.marking`), dense at ``rate``, with the laser gate's
``laser_on`` intervals. A failed target is a status; it never stops the others.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from planner.beam.trace import trace_beam
from planner.ik import BeamIK, IKOptions, Solution
from planner.io.plan_file import plan_json as plan_json  # re-exported
from planner.io.plan_file import write_plan as write_plan
from planner.model.status import Reason, Status
from planner.model.system import System, Targets
from planner.model.transforms import Array

if TYPE_CHECKING:
    from planner.model.scene import SceneModel
    from planner.model.settings import TrajectorySettings
    from planner.path.solve import PathResult
    from planner.path.timing import MoveFn, Trajectory, VisitReport
    from planner.safety.model import Safety
    from planner.verify.spot import Mask

PLAN_SCHEMA = "beamrelay.plan/1"
Progress = Callable[[int], None]


def plan_points(
    system: System,
    targets: Targets,
    options: IKOptions | None = None,
    q_start: Array | None = None,
    progress: Progress | None = None,
    scene: SceneModel | None = None,
    safety: Safety | None = None,
) -> list[Solution]:
    """Solve every target in order; each solve starts from the last solved configuration
    (``q_start``, default home, at first). ``progress(k)`` is called after target k. With a
    ``scene``, beams that cross it are re-solved or fail as ``occluded``
    (:func:`planner.safety.occlusion.check_points`). With ``safety`` rules every solution
    passes them, or the target fails with their reason (:class:`planner.ik.BeamIK`).
    Targets with a ``surface_tolerance`` are solved on the surface they land on
    (:func:`plan_landed_points` gives those targets)."""
    return plan_landed_points(system, targets, options, q_start, progress, scene, safety)[1]


def plan_landed_points(
    system: System,
    targets: Targets,
    options: IKOptions | None = None,
    q_start: Array | None = None,
    progress: Progress | None = None,
    scene: SceneModel | None = None,
    safety: Safety | None = None,
) -> tuple[Targets, list[Solution]]:
    """:func:`plan_points` and the targets it solved: those with a ``surface_tolerance``
    moved onto the scene surface their beam lands on
    (:func:`planner.safety.landing.land_on_surfaces`) before the occlusion check."""
    ik = BeamIK(system, options, safety)
    q_prev = system.home if q_start is None else np.asarray(q_start, dtype=float)
    out = []
    for k in range(len(targets)):
        sol = ik.solve(targets.points[k], targets.normal(k), q_prev)
        if sol.q is not None:
            q_prev = sol.q
        out.append(sol)
        if progress is not None:
            progress(k)
    scene = None if scene is None or scene.empty else scene
    if targets.surface_tolerance > 0 and (scene is not None or targets.cloud is not None):
        from planner.safety.landing import land_on_surfaces

        targets, out = land_on_surfaces(ik, scene, targets, out)
    if scene is not None:
        from planner.safety.occlusion import check_points

        out = check_points(ik, scene, targets, out)
    return targets, out


def solve_path(
    system: System,
    targets: Targets,
    options: IKOptions,
    q_start: Array | None = None,
    scene: SceneModel | None = None,
    safety: Safety | None = None,
) -> tuple[list[Solution], PathResult]:
    """A continuous sweep through :func:`planner.path.solve.plan_path`: per-sample solutions (a
    sample in a gap is ``failed`` with the gap's reason and evidence) and the path result.
    With a ``scene``, samples whose beam crosses it become ``occluded`` gaps
    (:func:`planner.safety.occlusion.check_path`); with ``safety`` rules, samples that
    break them become gaps with their reason (:func:`~planner.safety.occlusion.check_path_safety`).
    A path with a ``surface_tolerance`` is swept on the surface it lands on
    (:func:`solve_landed_path` gives those samples)."""
    return solve_landed_path(system, targets, options, q_start, scene, safety)[1:]


def solve_landed_path(
    system: System,
    targets: Targets,
    options: IKOptions,
    q_start: Array | None = None,
    scene: SceneModel | None = None,
    safety: Safety | None = None,
) -> tuple[Targets, list[Solution], PathResult]:
    """:func:`solve_path` and the samples it swept: a path with a ``surface_tolerance`` (in
    the camera frame) is swept once, moved onto the scene surface its beam lands on
    (:func:`planner.safety.landing.land_path`), and swept again there, before the
    occlusion check."""
    from planner.path.solve import PathOptions

    inc = 90.0 if options.max_incidence is None else float(np.degrees(options.max_incidence))
    opts = PathOptions(tolerance=options.tolerance, max_iter=options.max_iter,
                       max_incidence_deg=inc)  # fmt: skip
    out, res = _sweep(system, targets, opts, q_start, safety)
    if scene is not None and not scene.empty and targets.surface_tolerance > 0:
        from planner.safety.landing import land_path

        moved = land_path(scene, targets, out)
        if moved is not None:
            targets, found = moved
            out, res = _sweep(system, targets, opts, q_start, safety)
            out = [dataclasses.replace(sol, evidence={**sol.evidence, "surface": found[k].to_json()})
                   if k in found and sol.ok else sol for k, sol in enumerate(out)]  # fmt: skip
    if scene is not None and not scene.empty:
        from planner.safety.occlusion import check_path

        out, res = check_path(system, scene, out, res)
    if safety is not None:
        from planner.safety.occlusion import check_path_safety

        out, res = check_path_safety(system, safety, out, res)
    return targets, out, res


def _sweep(
    system: System, targets: Targets, opts: Any, q_start: Array | None, safety: Safety | None
) -> tuple[list[Solution], PathResult]:
    """:func:`planner.path.solve.plan_path` as per-sample solutions (see :func:`solve_path`)."""
    from planner.path.solve import plan_path

    t0 = time.perf_counter()
    res = plan_path(system, targets, q_start, opts, safety)
    per_sample = (time.perf_counter() - t0) / max(len(targets), 1)
    gap_of = {k: g for g in res.gaps for k in range(g.k0, g.k1)}
    out = []
    for k in range(len(targets)):
        if res.ok[k]:
            ev = trace_beam(system, res.q[k], targets.points[k], targets.normal(k))
            out.append(Solution.solved(res.q[k], ev, per_sample, 0, "path"))
        else:
            gap = gap_of.get(k)
            reason = Reason.UNREACHABLE if gap is None else gap.reason
            evidence: dict[str, object] = {"detail": gap.detail if gap is not None else ""}
            out.append(Solution.failed(reason, per_sample, 0, "path", evidence))
    return out, res


def plan_path_targets(
    system: System,
    targets: Targets,
    options: IKOptions,
    q_start: Array | None = None,
    scene: SceneModel | None = None,
    safety: Safety | None = None,
) -> list[Solution]:
    """A continuous sweep through :func:`planner.path.solve.plan_path`, as per-sample solutions."""
    return solve_path(system, targets, options, q_start, scene, safety)[0]


def solution_json(system: System, k: int, sol: Solution) -> dict[str, Any]:
    """One ``solutions[]`` entry of plan.json (world frame, SI)."""
    reason = None if sol.reason is None else str(sol.reason)
    d: dict[str, Any] = {"target": k, "status": str(sol.status), "reason": reason}
    if sol.q is not None and sol.hits is not None and sol.uv is not None and sol.spot is not None:
        d["q"] = {n: q.tolist() for n, q in system.split_q(sol.q).items()}
        d["spot"] = sol.spot.tolist()
        d["error"] = float(sol.error)
        d["incidence"] = float(sol.incidence)
        d["hits"] = [
            {"robot": r.name, "p": sol.hits[i].tolist(), "uv": sol.uv[i].tolist()}
            for i, r in enumerate(system.robots)
        ]
    if "surface" in sol.evidence:  # a camera-frame target landed on its surface
        d["surface"] = sol.evidence["surface"]
    d["solve_time"] = float(sol.solve_time)
    d["iterations"] = int(sol.iterations)
    return d


def plan_metrics(solutions: list[Solution], duration: float | None) -> dict[str, Any]:
    """``metrics`` of plan.json: medians over solved targets (None when none solved); the
    same computation ``beamrelay check`` repeats on the written plan."""
    from planner.verify.metrics import summary_metrics

    ok = [s for s in solutions if s.ok]
    return summary_metrics([float(s.error) for s in ok], [float(s.solve_time) for s in ok],
                           [s.reason for s in solutions if not s.ok], len(solutions), duration)  # fmt: skip


def verify_solutions(
    system: System, scenario: dict[str, Any], targets: Targets, solutions: list[Solution]
) -> list[Solution]:
    """Re-verify every solved target with the checks ``beamrelay check`` runs (spot error,
    incidence, mirrors, joint limits, same bounds: :mod:`planner.verify.tolerances`) on the
    resolved ``scenario``; a solution they reject becomes ``failed`` with the check's
    reason and message as evidence. Nothing is re-solved."""
    from dataclasses import replace

    from planner.verify.check import target_findings

    ok = [k for k, s in enumerate(solutions) if s.ok]
    if not ok:
        return solutions
    doc = {"scenario": scenario, "targets": [_target_json(targets, k) for k in ok],
           "solutions": [solution_json(system, k, solutions[k]) for k in ok]}  # fmt: skip
    out = list(solutions)
    for f in reversed(target_findings(doc)):  # the first finding of a target wins
        if f.target is None:
            continue
        evidence = {"check": f.message, "value": f.value, "bound": f.bound}
        out[f.target] = replace(out[f.target], status=Status.FAILED,
                                reason=Reason(f.reason or Reason.SOLVER_FAILED),
                                q=None, spot=None, hits=None, uv=None, error=float("inf"),
                                evidence=evidence)  # fmt: skip
    return out


def _target_json(targets: Targets, k: int) -> dict[str, Any]:
    n = targets.normal(k)
    return {"id": k, "p": targets.points[k].tolist(), "n": None if n is None else n.tolist()}


def plan_document(
    system: System,
    targets: Targets,
    solutions: list[Solution],
    scenario: dict[str, Any],
    trajectory: dict[str, Any] | None = None,
    extra: dict[str, float] | None = None,
    *,
    trajectory_requested: bool | None = None,
    verify: bool = True,
) -> dict[str, Any]:
    """The whole plan.json dict; ``extra`` figures go in ``metrics.extra``.

    ``trajectory_requested`` (default: a trajectory is given) is written to the plan: with
    it true, ``beamrelay check`` requires a trajectory whenever a target is solved. With
    ``verify`` the solutions are first re-verified by :func:`verify_solutions` (needs a
    resolved ``scenario`` with ``system``)."""
    if verify and "system" in scenario:
        solutions = verify_solutions(system, scenario, targets, solutions)
    duration = None
    if trajectory is not None and trajectory.get("t"):
        duration = float(trajectory["t"][-1])
    metrics = plan_metrics(solutions, duration)
    metrics["extra"] |= extra or {}
    requested = trajectory is not None if trajectory_requested is None else trajectory_requested
    doc = {
        "schema": PLAN_SCHEMA,
        "scenario": scenario,
        "robots": list(system.robot_names),
        "joint_names": {r.name: list(r.joint_names) for r in system.robots},
        "targets": [_target_json(targets, k) for k in range(len(targets))],
        "solutions": [solution_json(system, k, s) for k, s in enumerate(solutions)],
        "trajectory": trajectory,
        "trajectory_requested": bool(requested),
        "metrics": metrics,
    }
    power = ((scenario.get("system") or {}).get("laser") or {}).get("power")
    if power is not None and "targets" in scenario:
        from planner.verify.marking import exposure

        metrics["exposure"] = exposure(doc, float(power))
    return doc


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
    from planner.path.timing import points_trajectory

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
    from planner.model.polyline import arc_length
    from planner.path.marking import mark_runs, marking_trajectory

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
    from planner.path.solve import jacobian_condition

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
    from planner.verify.spot import segment_mask

    return segment_mask(traj.t, [s._asdict() for s in traj.segments], kind)


def spot_rays(system: System, Q: Array) -> tuple[Array, Array]:
    """Last ray (origin, unit direction), each M x 3 in the world frame, of configurations
    ``Q`` (M x nq) through the planner's beam function."""
    from planner.beam.graph import beam_function, system_params

    N = system.n_robots
    f = beam_function(tuple(r.kinematics for r in system.robots)).map(len(Q))
    zeros = np.zeros((3, len(Q)))
    out = f(q=Q.T, **system_params(system), target=zeros, normal=zeros)
    hits, dirs = np.asarray(out["hits"]), np.asarray(out["dirs"])
    return hits[:, N - 1 :: N].T, dirs[:, N :: N + 1].T


def path_deviation(system: System, targets: Targets, traj: Trajectory) -> float:
    """Largest distance (m) of the spot from the target polyline over the ``path`` segments
    (the spot is where the ray meets the nearest sample's plane)."""
    from planner.verify.trajectory import spot_deviation

    mask = _mask(traj, "path")
    if not mask.any():
        return 0.0
    p, v = spot_rays(system, traj.q[mask])
    dev = spot_deviation(p, v, targets.points, targets.normals, bool(targets.closed))
    return float(dev.max())


def ik_options(solver: Any, optimal: bool = False) -> IKOptions:
    """IKOptions from a scenario's ``solver`` section (pydantic model or None)."""
    if solver is None:
        return IKOptions(optimal=optimal)
    return IKOptions(
        tolerance=float(solver.tolerance),
        max_iter=int(solver.max_iter),
        max_incidence=float(np.radians(solver.max_incidence_deg)),
        optimal=optimal,
    )


class PlanOutcome(NamedTuple):
    """Everything :func:`run_scenario` made: the plan.json dict and the objects behind it."""

    doc: dict[str, Any]
    system: System
    targets: Targets
    timed: Timed | None
    path: PathResult | None
    solutions: list[Solution]


def time_safely(
    system: System, targets: Targets, solutions: list[Solution], settings: TrajectorySettings, *,
    safety: Safety | None, order: str, path: PathResult | None, progress: Progress | None,
    q_start: Array | None = None,
) -> tuple[Timed | None, list[Solution], PathResult | None, dict[str, float]]:  # fmt: skip
    """:func:`time_solutions` (from ``q_start``, default home) under the ``safety`` rules
    (:func:`planner.safety.timing.safe_timing`: collision-free moves, the whole trajectory
    checked densely, unsafe targets dropped); returns (timed, solutions, path, figures)."""
    q0 = system.home if q_start is None else np.asarray(q_start, dtype=float)
    if safety is None:
        timed = time_solutions(system, targets, solutions, settings, order=order, path=path,
                               progress=progress, q_start=q0)  # fmt: skip
        return timed, solutions, path, {}
    from planner.path.timing import ruckig_move
    from planner.safety.timing import safe_timing

    def time_fn(sols: list[Solution], pth: PathResult | None, mover: MoveFn) -> Timed | None:
        return time_solutions(system, targets, sols, settings, order=order, path=pth,
                              progress=progress, move=mover, q_start=q0)  # fmt: skip

    meta = targets.meta.get("strokes") if targets.kind == "path" else None
    strokes = [list(s) for s in meta] if isinstance(meta, (list, tuple)) else None
    res = safe_timing(safety, solutions, path, targets.points, time_fn, ruckig_move, q0,
                      strokes=strokes)  # fmt: skip
    return res.timed, res.solutions, res.path, res.figures


def run_scenario(
    scenario_path: Any, *, optimal: bool = False, progress: bool = True, scene: bool = True,
    safety: bool = True,
) -> PlanOutcome:  # fmt: skip
    """Load, plan, time and assemble plan.json for a scenario file (rich progress bars);
    ``scene=False`` skips the occlusion check against the scenario's ``scene:``,
    ``safety=False`` the safety rules (collisions, keep-out, clearance)."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeRemainingColumn

    from planner.io.resolved import resolved_scenario_dict
    from planner.io.scenario import (
        load_scenario,
        scene_model,
        system_from_scenario,
        targets_from_scenario,
        trajectory_settings,
    )

    loaded = load_scenario(scenario_path)
    scn = loaded.model
    resolved = resolved_scenario_dict(loaded)
    system = system_from_scenario(loaded)
    targets = targets_from_scenario(loaded, system)
    if scn.targets.frame == "camera" and targets.kind in ("points", "path"):  # seen on a surface
        from planner.safety.landing import surface_tolerance

        tol = surface_tolerance(float(scn.safety.spot_uncertainty))
        targets = dataclasses.replace(targets, surface_tolerance=tol)
    model = scene_model(loaded) if scene else None
    from planner.safety.model import Safety

    guard = Safety.from_scenario(loaded, system) if safety else None
    options = ik_options(scn.solver, optimal)
    settings = trajectory_settings(loaded)
    order_key = settings.order or scn.targets.order
    order = "given" if order_key == "given" else "optimal"
    columns = ("[progress.description]{task.description}", BarColumn(), MofNCompleteColumn(),
               TimeRemainingColumn())  # fmt: skip
    path = None
    with Progress(*columns, disable=not progress, transient=True) as bar:
        if targets.kind == "path":
            task = bar.add_task("path NLP", total=None)
            targets, solutions, path = solve_landed_path(system, targets, options, scene=model,
                                                         safety=guard)  # fmt: skip
            bar.update(task, total=1, completed=1)
        else:
            task = bar.add_task("solving targets", total=len(targets))
            targets, solutions = plan_landed_points(
                system, targets, options, scene=model, safety=guard,
                progress=lambda k: bar.update(task, completed=k + 1))  # fmt: skip
        solutions = verify_solutions(system, resolved, targets, solutions)
        n_ok = sum(s.ok for s in solutions)
        timing = bar.add_task("timing", total=n_ok if targets.kind != "path" else None)
        timed, solutions, path, safe_figures = time_safely(
            system, targets, solutions, settings, safety=guard, order=order, path=path,
            progress=lambda k: bar.update(timing, completed=k + 1))  # fmt: skip
    traj = None if timed is None else timed.trajectory.to_plan_dict(system)
    extra = None if timed is None else timed.figures | safe_figures
    doc = plan_document(system, targets, solutions, resolved, traj, extra,
                        trajectory_requested=True, verify=False)  # fmt: skip
    return PlanOutcome(doc, system, targets, timed, path, solutions)


def plan_scenario(
    scenario_path: Any, *, optimal: bool = False, progress: bool = True
) -> tuple[dict[str, Any], System, Targets]:
    """Load, plan and assemble plan.json for a scenario file (with a rich progress bar)."""
    out = run_scenario(scenario_path, optimal=optimal, progress=progress)
    return out.doc, out.system, out.targets
