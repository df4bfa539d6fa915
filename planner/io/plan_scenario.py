"""Typed reads of a plan's resolved scenario (plan.json ``scenario``: every default filled
in, every pose a ``{matrix: 4x4}``): each section a reader needs, validated by its model of
:mod:`schemas.scenario` when first read and kept. The document itself stays as it is, so
a plan writes back the text it was read from; the target list (10^5 points for as many
targets) is never validated here.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from typing import Any, TypeVar

from pydantic import BaseModel

from planner.model.transforms import Array
from schemas.common import Pose
from schemas.located import validate
from schemas.scenario import KeepOutObject, Laser, Safety, TrajectorySettings

M = TypeVar("M", bound=BaseModel)


@dataclass(frozen=True)
class PlannedScenario:
    """The resolved scenario ``doc`` a plan was made with. A section that does not validate
    is an :class:`~planner.errors.InputError` naming its key path (``scenario.system.laser.gate``)."""

    doc: Mapping[str, Any]

    @property
    def name(self) -> str | None:
        name = self.doc.get("name")
        return None if name is None else str(name)

    def _read(self, *path: str) -> Any:
        """The section at ``path`` (None when absent)."""
        data: Any = self.doc
        for key in path:
            data = data.get(key) if isinstance(data, Mapping) else None
        return data

    def _section(self, model: type[M], *path: str) -> M:
        """The section at ``path`` validated as ``model`` (an absent one: an error)."""
        return validate(model, self._read(*path), prefix=("scenario", *path))

    @cached_property
    def laser(self) -> Laser | None:
        """``system.laser``: its pose, power, gate, aim, limits and beam radius (None in a
        partial document without one)."""
        path = ("system", "laser")
        return None if self._read(*path) is None else self._section(Laser, *path)

    @property
    def world_T_camera(self) -> Array | None:
        """The fixed camera's pose (4x4, world; ``system.camera.world_T_camera``), None
        without a camera or for one on a flange (its pose depends on the joints)."""
        path = ("system", "camera", "world_T_camera")
        return None if self._read(*path) is None else self._section(Pose, *path).matrix()

    @cached_property
    def safety(self) -> Safety:
        """``safety``: clearance, return cone, spot uncertainty (defaults when absent)."""
        return Safety() if self._read("safety") is None else self._section(Safety, "safety")

    @cached_property
    def trajectory(self) -> TrajectorySettings:
        """``trajectory``: spot speed, dwell, rate, path tolerance, order."""
        if self._read("trajectory") is None:
            return TrajectorySettings()
        return self._section(TrajectorySettings, "trajectory")

    @cached_property
    def keep_out(self) -> tuple[KeepOutObject, ...]:
        """The keep-out volumes, each with its pose and ``attached_to``."""
        rows = self.doc.get("keep_out") or []
        return tuple(validate(KeepOutObject, o, prefix=("scenario", "keep_out", i))
                     for i, o in enumerate(rows))  # fmt: skip
