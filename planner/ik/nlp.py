"""The beam IK as one IPOPT NLP, built once per chain of robot models and reused.

Decision variables: the stacked joints q of all N robots (bounds = joint limits, passed per
call). Parameters (never baked in), packed by name in :data:`PROBLEM_PARAMETERS` order then
the chain geometry (:class:`planner.beam.graph.ChainSymbols` fields but q, valued by
:func:`planner.beam.graph.system_params`): target (3), target normal (3, zeros = none),
spot-plane basis (3x3: plane normal m, in-plane axes e1, e2), previous q, cos of the
maximum incidence (-2 = off), centre weight.

Constraints (thresholds of :mod:`planner.model.validity`):
    e1.(spot - target) = e2.(spot - target) = 0   spot on target (spot = ray ∩ plane ⊥ m)
    -n_i.v_i >= MIN_FRONT                          front face of every mirror
    t_i >= MIN_AHEAD                               every mirror ahead
    roi_half_i -+ uv_i >= 0                        hit inside each ROI
    s >= MIN_AHEAD                                 target ahead of the last mirror
    -v.n_target - cos_max >= 0                     incidence limit (only with a normal)
    A q >= lb                                      clearance rows (``cuts`` > 0 only)
Objective: |q - q_prev|^2 + w_centre * sum |uv_i|^2 (metres^2; the paper's centring term).

The clearance rows are linearised safety distances (:mod:`planner.safety.linearize`): the
row matrix ``A`` (cuts x nq) is a parameter and the lower bounds come with the call, unused
rows zero with bound -inf, so one solver per chain and row count serves every target.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any, NamedTuple

import casadi as ca
import numpy as np

from planner.beam.graph import ChainSymbols, beam_chain, chain_symbols, system_params
from planner.model.kinematics import RobotKinematics
from planner.model.mirror import Surface
from planner.model.system import System
from planner.model.transforms import Array, plane_basis
from planner.model.validity import MIN_AHEAD, MIN_FRONT, MIN_ROI_MARGIN

INACTIVE_COS = -2.0
#: IPOPT iterations of a solve with clearance rows (warm-started next to its solution)
CUT_MAX_ITER = 60


class NLPResult(NamedTuple):
    q: Array
    success: bool
    status: str  # IPOPT return status
    iterations: int


def _problem_parameters(nq: int, cuts: int = 0) -> dict[str, ca.SX]:
    """The per-call parameter symbols of the NLP, by name (geometry comes on top)."""
    rows = {"cuts": ca.SX.sym("cuts", cuts, nq)} if cuts else {}
    return rows | {
        "target": ca.SX.sym("target", 3),
        "normal": ca.SX.sym("normal", 3),
        "plane": ca.SX.sym("plane", 3, 3),
        "q_prev": ca.SX.sym("q_prev", nq),
        "cos_max": ca.SX.sym("cos_max"),
        "w_centre": ca.SX.sym("w_centre"),
    }


GEOMETRY = tuple(name for name in ChainSymbols._fields if name != "q")


@lru_cache(maxsize=8)
def build_solver(
    kinematics: tuple[RobotKinematics, ...], surfaces: tuple[Surface, ...], max_iter: int = 200,
    tol: float = 1e-10, cuts: int = 0,
) -> tuple[ca.Function, Array, Array]:  # fmt: skip
    """The ``beam_ik`` nlpsol (IPOPT, expanded, silent) for a chain of robot models and their
    mirrors' surfaces, with its constraint bounds (lbg, ubg; ``cuts`` clearance rows last, bounds set per call)."""
    N = len(kinematics)
    sym = chain_symbols(kinematics)
    q = sym.q
    P = _problem_parameters(q.size1(), cuts) | {name: getattr(sym, name) for name in GEOMETRY}
    hits, uvs, dirs, fronts, aheads, _ = beam_chain(
        q, sym.world_T_laser, sym.bases, sym.mounts, kinematics, surfaces
    )
    p, v = hits[-1], dirs[-1]
    m, e1, e2 = P["plane"][:, 0], P["plane"][:, 1], P["plane"][:, 2]
    target = P["target"]
    s = ca.dot(m, target - p) / ca.dot(m, v)
    spot = p + s * v
    g = [ca.dot(e1, spot - target), ca.dot(e2, spot - target)]
    lbg, ubg = [0.0, 0.0], [0.0, 0.0]
    for i in range(N):
        roi = P["roi_half"][:, i]
        g += [fronts[i], aheads[i], roi - uvs[i], roi + uvs[i]]
        lbg += [MIN_FRONT, MIN_AHEAD, *([MIN_ROI_MARGIN] * 4)]
        ubg += [ca.inf] * 6
    along = ca.dot(v, target - p)
    g += [along, -ca.dot(v, P["normal"]) - P["cos_max"]]
    lbg += [MIN_AHEAD, 0.0]
    ubg += [ca.inf, ca.inf]
    if cuts:
        g += [ca.mtimes(P["cuts"], q)]
        lbg += [-ca.inf] * cuts
        ubg += [ca.inf] * cuts
    dq = q - P["q_prev"]
    f = ca.dot(dq, dq) + P["w_centre"] * sum(ca.dot(uv, uv) for uv in uvs)
    p_all = ca.vertcat(*[ca.vec(x) for x in P.values()])
    nlp = {"x": q, "p": p_all, "f": f, "g": ca.vertcat(*g)}
    opts: dict[str, Any] = {
        "expand": True,
        "print_time": False,
        "ipopt.print_level": 0,
        "ipopt.sb": "yes",
        "ipopt.max_iter": max_iter,
        "ipopt.tol": tol,
        "ipopt.constr_viol_tol": 1e-12,
        "ipopt.mu_init": 1e-5,
        "ipopt.warm_start_init_point": "yes",
    }
    name = f"beam_ik_cuts{cuts}" if cuts else "beam_ik"
    return ca.nlpsol(name, "ipopt", nlp, opts), np.array(lbg), np.array(ubg)


class BeamNLP:
    """The NLP bound to one system; geometry is a parameter, so ``with_params`` systems of the
    same robot models reuse the same solver."""

    def __init__(
        self, system: System, *, max_iter: int = 200, centre_weight: float = 100.0
    ) -> None:
        self.system = system
        self.kinematics, self.surfaces = system.kinematics, system.surfaces
        self.max_iter = max_iter
        self.solver, self.lbg, self.ubg = build_solver(self.kinematics, self.surfaces, max_iter)
        self.geometry = system_params(system)
        self.centre_weight = centre_weight

    def solve(
        self,
        q0: Array,
        target: Array,
        normal: Array | None,
        q_prev: Array,
        plane_normal: Array,
        max_incidence: float | None = None,
        cuts: tuple[Array, Array] | None = None,
    ) -> NLPResult:
        """Solve from ``q0``. ``plane_normal``: the target normal, or (no normal) the expected
        outgoing beam direction; the spot plane only fixes how the residual is measured.
        ``cuts``: clearance rows ``(A, lb)``, ``A q >= lb`` (A rows x nq, m/rad; lb m)."""
        m = normal if normal is not None else plane_normal
        cos_max = INACTIVE_COS
        if normal is not None and max_incidence is not None:
            cos_max = float(np.cos(max_incidence))
        values = {
            "target": np.asarray(target, dtype=float),
            "normal": np.zeros(3) if normal is None else np.asarray(normal, dtype=float),
            "plane": plane_basis(m),
            "q_prev": np.asarray(q_prev, dtype=float),
            "cos_max": np.array([cos_max]),
            "w_centre": np.array([self.centre_weight]),
        } | {name: self.geometry[name] for name in GEOMETRY}
        solver, lbg, ubg = self.solver, self.lbg, self.ubg
        if cuts is not None:
            A, lb = cuts
            solver, lbg, ubg = build_solver(self.kinematics, self.surfaces,
                                            min(self.max_iter, CUT_MAX_ITER), cuts=len(A))  # fmt: skip
            values = {"cuts": np.asarray(A, dtype=float)} | values
            lbg = np.concatenate([lbg[: len(lbg) - len(A)], lb])
        p = np.concatenate([np.asarray(x, dtype=float).ravel(order="F") for x in values.values()])
        out = solver(x0=q0, p=p, lbx=self.system.lower, ubx=self.system.upper, lbg=lbg, ubg=ubg)
        st = solver.stats()
        return NLPResult(
            np.asarray(out["x"], dtype=float).ravel(),
            bool(st["success"]),
            str(st["return_status"]),
            int(st.get("iter_count", 0)),
        )
