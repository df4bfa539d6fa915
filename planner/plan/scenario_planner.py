"""One set of rules for every entry point: the scenario's planner.

:meth:`ScenarioPlanner.from_scenario` is the one constructor behind ``beamrelay plan``
(:func:`planner.plan.pipeline.run_scenario`), the planner node and the console that talks to it
(:func:`planner.service.handler.handler_from_scenario`) and the notebook API
(:func:`planner.api.solver`). It holds what the scenario says a plan must obey: the system,
the solver settings, the scene (occlusion), the safety rules (keep-out volumes, clearances,
arm collisions) and the surface tolerance of camera-frame targets, so a target that one entry
point fails as ``keep_out`` or ``occluded`` fails the same way through every other, and a
point no scenario file could hold (millimetres given as metres, behind the camera) is refused
alike.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from planner.beam.trace import trace_beam
from planner.errors import InputError
from planner.ik import BeamIK, IKOptions, Solution
from planner.model.scene import SceneModel
from planner.model.status import Reason
from planner.model.system import System, Targets
from planner.model.transforms import Array, transform_points
from planner.path.solve import PathOptions, plan_path
from planner.plan.gaps import check_path_safety
from planner.plan.landing import land_on_surfaces, land_path, surface_tolerance
from planner.plan.occlusion import check_path, check_points
from planner.safety.model import Safety
from schemas.bounds import check_coordinates
from schemas.common import FieldError

if TYPE_CHECKING:
    from planner.ik.closed_form import ClosedForm
    from planner.io.scenario import LoadedScenario
    from planner.path.result import PathResult

Progress = Callable[[int], None]


@dataclass(frozen=True)
class ScenarioPlanner:
    """A scenario's planning rules (see the module docstring)."""

    system: System
    options: IKOptions
    scene: SceneModel | None
    safety: Safety | None
    surface_tolerance: float
    """m: how far a camera-frame target may lie from the surface that carries it"""

    @classmethod
    def from_scenario(
        cls, loaded: LoadedScenario, *, system: System | None = None, optimal: bool = False,
        scene: bool = True, safety: bool = True,
    ) -> ScenarioPlanner:  # fmt: skip
        """The planner of a loaded scenario (``system``: its already built model, if any);
        ``scene=False`` / ``safety=False`` leave out the occlusion check / the safety rules
        (``beamrelay plan --no-scene`` style studies only)."""
        from planner.io.scenario import scene_model, system_from_scenario

        model = loaded.model
        system = system_from_scenario(loaded) if system is None else system
        return cls(
            system=system,
            options=ik_options(model.solver, optimal),
            scene=scene_model(loaded) if scene else None,
            safety=Safety.from_scenario(loaded, system) if safety else None,
            surface_tolerance=surface_tolerance(float(model.safety.spot_uncertainty)),
        )

    @property
    def ik(self) -> BeamIK:
        """The per-target beam IK under the safety rules (no occlusion: see :meth:`solve`)."""
        return BeamIK(self.system, self.options, self.safety)

    def points(
        self, targets: Targets, q_start: Array | None = None, progress: Any = None
    ) -> tuple[Targets, list[Solution]]:
        """Point targets solved in order (:func:`plan_landed_points`):
        the targets (camera-frame ones landed) and their solutions."""
        return plan_landed_points(self.system, targets, self.options, q_start, progress,
                                  self.scene, self.safety)  # fmt: skip

    def path(
        self, targets: Targets, q_start: Array | None = None
    ) -> tuple[Targets, list[Solution], PathResult]:
        """A path swept (:func:`solve_landed_path`)."""
        return solve_landed_path(self.system, targets, self.options, q_start, self.scene,
                                 self.safety)  # fmt: skip

    def targets(self, points: Any, normals: Any = None, frame: str = "world",
                q: Any = None) -> Targets:  # fmt: skip
        """Point targets (K x 3, m) in ``frame`` as the planner takes them: checked as a
        scenario file's are (InputError naming ``target``: beyond 20 m, behind the camera),
        camera-frame ones mapped through the calibrated camera pose (at joints ``q`` for an
        eye-in-hand camera) and allowed :attr:`surface_tolerance` from their surface."""

        p = np.asarray(points, dtype=float).reshape(-1, 3)
        n = None if normals is None else np.asarray(normals, dtype=float).reshape(-1, 3)
        if not np.all(np.isfinite(p)):
            raise InputError(f"{p.tolist()} is not finite", "target")
        if frame not in ("world", "camera"):
            raise InputError(f"frame must be world or camera, got {frame!r}", "frame")
        try:
            check_coordinates(p.tolist(), (), frame)
        except FieldError as exc:
            raise InputError(exc.reason, "target") from None
        if frame == "world":
            return Targets(p, n)
        if self.system.camera is None:
            raise InputError("frame is camera but the scenario has no camera", "frame")
        T = self.system.world_T_camera(q)
        return Targets(transform_points(T, p), None if n is None else n @ T[:3, :3].T,
                       surface_tolerance=self.surface_tolerance)  # fmt: skip

    def solve(self, target: Any, normal: Any = None, q_prev: Any = None, *,
              frame: str = "world") -> Solution:  # fmt: skip
        """One target (m, in ``frame``) under every rule of the scenario, as ``beamrelay
        plan`` and the node plan it: IK with the safety rules, a camera-frame target landed
        on its surface, the occlusion check. A Solution (status ok, or the failure's reason);
        InputError for a point no scenario could hold."""
        targets = self.targets(target, None if normal is None else [normal], frame, q_prev)
        q0 = None if q_prev is None else np.asarray(q_prev, dtype=float)
        return self.points(targets, q0)[1][0]


# --- the pipeline every entry point shares ---------------------------------------------
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
    (:func:`planner.plan.occlusion.check_points`). With ``safety`` rules every solution
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
    (:func:`planner.plan.landing.land_on_surfaces`) before the occlusion check."""
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
        targets, out = land_on_surfaces(ik, scene, targets, out)
    if scene is not None:
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
    (:func:`planner.plan.occlusion.check_path`); with ``safety`` rules, samples that
    break them become gaps with their reason (:func:`~planner.plan.gaps.check_path_safety`).
    A path with a ``surface_tolerance`` is swept on the surface it lands on
    (:func:`solve_landed_path` gives those samples: call it for a camera-frame path, whose
    solutions belong to the moved samples)."""
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
    (:func:`planner.plan.landing.land_path`), and swept again there (warm-started from
    the first sweep's joints: each landed sample lies on its first beam), before the
    occlusion check."""
    opts = path_options(options)
    out, res = sweep_solutions(system, targets, opts, q_start, safety)
    if scene is not None and not scene.empty and targets.surface_tolerance > 0:
        moved = land_path(scene, targets, out)
        if moved is not None:
            targets, found = moved
            out, res = sweep_solutions(system, targets, opts, q_start, safety, res.q)
            out = [_landed(sol, found[k]) if k in found and sol.ok else sol
                   for k, sol in enumerate(out)]  # fmt: skip
    if scene is not None and not scene.empty:
        out, res = check_path(system, scene, out, res)
    if safety is not None:
        out, res = check_path_safety(system, safety, out, res)
    return targets, out, res


def path_options(options: IKOptions) -> PathOptions:
    """The path NLP's options of the IK's (tolerance, iterations, incidence limit)."""
    inc = 90.0 if options.max_incidence is None else float(np.degrees(options.max_incidence))
    return PathOptions(tolerance=options.tolerance, max_iter=options.max_iter,
                       max_incidence_deg=inc)  # fmt: skip


def _landed(sol: Solution, landing: Any) -> Solution:
    """``sol`` carrying its sample's :class:`~planner.plan.landing.Landing`."""
    return dataclasses.replace(sol, evidence={**sol.evidence, "surface": landing.to_json()})


def sweep_solutions(
    system: System, targets: Targets, opts: PathOptions, q_start: Array | None,
    safety: Safety | None, q_warm: Array | None = None,
) -> tuple[list[Solution], PathResult]:  # fmt: skip
    """:func:`planner.path.solve.plan_path` as per-sample solutions (see :func:`solve_path`;
    ``q_warm``: its warm start, the joints of a nearby solved path)."""
    t0 = time.perf_counter()
    res = plan_path(system, targets, q_start, opts, safety, q_warm,
                    seeder=path_seeder(system, safety))  # fmt: skip
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


def path_seeder(system: System, safety: Safety | None = None) -> ClosedForm | None:
    """What seeds a path sample from scratch (:class:`planner.path.warm.Seeder`): the IK's
    closed-form family search, its members filtered by the ``safety`` rules as the per-target
    IK's are; None when an arm has no analytic seed model."""
    return BeamIK(system, None, safety).closed_form


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
