"""The one planning pipeline: a scenario's targets -> the plan.json document.

Point and grid targets are solved one by one with :class:`planner.ik.BeamIK`, each seeded by
the previous solution (smooth sequences); paths go to :func:`planner.path.solve.plan_path`
(:mod:`planner.plan.scenario_planner`: the scenario's rules, the scene's occlusion and the
landing of camera-frame targets on their surface). Every solution is re-verified by the
checker's rules (:mod:`planner.plan.document`), then the solved targets are timed under the
safety rules (:mod:`planner.plan.timed`). A failed target is a status; it never stops the
others.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import TYPE_CHECKING, Any

from planner.io.plan import Plan
from planner.model.system import System, Targets
from planner.model.transforms import Array
from planner.plan.document import build_plan, verify_solutions
from planner.plan.scenario_planner import Progress, ScenarioPlanner
from planner.plan.timed import Timed, time_safely

if TYPE_CHECKING:
    from planner.ik import Solution
    from planner.model.settings import TrajectorySettings
    from planner.path.result import PathResult


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
