"""The beam IK as one IPOPT NLP, built once per chain of robot models and reused.

Decision variables: the stacked joints q of all N robots (bounds = joint limits, passed per
call). Parameters (never baked in): target (3), target normal (3, zeros = none), spot-plane
basis (3x3: plane normal m, in-plane axes e1, e2), previous q, cos of the maximum incidence
(-2 = off), centre weight, and the system geometry of :func:`planner.beam.graph.system_params`.

Constraints (SPEC section 3):
    e1.(spot - target) = e2.(spot - target) = 0   spot on target (spot = ray ∩ plane ⊥ m)
    -n_i.v_i >= MIN_FRONT                          front face of every mirror
    t_i >= MIN_AHEAD                               every mirror ahead
    roi_half_i -+ uv_i >= 0                        hit inside each ROI
    s >= MIN_AHEAD                                 target ahead of the last mirror
    -v.n_target - cos_max >= 0                     incidence limit (only with a normal)
Objective: |q - q_prev|^2 + w_centre * sum |uv_i|^2 (metres^2; the paper's centring term).
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any, NamedTuple

import casadi as ca
import numpy as np

from planner.beam.graph import beam_chain, system_params
from planner.ik.evaluate import MIN_AHEAD, MIN_FRONT
from planner.model.kinematics import RobotKinematics
from planner.model.system import System
from planner.model.transforms import Array

INACTIVE_COS = -2.0


class NLPResult(NamedTuple):
    q: Array
    success: bool
    status: str  # IPOPT return status
    iterations: int


def _parameter_layout(N: int, nq: int) -> list[tuple[str, tuple[int, int]]]:
    return [
        ("target", (3, 1)),
        ("normal", (3, 1)),
        ("plane", (3, 3)),
        ("q_prev", (nq, 1)),
        ("cos_max", (1, 1)),
        ("w_centre", (1, 1)),
        ("world_T_laser", (4, 4)),
        ("world_T_base", (4, 4 * N)),
        ("flange_T_mirror", (4, 4 * N)),
        ("roi_half", (2, N)),
    ]


@lru_cache(maxsize=8)
def build_solver(
    kinematics: tuple[RobotKinematics, ...], max_iter: int = 200, tol: float = 1e-10
) -> tuple[ca.Function, Array, Array]:
    """The ``beam_ik`` nlpsol (IPOPT, expanded, silent) for a chain of robot models, with
    its constraint bounds (lbg, ubg)."""
    N = len(kinematics)
    nq = sum(k.nq for k in kinematics)
    q = ca.SX.sym("q", nq)
    P = {name: ca.SX.sym(name, *shape) for name, shape in _parameter_layout(N, nq)}
    bases = [P["world_T_base"][:, 4 * i : 4 * i + 4] for i in range(N)]
    mounts = [P["flange_T_mirror"][:, 4 * i : 4 * i + 4] for i in range(N)]
    hits, uvs, dirs, fronts, aheads, _ = beam_chain(
        q, P["world_T_laser"], bases, mounts, kinematics
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
        lbg += [MIN_FRONT, MIN_AHEAD, 0.0, 0.0, 0.0, 0.0]
        ubg += [ca.inf] * 6
    along = ca.dot(v, target - p)
    g += [along, -ca.dot(v, P["normal"]) - P["cos_max"]]
    lbg += [MIN_AHEAD, 0.0]
    ubg += [ca.inf, ca.inf]
    dq = q - P["q_prev"]
    f = ca.dot(dq, dq) + P["w_centre"] * sum(ca.dot(uv, uv) for uv in uvs)
    p_all = ca.vertcat(*[ca.vec(P[name]) for name, _ in _parameter_layout(N, nq)])
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
    return ca.nlpsol("beam_ik", "ipopt", nlp, opts), np.array(lbg), np.array(ubg)


def plane_basis(m: Array) -> Array:
    """3x3 [m, e1, e2]: unit plane normal and two in-plane unit axes."""
    m = np.asarray(m, dtype=float) / np.linalg.norm(m)
    a = np.array([1.0, 0.0, 0.0]) if abs(m[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(m, a)
    e1 /= np.linalg.norm(e1)
    return np.column_stack([m, e1, np.cross(m, e1)])


class BeamNLP:
    """The NLP bound to one system; geometry is a parameter, so ``with_params`` systems of the
    same robot models reuse the same solver."""

    def __init__(
        self, system: System, *, max_iter: int = 200, centre_weight: float = 100.0
    ) -> None:
        self.system = system
        kins = tuple(r.kinematics for r in system.robots)
        self.solver, self.lbg, self.ubg = build_solver(kins, max_iter)
        self.geometry = [np.asarray(x, dtype=float) for x in system_params(system).values()]
        self.centre_weight = centre_weight

    def solve(
        self,
        q0: Array,
        target: Array,
        normal: Array | None,
        q_prev: Array,
        plane_normal: Array,
        max_incidence: float | None = None,
    ) -> NLPResult:
        """Solve from ``q0``. ``plane_normal``: the target normal, or (no normal) the expected
        outgoing beam direction; the spot plane only fixes how the residual is measured."""
        m = normal if normal is not None else plane_normal
        cos_max = INACTIVE_COS
        if normal is not None and max_incidence is not None:
            cos_max = float(np.cos(max_incidence))
        values = [
            np.asarray(target, dtype=float),
            np.zeros(3) if normal is None else np.asarray(normal, dtype=float),
            plane_basis(m),
            np.asarray(q_prev, dtype=float),
            np.array([cos_max]),
            np.array([self.centre_weight]),
            *self.geometry,
        ]
        p = np.concatenate([np.asarray(x).ravel(order="F") for x in values])
        out = self.solver(
            x0=q0, p=p, lbx=self.system.lower, ubx=self.system.upper, lbg=self.lbg, ubg=self.ubg
        )
        st = self.solver.stats()
        return NLPResult(
            np.asarray(out["x"], dtype=float).ravel(),
            bool(st["success"]),
            str(st["return_status"]),
            int(st.get("iter_count", 0)),
        )
