"""beamrelay: relay a free-space laser beam with robot-held mirrors.

The curated API (imported lazily, so ``import planner`` and ``beamrelay --help`` stay fast):

- :func:`load` a scenario -> :class:`Setup` (system model + targets); :func:`solver` -> a
  per-target solver under the scenario's rules (safety, occlusion, bounds: what ``plan``
  applies); :func:`plan` a scenario -> plan.json dict;
  :func:`check_plan` re-verifies one; :func:`calibrate_handeye`, :func:`calibrate_beam`.
- Model types: :class:`System`, :class:`Robot`, :class:`Mirror` (its face a
  :class:`Surface`: flat, or e.g. a :class:`Sphere` built in code), :class:`Limits`,
  :class:`Targets`, :class:`BeamModel` (forward trace), :class:`IKOptions`,
  :class:`TrajectorySettings`; robot models by name: :func:`robot_model`,
  :func:`register_model`.
- Errors: :class:`InputError` (a user mistake, with where and why), :class:`BeamrelayError`.

Units are SI (metres, radians, seconds); points are in the world frame unless named otherwise.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

_EXPORTS = {
    "load": "planner.api",
    "Setup": "planner.api",
    "solver": "planner.api",
    "plan": "planner.api",
    "check_plan": "planner.api",
    "calibrate_handeye": "planner.api",
    "calibrate_beam": "planner.api",
    "load_scenario": "planner.io.scenario",
    "system_from_scenario": "planner.io.scenario",
    "BeamIK": "planner.ik",
    "IKOptions": "planner.ik",
    "BeamModel": "planner.beam.graph",
    "System": "planner.model.system",
    "Robot": "planner.model.system",
    "Mirror": "planner.model.system",
    "Surface": "planner.model.mirror",
    "Sphere": "planner.model.mirror_sphere",
    "Limits": "planner.model.system",
    "Targets": "planner.model.system",
    "robot_model": "planner.model.robots",
    "register_model": "planner.model.robots",
    "TrajectorySettings": "planner.model.settings",
    "InputError": "planner.errors",
    "BeamrelayError": "planner.errors",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'planner' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *__all__])
