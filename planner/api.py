"""The few calls a notebook or script needs, over the planner's internal modules.

Points are in the world frame (metres), joints in radians, stacked in robot order.

    >>> import planner
    >>> sol = planner.solver("scenarios/paper_n1.yaml").solve([-0.49, -0.52, 0.0])
    >>> sol.ok, sol.error          # (True, ~1e-13 m)

Everything here reads a scenario file exactly as the ``beamrelay`` command line does (solver
settings, includes, scene), so results match ``beamrelay plan``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from planner.verify.check import check_plan as _check

if TYPE_CHECKING:
    from planner.io.scenario import LoadedScenario
    from planner.model.scene import SceneModel
    from planner.model.system import System, Targets
    from planner.plan.scenario_planner import ScenarioPlanner
    from planner.verify.context import CheckResult


@dataclass(frozen=True)
class Setup:
    """A loaded scenario: the validated file, the system model and its targets."""

    scenario: LoadedScenario
    system: System
    targets: Targets

    @property
    def scene(self) -> SceneModel | None:
        """The scenario's scene objects for occlusion checks (None without a scene)."""
        from planner.io.scenario import scene_model

        return scene_model(self.scenario)


def load(path: str | Path) -> Setup:
    """Load and validate a scenario YAML (includes applied): system model and targets.

    Args:
        path: the scenario file.

    Returns:
        A :class:`Setup`. Raises :class:`planner.errors.ScenarioError` (file:line key: reason).
    """
    from planner.io.scenario import load_scenario, system_from_scenario, targets_from_scenario

    loaded = load_scenario(path)
    system = system_from_scenario(loaded)
    return Setup(loaded, system, targets_from_scenario(loaded, system))


def solver(scenario: str | Path | Setup, *, optimal: bool = False) -> ScenarioPlanner:
    """A per-target solver under every rule of the scenario, the one ``beamrelay plan`` and
    the planner node use (:class:`planner.plan.scenario_planner.ScenarioPlanner`): solver
    settings, safety rules (a target in a keep-out volume fails as ``keep_out``), the
    scene's occlusion (a target under the board fails as ``occluded``), the bounds of a
    scenario file (a target in millimetres is an InputError).

    Args:
        scenario: a scenario file or a :class:`Setup`.
        optimal: also run the IPOPT refinement (mirror-centred hits), as ``plan --optimal``.

    Returns:
        ``.solve(target, normal=None, q_prev=None, frame="world")`` returns a Solution;
        ``.system`` is the model, ``.ik`` the bare IK under the safety rules.
    """
    from planner.plan.scenario_planner import ScenarioPlanner

    setup = scenario if isinstance(scenario, Setup) else load(scenario)
    return ScenarioPlanner.from_scenario(setup.scenario, system=setup.system, optimal=optimal)


def plan(path: str | Path, *, optimal: bool = False, progress: bool = False) -> dict[str, Any]:
    """Plan a scenario file (IK, paths, timing) exactly as ``beamrelay plan``.

    Args:
        path: the scenario file.
        optimal: IPOPT refinement of every target.
        progress: show rich progress bars.

    Returns:
        The plan.json document as a dict; its trajectory's dense tables (``t``, ``q``,
        ``qd``, ``qdd``) are numpy arrays (write it with :func:`planner.io.plan_file.write_plan`).
    """
    from planner.plan.pipeline import run_scenario

    return run_scenario(path, optimal=optimal, progress=progress).doc


def check_plan(plan_doc: dict[str, Any], base_dir: str | Path = ".") -> list[CheckResult]:
    """Re-verify a plan document with the independent numpy checker (no CasADi).

    Args:
        plan_doc: a plan.json dict (as returned by :func:`plan` or read from a file).
        base_dir: where relative mesh paths of the plan's scenario are resolved.

    Returns:
        One result per check; each has ``ok`` and its findings.
    """

    return _check(plan_doc, Path(base_dir))


def calibrate_handeye(dataset: str | Path, scenario: str | Path | Setup, **options: Any) -> Any:
    """Hand-eye calibration of a dataset file against a scenario's robot models.

    Args:
        dataset: a ``beamrelay.handeye/1`` JSON file.
        scenario: the scenario (robot models, nominal values).
        **options: ``loss`` (none, huber, cauchy), ``loss_scale`` (m).

    Returns:
        :class:`planner.calibration.handeye.HandEyeResult`.
    """
    from planner.calibration.dataset import load_handeye
    from planner.calibration.handeye import calibrate_handeye as _calibrate

    setup = scenario if isinstance(scenario, Setup) else load(scenario)
    return _calibrate(load_handeye(dataset), setup.system, **options)


def calibrate_beam(dataset: str | Path, scenario: str | Path | Setup, **options: Any) -> Any:
    """Laser line + mirror plane calibration of a beam dataset file.

    Args:
        dataset: a ``beamrelay.beam/1`` JSON file.
        scenario: the scenario (robot models, nominal values, camera pose for camera spots).
        **options: ``loss``, ``loss_scale`` (m), ``starts``, ``seed``, ``mirror_centre``.

    Returns:
        :class:`planner.calibration.beam.BeamResult`.
    """
    from planner.calibration.beam import calibrate_beam as _calibrate
    from planner.calibration.dataset import load_beam

    setup = scenario if isinstance(scenario, Setup) else load(scenario)
    return _calibrate(load_beam(dataset, setup.system), setup.system, **options)
