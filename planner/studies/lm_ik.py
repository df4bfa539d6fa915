"""The paper's IK formulation (Eq. 7) as a comparison: Levenberg-Marquardt on the spot error.

The paper solves each target by least squares on the spot residual from a start
configuration with MATLAB's Levenberg-Marquardt. Here: ``scipy.optimize.least_squares``
(``method="lm"``, MINPACK) on the product's beam residual (:func:`planner.ik.newton.
residual_function`: ``spot - target``, 3, world m, and its Jacobian w.r.t. the stacked
joints). MINPACK's LM needs at least as many residuals as unknowns: the residual is padded
with zeros (rows of zero Jacobian; they change neither the cost nor the steps, and LM's
damping handles the rank-deficient Jacobian, as MATLAB's LM does). A result counts as solved when the spot error is within the
tolerance, every joint within its limits and the beam a valid reflection chain (the same
validity rule as the product's IK).
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

from planner.model.system import System
from planner.model.transforms import Array

MAX_EVALUATIONS = 200  # residual evaluations per target at most


class LMResult(NamedTuple):
    """One target: joints (rad), spot error (m), solved, wall time (s), function calls."""

    q: Array
    error: float
    solved: bool
    time: float
    evaluations: int


class LMIK:
    """Eq. 7 IK on one system: LM from a start configuration (see the module docstring)."""

    def __init__(self, system: System, tolerance: float = 1e-9) -> None:
        from planner.beam.graph import BeamModel, system_params
        from planner.ik.newton import residual_function

        self.system = system
        self.tolerance = tolerance
        self.function = residual_function(tuple(r.kinematics for r in system.robots))
        self.params = system_params(system)
        self.model = BeamModel(system)

    def _eval(self, q: Array, target: Array) -> tuple[Array, Array]:
        out = self.function(q=q, **self.params, target=target, normal=np.zeros(3))
        return np.asarray(out["residual"], float).ravel(), np.asarray(out["jacobian"], float)

    def solve(self, target: Array, q_start: Array) -> LMResult:
        """Solve ``target`` (world, m, no normal) from stacked joints ``q_start`` (rad)."""
        from scipy.optimize import least_squares

        target = np.asarray(target, dtype=float)
        q0 = np.asarray(q_start, dtype=float)
        pad = max(0, len(q0) - 3)
        t0 = time.perf_counter()

        def fun(q: Array) -> Array:
            return np.concatenate([self._eval(q, target)[0], np.zeros(pad)])

        def jac(q: Array) -> Array:
            return np.vstack([self._eval(q, target)[1], np.zeros((pad, len(q)))])

        res = least_squares(fun, q0, jac=jac, method="lm", xtol=1e-15, ftol=1e-15,
                            gtol=1e-15, max_nfev=MAX_EVALUATIONS)  # fmt: skip
        dt = time.perf_counter() - t0
        tr = self.model.trace(res.x, target)
        within = bool(np.all(res.x >= self.system.lower) and np.all(res.x <= self.system.upper))
        solved = tr.valid and within and tr.error <= self.tolerance
        return LMResult(res.x, float(tr.error), solved, dt, int(res.nfev))
