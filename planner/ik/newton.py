"""Minimum-norm Gauss-Newton on the spot residual: closes the last gap to machine precision.

Used after a nominal analytic seed on a calibrated arm (flange 1-2 mm off the nominal DH)
and after IPOPT (whose constraint tolerance is ~1e-9). The step ``dq = -pinv(J) r`` on the
3-vector ``r = spot - target`` moves the joints as little as possible (the residual has rank
2 without a target normal; the pseudo-inverse handles that).
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import casadi as ca
import numpy as np

from planner.beam.graph import beam_function, system_params
from planner.model.kinematics import RobotKinematics
from planner.model.mirror import Surface
from planner.model.system import System
from planner.model.transforms import Array


@lru_cache(maxsize=16)
def residual_function(
    kinematics: tuple[RobotKinematics, ...], surfaces: tuple[Surface, ...]
) -> ca.Function:
    """Named ``beam_newton``: (q, params, target, normal) -> (residual 3, d residual/dq 3xnq)."""
    beam = beam_function(kinematics, surfaces)
    args = {name: ca.SX.sym(name, beam.sparsity_in(name)) for name in beam.name_in()}
    residual = beam.call(args)["residual"]
    outputs = {"residual": residual, "jacobian": ca.jacobian(residual, args["q"])}
    return ca.Function("beam_newton", args | outputs, list(args), list(outputs))


class NewtonResult(NamedTuple):
    q: Array
    error: float  # metres
    iterations: int


class Newton:
    """Gauss-Newton on one system; the CasADi function is built once per chain of models."""

    def __init__(self, system: System) -> None:
        self.system = system
        self.function = residual_function(system.kinematics, system.surfaces)
        self.params = system_params(system)

    def _eval(self, q: Array, target: Array, normal: Array) -> tuple[Array, Array]:
        out = self.function(q=q, **self.params, target=target, normal=normal)
        return np.asarray(out["residual"], dtype=float).ravel(), np.asarray(
            out["jacobian"], dtype=float
        )

    def polish(
        self,
        q: Array,
        target: Array,
        normal: Array | None,
        *,
        tol: float = 1e-14,
        max_iter: int = 10,
    ) -> NewtonResult:
        """Iterate until ``|residual| <= tol`` or no progress; never returns a worse q."""
        nrm = np.zeros(3) if normal is None else np.asarray(normal, dtype=float)
        target = np.asarray(target, dtype=float)
        best_q = np.asarray(q, dtype=float)
        r, J = self._eval(best_q, target, nrm)
        best_err = float(np.linalg.norm(r))
        it = 0
        while best_err > tol and it < max_iter:
            it += 1
            dq = np.linalg.lstsq(J, -r, rcond=1e-10)[0]
            q_new = best_q + dq
            r, J = self._eval(q_new, target, nrm)
            err = float(np.linalg.norm(r))
            if not np.isfinite(err) or err >= best_err:
                break
            best_q, best_err = q_new, err
        return NewtonResult(best_q, best_err, it)
