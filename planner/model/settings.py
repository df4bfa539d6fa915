"""Typed trajectory settings: how a plan's joint trajectory is timed and sampled."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from planner.errors import InputError
from schemas import defaults

ORDERS = ("optimal", "optimized", "given")


@dataclass(frozen=True)
class TrajectorySettings:
    """The scenario's ``trajectory`` section, built once and passed to timing.

    ``spot_speed``: speed of the spot along a path (m/s); ``dwell``: rest on each point or
    grid target (s); ``rate``: sample rate of the dense trajectory (Hz); ``path_tolerance``:
    largest distance of the spot from the path while the laser is on (m); ``order``: visit
    order of point/grid targets (``optimal``/``optimized``/``given``; None: the targets'
    ``order`` decides). Defaults are :mod:`schemas.defaults`'.
    """

    spot_speed: float = defaults.SPOT_SPEED_MPS
    dwell: float = defaults.DWELL_S
    rate: float = defaults.SERVO_RATE_HZ
    path_tolerance: float = defaults.PATH_TOLERANCE_M
    order: str | None = None

    def __post_init__(self) -> None:
        for name, unit in (("spot_speed", "m/s"), ("rate", "Hz"), ("path_tolerance", "m")):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise InputError(f"must be a positive number of {unit}, got {value!r}", name)
        if not (math.isfinite(self.dwell) and self.dwell >= 0):
            raise InputError(f"must be a non-negative number of s, got {self.dwell!r}", "dwell")
        if self.order is not None and self.order not in ORDERS:
            raise InputError(f"must be one of {', '.join(ORDERS)}, got {self.order!r}", "order")

    @property
    def period(self) -> float:
        """Sample period 1 / ``rate`` (s)."""
        return 1.0 / self.rate

    @classmethod
    def from_mapping(cls, section: Mapping[str, Any] | None) -> TrajectorySettings:
        """From a ``trajectory`` section as a plain mapping (keys left out or None take the
        defaults; keys this class does not know are ignored)."""
        known = {f.name for f in dataclasses.fields(cls)}
        given = {k: v for k, v in (section or {}).items() if k in known and v is not None}
        floats = {k: float(v) for k, v in given.items() if k != "order"}
        return cls(**floats, order=given.get("order"))
