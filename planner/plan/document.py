"""The plan.json document of solved targets: each solution as plan.json holds it
(:func:`plan_solution`), the summary metrics, every solution re-verified by the checks
``beamrelay check`` runs (:func:`verify_solutions`), and the whole
:class:`~planner.io.plan.Plan` (:func:`build_plan`). World frame, SI units.
"""

from __future__ import annotations

import dataclasses
from dataclasses import replace
from typing import Any

import numpy as np

from planner.ik import Solution
from planner.io.plan import Exposure, Hit, Metrics, Plan, PlanTargets, SurfaceLanding
from planner.io.plan import Solution as PlanSolution
from planner.io.plan import Trajectory as PlanTrajectory
from planner.model.status import Reason, Status
from planner.model.system import System, Targets
from planner.verify.check import target_findings
from planner.verify.marking import exposure
from planner.verify.metrics import summary_metrics


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
