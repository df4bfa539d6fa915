"""Batch planning: a scenario's targets -> the plan.json document of SPEC section 5.

Point and grid targets are solved one by one with :class:`planner.ik.BeamIK`, each seeded by
the previous solution (smooth sequences); paths go to :func:`planner.path.plan_path`, and the
``trajectory`` field comes from :mod:`planner.timing` when that module is available
(``trajectory: null`` otherwise). A failed target is a status; it never stops the others.
"""

from __future__ import annotations

import importlib
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from planner.ik import REASONS, BeamIK, IKOptions, Solution
from planner.ik.evaluate import evaluate
from planner.system import System, Targets
from planner.transforms import Array

PLAN_SCHEMA = "beamrelay.plan/1"
Progress = Callable[[int], None]


def plan_points(
    system: System,
    targets: Targets,
    options: IKOptions | None = None,
    q_start: Array | None = None,
    progress: Progress | None = None,
) -> list[Solution]:
    """Solve every target in order; each solve starts from the last solved configuration
    (``q_start``, default home, at first). ``progress(k)`` is called after target k."""
    ik = BeamIK(system, options)
    q_prev = system.home if q_start is None else np.asarray(q_start, dtype=float)
    out = []
    for k in range(len(targets)):
        sol = ik.solve(targets.points[k], targets.normal(k), q_prev)
        if sol.q is not None:
            q_prev = sol.q
        out.append(sol)
        if progress is not None:
            progress(k)
    return out


def plan_path_targets(
    system: System, targets: Targets, options: IKOptions, q_start: Array | None = None
) -> list[Solution]:
    """A continuous sweep through :func:`planner.path.plan_path`, as per-sample solutions."""
    from planner.path import plan_path

    t0 = time.perf_counter()
    res = plan_path(
        system,
        targets,
        q_start,
        {"tolerance": options.tolerance, "max_iter": options.max_iter},
    )
    per_sample = (time.perf_counter() - t0) / max(len(targets), 1)
    gap_of = {k: g for g in res.gaps for k in range(g.k0, g.k1)}
    out = []
    for k in range(len(targets)):
        if res.ok[k]:
            ev = evaluate(system, res.q[k], targets.points[k], targets.normal(k))
            out.append(Solution("ok", None, res.q[k], ev.spot, ev.error, ev.hits, ev.uv,
                                per_sample, 0, "path", ev.incidence))  # fmt: skip
        else:
            gap = gap_of.get(k)
            reason = gap.reason if gap is not None and gap.reason in REASONS else "unreachable"
            evidence: dict[str, object] = {"detail": gap.detail if gap is not None else ""}
            out.append(Solution("failed", reason, None, None, float("inf"), None, None,
                                per_sample, 0, "path", 0.0, evidence))  # fmt: skip
    return out


def solution_json(system: System, k: int, sol: Solution) -> dict[str, Any]:
    """One ``solutions[]`` entry of plan.json (world frame, SI)."""
    d: dict[str, Any] = {"target": k, "status": sol.status, "reason": sol.reason}
    if sol.q is not None and sol.hits is not None and sol.uv is not None and sol.spot is not None:
        d["q"] = {n: q.tolist() for n, q in system.split_q(sol.q).items()}
        d["spot"] = sol.spot.tolist()
        d["error"] = float(sol.error)
        d["incidence"] = float(sol.incidence)
        d["hits"] = [
            {"robot": r.name, "p": sol.hits[i].tolist(), "uv": sol.uv[i].tolist()}
            for i, r in enumerate(system.robots)
        ]
    d["solve_time"] = float(sol.solve_time)
    d["iterations"] = int(sol.iterations)
    return d


def plan_metrics(solutions: list[Solution], duration: float | None) -> dict[str, Any]:
    """``metrics`` of plan.json: medians over solved targets (None when none solved)."""
    ok = [s for s in solutions if s.ok]
    err = np.array([s.error for s in ok])
    dt = np.array([s.solve_time for s in ok])
    failures: dict[str, float] = {}
    for s in solutions:
        if not s.ok:
            key = f"failed_{s.reason}"
            failures[key] = failures.get(key, 0) + 1
    return {
        "n_targets": len(solutions),
        "n_ok": len(ok),
        "error_max": float(err.max()) if ok else None,
        "error_median": float(np.median(err)) if ok else None,
        "solve_time_median": float(np.median(dt)) if ok else None,
        "solve_time_p95": float(np.percentile(dt, 95)) if ok else None,
        "duration": duration,
        "extra": failures,
    }


def _target_json(targets: Targets, k: int) -> dict[str, Any]:
    n = targets.normal(k)
    return {"id": k, "p": targets.points[k].tolist(), "n": None if n is None else n.tolist()}


def plan_document(
    system: System,
    targets: Targets,
    solutions: list[Solution],
    scenario: dict[str, Any],
    trajectory: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The whole plan.json dict (SPEC section 5)."""
    duration = None
    if trajectory is not None and trajectory.get("t"):
        duration = float(trajectory["t"][-1])
    return {
        "schema": PLAN_SCHEMA,
        "scenario": scenario,
        "robots": list(system.robot_names),
        "joint_names": {r.name: list(r.joint_names) for r in system.robots},
        "targets": [_target_json(targets, k) for k in range(len(targets))],
        "solutions": [solution_json(system, k, s) for k, s in enumerate(solutions)],
        "trajectory": trajectory,
        "metrics": plan_metrics(solutions, duration),
    }


def trajectory_hook(
    system: System, targets: Targets, solutions: list[Solution], settings: dict[str, Any]
) -> dict[str, Any] | None:
    """``planner.timing.plan_trajectory(system, q_waypoints (K x nq), kind=, settings=)`` when
    the timing module exists, else None. Failed targets are skipped (not waypoints)."""
    try:
        timing = importlib.import_module("planner.timing")
    except ImportError:
        return None
    fn = getattr(timing, "plan_trajectory", None)
    solved = [s.q for s in solutions if s.q is not None]
    if fn is None or not solved:
        return None
    result: dict[str, Any] | None = fn(
        system, np.array(solved), kind=targets.kind, settings=settings
    )
    return result


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


def plan_scenario(
    scenario_path: Any, *, optimal: bool = False, progress: bool = True
) -> tuple[dict[str, Any], System, Targets]:
    """Load, plan and assemble plan.json for a scenario file (with a rich progress bar)."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeRemainingColumn

    from planner.scenario import (
        load_scenario,
        resolved_scenario_dict,
        system_from_scenario,
        targets_from_scenario,
    )

    loaded = load_scenario(scenario_path)
    scn = loaded.model
    system = system_from_scenario(loaded)
    targets = targets_from_scenario(loaded, system)
    options = ik_options(scn.solver, optimal)
    settings = scn.trajectory.model_dump() if scn.trajectory is not None else {}
    if targets.kind == "path":
        solutions = plan_path_targets(system, targets, options)
    else:
        columns = ("[progress.description]{task.description}", BarColumn(), MofNCompleteColumn(),
                   TimeRemainingColumn())  # fmt: skip
        with Progress(*columns, disable=not progress, transient=True) as bar:
            task = bar.add_task("solving targets", total=len(targets))
            solutions = plan_points(
                system, targets, options, progress=lambda k: bar.update(task, completed=k + 1)
            )
    trajectory = trajectory_hook(system, targets, solutions, settings)
    doc = plan_document(system, targets, solutions, resolved_scenario_dict(loaded), trajectory)
    return doc, system, targets
