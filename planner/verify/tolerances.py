"""The acceptance thresholds a plan is judged by, shared by planning and ``beamrelay check``.

The planner calls a solution, a path sample or a trajectory ok with exactly these bounds, and
the independent checker enforces exactly these bounds, so the two cannot disagree. Bounds
that the scenario sets (spot error, incidence limit, path tolerance) are read from the
resolved scenario mapping by :meth:`Tolerances.from_scenario`; the numerical slack (what two
independent float computations, or an interior-point solver that relaxes its bounds by
1e-8 relative, legitimately differ by) is fixed here, once. Units SI: m, rad, s.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.model import validity
from schemas import defaults

JOINT_SLACK = 1e-7  # rad: a joint position may lie this far beyond its limit
INCIDENCE_SLACK = 1e-7  # rad: the incidence angle may exceed max_incidence_deg by this much
ROI_SLACK = 1e-9  # m: a mirror hit may lie this far outside the region of interest
TRACE_SLACK = 1e-9  # front cosine, m: the checker's slack on the other beam-chain thresholds
RATE_SLACK = 0.02  # fraction: finite-difference |qd|, |qdd|, |jerk| may exceed a limit by 2 %
DERIVATIVE_SLACK = 1e-3  # fraction of the limit: declared qd (qdd) vs differences of q (qd)
TIME_GRID_SLACK = 1e-6  # fraction of the period 1/rate: sample spacing off the grid
REPORT_SLACK = 1e-9  # m: a reported spot or error vs the recomputed one (or the tolerance)
METRIC_SLACK = 1e-9  # relative: a reported metric vs the one recomputed from the plan

DEFAULT_SPOT_TOLERANCE = defaults.SPOT_TOLERANCE_M  # m, ``solver.tolerance``
DEFAULT_MAX_INCIDENCE_DEG = defaults.MAX_INCIDENCE_DEG  # deg, ``solver.max_incidence_deg``
DEFAULT_PATH_TOLERANCE = defaults.PATH_TOLERANCE_M  # m, ``trajectory.path_tolerance``
DEFAULT_RATE = defaults.SERVO_RATE_HZ  # Hz, ``trajectory.rate``


@dataclass(frozen=True)
class Tolerances:
    """The scenario's bounds: ``spot`` (m) on a solved target's spot error,
    ``max_incidence`` (rad, None = no limit) on targets that carry a normal, ``path`` (m) on
    the spot's distance from the path (or its target) while on a path, dwelling or arriving,
    ``rate`` (Hz) of the dense trajectory."""

    spot: float = DEFAULT_SPOT_TOLERANCE
    max_incidence: float | None = float(np.radians(DEFAULT_MAX_INCIDENCE_DEG))
    path: float = DEFAULT_PATH_TOLERANCE
    rate: float = DEFAULT_RATE

    @classmethod
    def from_scenario(cls, scenario: Mapping[str, Any]) -> Tolerances:
        """From a resolved scenario mapping (missing sections take the defaults). Raises
        KeyError/TypeError/ValueError on malformed numbers (callers name the document)."""
        solver = scenario.get("solver") or {}
        traj = scenario.get("trajectory") or {}
        inc = solver.get("max_incidence_deg", DEFAULT_MAX_INCIDENCE_DEG)
        return cls(
            spot=float(solver.get("tolerance", DEFAULT_SPOT_TOLERANCE)),
            max_incidence=None if inc is None else float(np.radians(float(inc))),
            path=float(traj.get("path_tolerance", DEFAULT_PATH_TOLERANCE)),
            rate=float(traj.get("rate", DEFAULT_RATE)),
        )

    def spot_ok(self, error: float) -> bool:
        """Spot error (m) within ``solver.tolerance``."""
        return bool(error <= self.spot)

    def incidence_ok(self, incidence: float) -> bool:
        """Incidence (rad) within the limit plus :data:`INCIDENCE_SLACK`."""
        return self.max_incidence is None or bool(incidence <= self.max_incidence + INCIDENCE_SLACK)

    @property
    def min_cos_incidence(self) -> float:
        """Smallest accepted |v.n| (cosine of the largest accepted incidence, slack included)."""
        if self.max_incidence is None:
            return -np.inf
        return float(np.cos(min(self.max_incidence + INCIDENCE_SLACK, np.pi / 2)))

    def deviation_ok(self, deviation: float) -> bool:
        """Spot distance (m) from the path / target within ``trajectory.path_tolerance``."""
        return bool(deviation <= self.path)


def limit_violation(q: Any, lower: Any, upper: Any) -> float:
    """Largest amount (rad) by which any joint of ``q`` (..., n) lies outside [lower, upper]
    (negative: the smallest distance to a limit)."""
    q = np.asarray(q, dtype=float)
    return float(np.max(np.maximum(q - upper, np.asarray(lower) - q)))


def joints_ok(violation: float) -> bool:
    """A :func:`limit_violation` within :data:`JOINT_SLACK`."""
    return bool(violation <= JOINT_SLACK)


def roi_ok(margin: float) -> bool:
    """A hit's ROI margin (m, half-size minus |uv|, negative outside) inside by the beam-chain
    rule (:func:`planner.model.validity.roi_ok`) less :data:`ROI_SLACK`."""
    return bool(validity.roi_ok(margin, ROI_SLACK))
