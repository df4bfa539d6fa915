"""The paper's IK formulation (Eq. 7) as a comparison: Levenberg-Marquardt from a start
configuration, in two readings.

The paper solves each target by least squares from a start configuration with MATLAB's
Levenberg-Marquardt. Its text is not at hand here; what is assumed, and why:

- ``LM, spot only`` (``centre_weight=None``): the residual is the product's beam residual
  alone (:func:`planner.ik.newton.residual_function`: ``spot - target``, 3, world m). This
  leaves out the paper's h(.) term; it is kept as the lower reading.
- ``LM, spot + mirror centre (paper Eq. 7)`` (``centre_weight=w``): the residual stacks
  ``spot(q) - target`` (3) and ``w (h_i(q) - c_i(q))`` (3 per mirror, world m), where
  ``h_i(q) = p + t v`` is the beam's hit on mirror i (SPEC section 3, the paper's Eqs. 1-2)
  and ``c_i(q)`` the mirror's centre (``world_T_base @ fk(q) @ flange_T_mirror``, its
  origin), both functions of the joints. Assumed: (a) Eq. 7's h(.) term is this distance of
  the hit from the mirror centre, squared and added to the squared spot error; (b) the
  unknowns are the stacked joints q (Eq. 5's parametrisation is not described in SPEC; the
  joints are what SPEC's beam model is a function of, and what the product's IK returns);
  (c) the weight ``w`` = :data:`CENTRE_WEIGHT` = 1 (both terms in metres). With one mirror
  the stacked residual has 3 + 2 independent rows for 6 joints, so where a joint
  configuration puts the spot on the target with the hit at the mirror centre (what the
  product's closed form solves) the least-squares optimum is exactly there, for any w > 0:
  w changes the path of the iterations, not the answer.

Both use ``scipy.optimize.least_squares`` (``method="lm"``, MINPACK) with the analytic
Jacobian of the CasADi residual. MINPACK's LM needs at least as many residuals as unknowns:
a shorter residual is padded with zeros (rows of zero Jacobian; they change neither the
cost nor the steps, and LM's damping handles the rank-deficient Jacobian, as MATLAB's LM
does). LM knows no joint limits: each joint of its result is moved by whole turns to the
equivalent angle (the same pose of a revolute joint) nearest the start configuration, and,
when that is outside the limits, by one more turn toward them, as the product's analytic
IK picks its solution (:func:`wrap_joints`). A result counts as solved when the spot error
is within the tolerance, every joint within its limits and the beam a valid reflection
chain (the same validity rule as the product's IK).
"""

from __future__ import annotations

import time
from functools import lru_cache
from typing import NamedTuple

import casadi as ca
import numpy as np

from planner.model.kinematics import RobotKinematics
from planner.model.mirror import Surface
from planner.model.system import System
from planner.model.transforms import Array

MAX_EVALUATIONS = 200  # residual evaluations per target at most
CENTRE_WEIGHT = 1.0  # weight of h - c against spot - target (both m); see the docstring, (c)


class LMResult(NamedTuple):
    """One target: joints (rad), spot error (m), solved, wall time (s), function calls,
    largest distance of a hit from its mirror's centre (m)."""

    q: Array
    error: float
    solved: bool
    time: float
    evaluations: int
    centre_offset: float


@lru_cache(maxsize=16)
def eq7_residual(
    kinematics: tuple[RobotKinematics, ...], surfaces: tuple[Surface, ...]
) -> ca.Function:
    """Named ``lm_eq7``: (q, geometry, target, normal, weight) -> residual (3 + 3N: spot -
    target, then weight * (h_i - c_i) per mirror, world m) and its Jacobian w.r.t. q."""
    from planner.beam.graph import beam_chain, beam_function, chain_symbols

    sym = chain_symbols(kinematics)
    target, normal, w = ca.SX.sym("target", 3), ca.SX.sym("normal", 3), ca.SX.sym("weight")
    args = {**sym._asdict(), "target": target, "normal": normal}
    spot_residual = beam_function(kinematics, surfaces).call(args)["residual"]
    hits, _, _, _, _, mirrors = beam_chain(sym.q, sym.world_T_laser, sym.bases, sym.mounts,
                                           kinematics, surfaces)  # fmt: skip
    off = [h - M[:3, 3] for h, M in zip(hits, mirrors, strict=True)]
    r = ca.vertcat(spot_residual, w * ca.vertcat(*off))
    inputs = {**args, "weight": w}
    outputs = {"residual": r, "jacobian": ca.jacobian(r, sym.q)}
    return ca.Function("lm_eq7", inputs | outputs, list(inputs), list(outputs))


def wrap_joints(q: Array, q_ref: Array, lower: Array, upper: Array) -> Array:
    """``q`` (rad) with each joint moved by whole turns to the equivalent nearest ``q_ref``,
    or one turn further when that leaves [lower, upper] and the next one does not."""
    w = q_ref + (q - q_ref + np.pi) % (2 * np.pi) - np.pi
    for turn in (2 * np.pi, -2 * np.pi):
        alt = w + turn
        fix = ((w < lower) | (w > upper)) & (alt >= lower) & (alt <= upper)
        w = np.where(fix, alt, w)
    return w


class LMIK:
    """Eq. 7 IK on one system: LM from a start configuration (see the module docstring);
    ``centre_weight`` None: the spot term only."""

    def __init__(
        self, system: System, tolerance: float = 1e-9, centre_weight: float | None = None
    ) -> None:
        from planner.beam.graph import BeamModel, system_params
        from planner.ik.newton import residual_function

        self.system = system
        self.tolerance = tolerance
        self.centre_weight = centre_weight
        chain = system.kinematics, system.surfaces
        self.function = residual_function(*chain) if centre_weight is None else eq7_residual(*chain)
        self.params = system_params(system)
        self.model = BeamModel(system)

    def _eval(self, q: Array, target: Array) -> tuple[Array, Array]:
        extra = {} if self.centre_weight is None else {"weight": self.centre_weight}
        out = self.function(q=q, **self.params, target=target, normal=np.zeros(3), **extra)
        return np.asarray(out["residual"], float).ravel(), np.asarray(out["jacobian"], float)

    def solve(self, target: Array, q_start: Array) -> LMResult:
        """Solve ``target`` (world, m, no normal) from stacked joints ``q_start`` (rad)."""
        from scipy.optimize import least_squares

        target = np.asarray(target, dtype=float)
        q0 = np.asarray(q_start, dtype=float)
        pad = max(0, len(q0) - len(self._eval(q0, target)[0]))
        t0 = time.perf_counter()

        def fun(q: Array) -> Array:
            return np.concatenate([self._eval(q, target)[0], np.zeros(pad)])

        def jac(q: Array) -> Array:
            return np.vstack([self._eval(q, target)[1], np.zeros((pad, len(q)))])

        res = least_squares(fun, q0, jac=jac, method="lm", xtol=1e-15, ftol=1e-15,
                            gtol=1e-15, max_nfev=MAX_EVALUATIONS)  # fmt: skip
        dt = time.perf_counter() - t0
        q = wrap_joints(res.x, q0, self.system.lower, self.system.upper)
        tr = self.model.trace(q, target)
        within = bool(np.all(q >= self.system.lower) and np.all(q <= self.system.upper))
        solved = tr.valid and within and tr.error <= self.tolerance
        offset = float(np.max(np.linalg.norm(tr.uv, axis=1)))
        return LMResult(q, float(tr.error), solved, dt, int(res.nfev), offset)
