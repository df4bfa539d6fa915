"""Batch planning: a scenario's targets -> the plan.json document.

Point and grid targets are solved one by one with :class:`planner.ik.BeamIK`, each seeded by
the previous solution (smooth sequences); paths go to :func:`planner.path.solve.plan_path`. The
``trajectory`` field comes from :mod:`planner.path.timing` (:func:`time_solutions`): Ruckig
rest-to-rest moves through the solved points (visit order optimised unless the scenario says
``order: given``), or each marked stroke of a path swept at the scenario's spot speed with
sky-writing (:mod:`planner.path.marking`), dense at ``rate``, with the laser gate's
``laser_on`` intervals. A failed target is a status; it never stops the others.
"""
# long module: batch planning's pipeline (solve, verify, time, build the plan) in one place, as the issue asked

from __future__ import annotations

import dataclasses
import functools
from dataclasses import replace
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from planner.ik import Solution
from planner.io.plan import Exposure, Hit, Metrics, Plan, PlanTargets, SurfaceLanding
from planner.io.plan import Solution as PlanSolution
from planner.io.plan import Trajectory as PlanTrajectory
from planner.io.plan_file import plan_json as plan_json  # re-exported
from planner.io.plan_file import write_plan as write_plan
from planner.model.polyline import arc_length
from planner.model.status import Reason, Status
from planner.model.system import System, Targets
from planner.model.transforms import Array
from planner.path.timing import points_trajectory, ruckig_move
from planner.scenario_planner import Progress as Progress  # re-exported
from planner.scenario_planner import ScenarioPlanner
from planner.scenario_planner import ik_options as ik_options
from planner.scenario_planner import plan_landed_points as plan_landed_points
from planner.scenario_planner import plan_path_targets as plan_path_targets
from planner.scenario_planner import plan_points as plan_points
from planner.scenario_planner import solve_landed_path as solve_landed_path
from planner.scenario_planner import solve_path as solve_path
from planner.verify.check import target_findings
from planner.verify.marking import exposure
from planner.verify.metrics import summary_metrics
from planner.verify.spot import segment_mask
from planner.verify.trajectory import spot_deviation

if TYPE_CHECKING:
    from planner.model.settings import TrajectorySettings
    from planner.path.solve import PathResult
    from planner.path.timing import MoveFn, Trajectory, VisitReport
    from planner.safety.model import Safety
    from planner.verify.spot import Mask


def plan_solution(system: System, k: int, sol: Solution) -> PlanSolution:
    """Target ``k``'s :class:`~planner.io.plan.Solution` (per robot name; world frame, SI)."""
    surface = sol.evidence.get("surface")  # a camera-frame target landed on its surface
    landing = None
    if isinstance(surface, dict):
        landing = SurfaceLanding(str(surface["object"]), np.asarray(surface["requested"], float),
                                 float(surface["offset_m"]))  # fmt: skip
    out = PlanSolution(k, Status(sol.status), None if sol.reason is None else Reason(sol.reason),
                       solve_time=float(sol.solve_time), iterations=int(sol.iterations),
                       surface=landing)  # fmt: skip
    if sol.q is None or sol.hits is None or sol.uv is None or sol.spot is None:
        return out
    hits = tuple(Hit(r.name, sol.hits[i], sol.uv[i]) for i, r in enumerate(system.robots))
    return dataclasses.replace(out, q=system.split_q(sol.q), spot=sol.spot,
                               error=float(sol.error), incidence=float(sol.incidence),
                               hits=hits)  # fmt: skip


def solution_json(system: System, k: int, sol: Solution) -> dict[str, Any]:
    """One ``solutions[]`` entry of plan.json (world frame, SI)."""
    return plan_solution(system, k, sol).to_document()


def plan_metrics(solutions: list[Solution], duration: float | None) -> dict[str, Any]:
    """``metrics`` of plan.json: medians over solved targets (None when none solved); the
    same computation ``beamrelay check`` repeats on the written plan."""

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

    ok = [k for k, s in enumerate(solutions) if s.ok]
    if not ok:
        return solutions
    doc = {"scenario": scenario, "targets": [_target_json(targets, k) for k in ok],
           "solutions": [solution_json(system, k, solutions[k]) for k in ok]}  # fmt: skip
    out = list(solutions)
    surfaces = {r.name: r.mirror.surface.spec for r in system.robots}  # the checker's faces
    for f in reversed(target_findings(doc, surfaces=surfaces)):  # a target's first finding wins
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
    """The whole plan.json dict of :func:`build_plan` (the ``trajectory`` mapping's tables
    kept as arrays when given as arrays)."""
    traj = None if trajectory is None else PlanTrajectory.from_document(trajectory)
    arrays = trajectory is not None and isinstance(trajectory.get("t"), np.ndarray)
    return build_plan(system, targets, solutions, scenario, traj, extra,
                      trajectory_requested=trajectory_requested,
                      verify=verify).to_document(arrays)  # fmt: skip


def build_plan(
    system: System,
    targets: Targets,
    solutions: list[Solution],
    scenario: dict[str, Any],
    trajectory: PlanTrajectory | None = None,
    extra: dict[str, float] | None = None,
    *,
    trajectory_requested: bool | None = None,
    verify: bool = True,
) -> Plan:
    """The :class:`~planner.io.plan.Plan` of solved targets; ``extra`` figures go in
    ``metrics.extra``.

    ``trajectory_requested`` (default: a trajectory is given) is kept in the plan: with
    it true, ``beamrelay check`` requires a trajectory whenever a target is solved. With
    ``verify`` the solutions are first re-verified by :func:`verify_solutions` (needs a
    resolved ``scenario`` with ``system``)."""
    if verify and "system" in scenario:
        solutions = verify_solutions(system, scenario, targets, solutions)
    duration = None
    if trajectory is not None and len(trajectory.t):
        duration = float(trajectory.t[-1])
    metrics = Metrics.from_document(plan_metrics(solutions, duration)).with_extra(**(extra or {}))
    requested = trajectory is not None if trajectory_requested is None else trajectory_requested
    n = targets.normals
    plan = Plan(
        scenario, tuple(system.robot_names),
        {r.name: tuple(r.joint_names) for r in system.robots},
        PlanTargets(np.arange(len(targets)), targets.points,
                    None if n is None or not np.isfinite(n).all(axis=1).any() else n),
        tuple(plan_solution(system, k, s) for k, s in enumerate(solutions)), metrics,
        trajectory, bool(requested),
    )  # fmt: skip
    power = ((scenario.get("system") or {}).get("laser") or {}).get("power")
    if power is not None and "targets" in scenario:
        e = exposure(plan.to_document(arrays=True), float(power)) or {}
        metrics = dataclasses.replace(metrics, exposure=Exposure(**e))
        plan = dataclasses.replace(plan, metrics=metrics)
    return plan


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

    return segment_mask(traj.t, [s._asdict() for s in traj.segments], kind)


def spot_rays(system: System, Q: Array) -> tuple[Array, Array]:
    """Last ray (origin, unit direction), each M x 3 in the world frame, of configurations
    ``Q`` (M x nq) through the planner's beam function."""
    from planner.beam.graph import beam_function, system_params

    N = system.n_robots
    f = beam_function(system.kinematics, system.surfaces).map(len(Q))
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


@dataclasses.dataclass(frozen=True)
class PlanOutcome:
    """Everything :func:`run_scenario` made: the :class:`~planner.io.plan.Plan` and the
    objects behind it."""

    plan: Plan
    system: System
    targets: Targets
    timed: Timed | None
    path: PathResult | None
    solutions: list[Solution]

    @functools.cached_property
    def doc(self) -> dict[str, Any]:
        """The plan.json document (its trajectory tables as arrays)."""
        return self.plan.to_document(arrays=True)


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
    from planner.safety.timing import safe_timing

    def time_fn(sols: list[Solution], pth: PathResult | None, mover: MoveFn) -> Timed | None:
        return time_solutions(system, targets, sols, settings, order=order, path=pth,
                              progress=progress, move=mover, q_start=q0)  # fmt: skip

    meta = targets.meta.get("strokes") if targets.kind == "path" else None
    strokes = [list(s) for s in meta] if isinstance(meta, (list, tuple)) else None
    res = safe_timing(safety, solutions, path, targets.points, time_fn, ruckig_move, q0,
                      strokes=strokes)  # fmt: skip
    return res.timed, res.solutions, res.path, res.figures


@dataclasses.dataclass(frozen=True)
class Pipeline:
    """The one planning pipeline, used by ``beamrelay plan`` and the API
    (:func:`run_scenario`) and by the node (:func:`planner.service.handler.make_plan_fn`):
    :meth:`solve` (the scenario's rules: IK, scene, safety; then every solution re-verified
    by the checker's rules, so a rejected one is never visited), then :meth:`time` (the
    solved targets timed under the safety rules)."""

    rules: ScenarioPlanner
    scenario: dict[str, Any]  # resolved; echoed in every plan and verified against

    def solve(self, targets: Targets, q_start: Array | None = None,
              progress: Progress | None = None) -> tuple[Targets, list[Solution], PathResult | None]:  # fmt: skip
        """(targets as planned, solutions, path) from ``q_start`` (stacked joints; default home)."""
        path = None
        if targets.kind == "path":
            targets, solutions, path = self.rules.path(targets, q_start)
        else:
            targets, solutions = self.rules.points(targets, q_start, progress=progress)
        if "system" in self.scenario:
            solutions = verify_solutions(self.rules.system, self.scenario, targets, solutions)
        return targets, solutions, path

    def time(self, targets: Targets, solutions: list[Solution], path: PathResult | None,
             settings: TrajectorySettings, *, q_start: Array | None = None, order: str = "given",
             progress: Progress | None = None,
             ) -> tuple[Timed | None, list[Solution], PathResult | None, dict[str, float]]:  # fmt: skip
        """:func:`time_safely` under the rules' safety: (timed, solutions, path, figures)."""
        return time_safely(self.rules.system, targets, solutions, settings,
                           safety=self.rules.safety, order=order, path=path, progress=progress,
                           q_start=q_start)  # fmt: skip


def run_scenario(
    scenario_path: Any, *, optimal: bool = False, progress: bool = True, scene: bool = True,
    safety: bool = True,
) -> PlanOutcome:  # fmt: skip
    """Load, plan, time and assemble plan.json for a scenario file (rich progress bars);
    ``scene=False`` skips the occlusion check against the scenario's ``scene:``,
    ``safety=False`` the safety rules (collisions, keep-out, clearance)."""
    from rich.progress import BarColumn, MofNCompleteColumn, TimeRemainingColumn
    from rich.progress import Progress as Bars

    from planner.io.resolved import resolved_scenario_dict
    from planner.io.scenario import load_scenario, targets_from_scenario, trajectory_settings

    loaded = load_scenario(scenario_path)
    scn = loaded.model
    resolved = resolved_scenario_dict(loaded)
    rules = ScenarioPlanner.from_scenario(loaded, optimal=optimal, scene=scene, safety=safety)
    pipeline, system = Pipeline(rules, resolved), rules.system
    targets = targets_from_scenario(loaded, system)
    if scn.targets.frame == "camera" and targets.kind in ("points", "path"):  # seen on a surface
        targets = dataclasses.replace(targets, surface_tolerance=rules.surface_tolerance)
    settings = trajectory_settings(loaded)
    order_key = settings.order or scn.targets.order
    order = "given" if order_key == "given" else "optimal"
    columns = ("[progress.description]{task.description}", BarColumn(), MofNCompleteColumn(),
               TimeRemainingColumn())  # fmt: skip
    with Bars(*columns, disable=not progress, transient=True) as bar:
        path_nlp = targets.kind == "path"
        task = bar.add_task("path NLP" if path_nlp else "solving targets",
                            total=None if path_nlp else len(targets))  # fmt: skip
        targets, solutions, path = pipeline.solve(
            targets, progress=lambda k: bar.update(task, completed=k + 1))  # fmt: skip
        if path_nlp:
            bar.update(task, total=1, completed=1)
        n_ok = sum(s.ok for s in solutions)
        timing = bar.add_task("timing", total=n_ok if targets.kind != "path" else None)
        timed, solutions, path, safe_figures = pipeline.time(
            targets, solutions, path, settings, order=order,
            progress=lambda k: bar.update(timing, completed=k + 1))  # fmt: skip
    traj = None if timed is None else timed.trajectory.to_plan(system)
    extra = None if timed is None else timed.figures | safe_figures
    plan = build_plan(system, targets, solutions, resolved, traj, extra,
                      trajectory_requested=True, verify=False)  # fmt: skip
    return PlanOutcome(plan, system, targets, timed, path, solutions)


def plan_scenario(
    scenario_path: Any, *, optimal: bool = False, progress: bool = True
) -> tuple[dict[str, Any], System, Targets]:
    """Load, plan and assemble plan.json for a scenario file (with a rich progress bar)."""
    out = run_scenario(scenario_path, optimal=optimal, progress=progress)
    return out.doc, out.system, out.targets
