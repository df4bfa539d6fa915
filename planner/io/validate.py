"""Tell what a beamrelay file is and validate it fully (``beamrelay validate``)."""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel

from planner.io.scenario import load_scenario, system_from_scenario, targets_from_scenario
from schemas.yamlio import SCENARIO_KIND, read_tagged


def validate_file(path: str | Path) -> tuple[str, BaseModel]:
    """Detect and fully validate a file; returns ``(kind, model)``.

    A scenario is loaded with its includes applied and its robots (kinematics, limits, home),
    camera and targets resolved, the ``truth`` system too; every other kind is validated as
    :func:`schemas.yamlio.read_tagged` describes. Raises :class:`~planner.errors.InputError`
    (or its Scenario/Dataset subclasses) naming file, line and key.
    """
    kind, model = read_tagged(path)
    if model is not None:
        return kind, model
    scn = load_scenario(path)
    system = system_from_scenario(scn)
    targets_from_scenario(scn, system)
    if scn.truth_system is not None:
        system_from_scenario(scn, truth=True)
    return SCENARIO_KIND, scn.model
