"""Per-target beam IK driver: closed form first, Newton to close calibration gaps, IPOPT for
the optimal step and as the multi-start fallback. Data in, :class:`Solution` out.

Under safety rules the IPOPT steps carry the clearance as constraints: a result that breaks
a distance rule is re-solved, warm-started, with the pairs within a margin of their
required distance as linearised rows (:mod:`planner.safety.linearize`), re-linearised at
each new iterate, a few rounds at most; every accepted result still passes every rule.

A failed target is a status with a machine-readable reason (plan.json ``reason``) and the numbers
that show it (``evidence``); it never raises.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from planner.beam.trace import BeamTrace, trace_beam
from planner.ik.closed_form import ClosedForm, seed_kinematics
from planner.ik.newton import Newton
from planner.ik.nlp import BeamNLP
from planner.ik.safe_members import MemberSafety
from planner.model.status import Reason, Status
from planner.model.system import System
from planner.model.transforms import Array
from planner.model.validity import ahead_ok, front_ok, roi_ok
from planner.safety.linearize import ClearanceRow, Linearizer, cut_matrix
from planner.safety.model import Safety, Violation

#: rules that are no distance (no clearance row can fix them)
APERTURE_CHECKS = ("laser_return", "camera_lens")

EXACT = 1e-12  # metres: what "machine precision" means for a spot error here
#: re-solves of an IPOPT result that breaks a distance rule, clearance rows per solve, and
#: solves with rows per target (bounds the cost of a target no configuration serves safely)
CLEARANCE_ROUNDS, CLEARANCE_ROWS, CLEARANCE_BUDGET = 4, 16, 6


@dataclass(frozen=True)
class IKOptions:
    """Solver settings. ``tolerance``: largest accepted spot error (m, scenario
    ``solver.tolerance``); ``max_incidence``: rad on targets with normals (None = off);
    ``centre_weight``: NLP weight of sum |uv|^2 (1/m^2); ``starts``: multi-start seeds."""

    tolerance: float = 1e-9
    optimal: bool = False
    max_iter: int = 200
    max_incidence: float | None = None
    centre_weight: float = 100.0
    starts: int = 6
    seed: int = 0


@dataclass(frozen=True)
class Solution:
    """One target's result. ``q`` stacked (robot order), None when failed; world frame."""

    status: Status
    reason: Reason | None
    q: Array | None
    spot: Array | None
    error: float  # metres (inf when nothing was traced)
    hits: Array | None  # (N, 3)
    uv: Array | None  # (N, 2)
    solve_time: float  # seconds
    iterations: int  # family members tried, or IPOPT iterations
    method: str
    incidence: float = 0.0
    evidence: dict[str, object] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.status == Status.OK

    @classmethod
    def solved(
        cls,
        q: Array,
        trace: BeamTrace,
        solve_time: float,
        iterations: int,
        method: str,
        evidence: dict[str, object] | None = None,
    ) -> Solution:
        """An ``ok`` solution at stacked joints ``q`` with the spot, hits and incidence of
        its ``trace``."""
        return cls(Status.OK, None, q, trace.spot, trace.error, trace.hits, trace.uv,
                   solve_time, iterations, method, trace.incidence, dict(evidence or {}))  # fmt: skip

    @classmethod
    def failed(
        cls,
        reason: Reason,
        solve_time: float,
        iterations: int,
        method: str,
        evidence: dict[str, object] | None = None,
    ) -> Solution:
        """A ``failed`` solution with its reason and the numbers that show it."""
        return cls(Status.FAILED, reason, None, None, float("inf"), None, None, solve_time,
                   iterations, method, 0.0, dict(evidence or {}))  # fmt: skip


def _limit_violation(system: System, q: Array) -> float:
    return float(max(np.max(q - system.upper), np.max(system.lower - q), 0.0))


class BeamIK:
    """Beam IK for one system. Heavy pieces (Newton function, IPOPT NLP) are built lazily,
    once, and reused for every target."""

    def __init__(
        self, system: System, options: IKOptions | None = None, safety: Safety | None = None
    ) -> None:
        self.system = system
        self.options = options or IKOptions()
        self.safety = safety
        self._cut_solves = CLEARANCE_BUDGET  # left for the current target
        has_seed = all(seed_kinematics(r.kinematics) is not None for r in system.robots)
        guard = None if safety is None else MemberSafety(safety)
        self.closed_form = ClosedForm(system, guard) if has_seed else None

    @cached_property
    def newton(self) -> Newton:
        return Newton(self.system)

    @cached_property
    def nlp(self) -> BeamNLP:
        o = self.options
        return BeamNLP(self.system, max_iter=o.max_iter, centre_weight=o.centre_weight)

    @cached_property
    def linearizer(self) -> Linearizer:
        assert self.safety is not None
        return Linearizer(self.safety)

    # --------------------------------------------------------------------------------------
    def accept(self, ev: BeamTrace, q: Array) -> bool:
        """Valid chain, error within tolerance, joints within limits, incidence within limit."""
        inc_ok = self.options.max_incidence is None or ev.incidence <= self.options.max_incidence
        return bool(
            ev.valid
            and ev.error <= self.options.tolerance
            and _limit_violation(self.system, q) <= 0.0
            and inc_ok
        )

    def classify(self, ev: BeamTrace, q: Array, status: str) -> tuple[Reason, dict[str, object]]:
        """Reason (docs/conventions.md section 5) of a rejected configuration, with its evidence."""
        evidence: dict[str, object] = {
            "error_m": ev.error,
            "ipopt_status": status,
            "front_min": float(ev.front.min()),
            "roi_min_mm": 1e3 * float(ev.roi.min()),
        }
        viol = _limit_violation(self.system, q)
        converged = status in ("Solve_Succeeded", "Solved_To_Acceptable_Level")
        if not np.all(np.isfinite(q)) or not np.isfinite(ev.error):
            return Reason.SOLVER_FAILED, evidence
        if not converged and status != "Infeasible_Problem_Detected":
            return Reason.SOLVER_FAILED, evidence  # the iterate says nothing about the target
        if viol > 0.0:
            return Reason.JOINT_LIMITS, {**evidence, "limit_violation_rad": viol}
        if not front_ok(ev.front).all() or not ahead_ok(ev.target_ahead):
            return Reason.BACK_FACE, {**evidence, "target_ahead_m": ev.target_ahead}
        if not roi_ok(ev.roi).all():
            return Reason.OUTSIDE_ROI, evidence
        if not ahead_ok(ev.ahead).all() or status == "Infeasible_Problem_Detected":
            return Reason.UNREACHABLE, evidence
        max_inc = self.options.max_incidence
        if max_inc is not None and ev.incidence > max_inc:
            return Reason.UNREACHABLE, {
                **evidence,
                "incidence_deg": float(np.degrees(ev.incidence)),
            }
        return Reason.SOLVER_FAILED, evidence

    def _nlp(
        self, q0: Array, target: Array, normal: Array | None, q_prev: Array,
        cuts: tuple[Array, Array] | None = None,
    ) -> tuple[Array, BeamTrace, str, int]:  # fmt: skip
        ev0 = trace_beam(self.system, q0, target, normal)
        m = target - ev0.hits[-1]
        if np.linalg.norm(m) < 1e-9:
            m = ev0.dirs[-1]
        res = self.nlp.solve(q0, target, normal, q_prev, m, self.options.max_incidence, cuts)
        q = res.q
        if np.all(np.isfinite(q)):
            q = self.newton.polish(q, target, normal).q
        return q, trace_beam(self.system, q, target, normal), res.status, res.iterations

    def _safe_nlp(
        self, q0: Array, target: Array, normal: Array | None, q_prev: Array
    ) -> tuple[Array, BeamTrace, str, int]:
        """:meth:`_nlp`, then, while its accepted result breaks a distance rule, the NLP
        again from that result with the near pairs' clearance rows (module docstring). A
        start that is itself a solution (the optimal step) gives its near pairs' rows to
        the first solve already."""
        if self.safety is None:
            return self._nlp(q0, target, normal, q_prev)
        rows: dict[tuple[str, int], ClearanceRow] = {}
        ev0 = trace_beam(self.system, q0, target, normal)
        if self.accept(ev0, q0) and self._cut_solves > 0:
            rows = {r.key: r for r in self.linearizer.rows(q0, self._polyline(ev0))}
        first = cut_matrix(list(rows.values()), CLEARANCE_ROWS, self.system.nq) if rows else None
        self._cut_solves -= first is not None
        q, ev, status, iters = self._nlp(q0, target, normal, q_prev, first)
        worst = -np.inf
        for _ in range(CLEARANCE_ROUNDS):
            if not self.accept(ev, q) or self._cut_solves <= 0:
                break
            bad = self.unsafe(q, ev)
            if bad is None or bad.check.value in APERTURE_CHECKS:
                break  # safe, or a rule that is not a distance
            if bad.margin <= worst + 1e-4:
                break  # no progress (0.1 mm): the rows cannot be met here
            worst = bad.margin
            rows |= {r.key: r for r in self.linearizer.rows(q, self._polyline(ev))}
            near = sorted(rows.values(), key=lambda r: r.distance - r.required)
            cuts = cut_matrix(near, CLEARANCE_ROWS, self.system.nq)
            self._cut_solves -= 1
            q2, ev2, status2, it = self._nlp(q, target, normal, q_prev, cuts)
            iters += it
            if not self.accept(ev2, q2):
                break
            q, ev, status = q2, ev2, status2
        return q, ev, status, iters

    def unsafe(self, q: Array, ev: BeamTrace) -> Violation | None:
        """The safety rules' worst violation at ``q`` with its traced beam (None: safe or no
        rules)."""
        if self.safety is None:
            return None
        return self.safety.config(q, self._polyline(ev))

    def _polyline(self, ev: BeamTrace) -> Array:
        """The traced beam as world points: laser exit, mirror hits, spot (m)."""
        return np.vstack([self.system.world_T_laser[:3, 3], ev.hits, ev.spot])

    def _multistart(
        self, target: Array, normal: Array | None, q_prev: Array, first: list[Array]
    ) -> tuple[Array | None, BeamTrace | None, int, tuple[Reason | None, dict[str, object]]]:
        rng = np.random.default_rng(self.options.seed)
        lo, hi = np.maximum(self.system.lower, -np.pi), np.minimum(self.system.upper, np.pi)
        seeds = [*first, q_prev, self.system.home]
        seeds += [rng.uniform(lo, hi) for _ in range(self.options.starts)]
        best: tuple[float, Reason, dict[str, object]] | None = None
        unsafe: Violation | None = None
        iters = 0
        for q0 in seeds:
            q, ev, status, it = self._safe_nlp(
                np.clip(q0, self.system.lower, self.system.upper), target, normal, q_prev
            )
            iters += it
            if self.accept(ev, q):
                bad = self.unsafe(q, ev)
                if bad is None:
                    return q, ev, iters, (None, {})
                unsafe = bad if unsafe is None or bad.margin > unsafe.margin else unsafe
                continue
            reason, evidence = self.classify(ev, q, status)
            if best is None or ev.error < best[0]:
                best = (ev.error, reason, {**evidence, "starts": len(seeds)})
        if unsafe is not None:  # reachable, but never safely
            return None, None, iters, (Reason(unsafe.reason), dict(unsafe.evidence))
        assert best is not None
        return None, None, iters, (best[1], best[2])

    def _closed_form(
        self, target: Array, normal: Array | None, q_prev: Array
    ) -> tuple[
        Array | None, BeamTrace | None, str, int, Reason | None, dict[str, object], list[Array]
    ]:
        """The closed-form member (Newton-polished for calibrated arms, and for a nominal one
        that lost digits; a polished one is checked against the safety rules again): (q,
        evaluation, method, members, reason, evidence, seeds for the multi-start)."""
        assert self.closed_form is not None
        cf = self.closed_form.search(target, normal, q_prev, self.options.max_incidence)
        reason, evidence = cf.reason, dict(cf.evidence)
        if cf.q is None:
            return None, None, "closed_form", cf.members, reason, evidence, []
        q, method = cf.q, "closed_form"
        ev = trace_beam(self.system, q, target, normal)
        # A calibrated arm's member is a nominal seed; a nominal one can still lose digits in
        # the closed form near a zero joint (ur_analytic_ik's atan2s: 1e-9 m where most land
        # at 1e-13). Both close the gap by Gauss-Newton.
        if not self.closed_form.exact or ev.error > EXACT:
            q = self.newton.polish(q, target, normal).q
            method = "closed_form+newton"
            ev = trace_beam(self.system, q, target, normal)
        if not self.accept(ev, q):
            why: dict[str, object] = {"why": "closed-form member rejected"}
            return None, None, method, cf.members, Reason.SOLVER_FAILED, why, [q]
        polished = method != "closed_form"  # not the member the search checked: check it
        bad = self.unsafe(q, ev) if polished else None
        if bad is not None:
            return None, None, method, cf.members, Reason(bad.reason), bad.evidence, [q]
        return q, ev, method, cf.members, None, evidence, []

    def solve(
        self, target: Array, normal: Array | None = None, q_prev: Array | None = None
    ) -> Solution:
        """Solve one target.

        Args:
            target: the spot's goal (3,), world frame, m.
            normal: the target surface's outward normal (3,), world frame, or None (then the
                spot is the point of the last ray closest to ``target``).
            q_prev: stacked joints (rad) to start from and stay near; default home.

        With safety rules, a target inside a keep-out volume fails as ``keep_out`` at once and
        every accepted configuration passes the rules.

        Returns:
            A :class:`Solution`: ``status`` ok or a failure ``reason`` with its evidence,
            ``q`` (stacked, rad), the spot error (m) and the traced beam.
        """
        t0 = time.perf_counter()
        self._cut_solves = CLEARANCE_BUDGET
        target = np.asarray(target, dtype=float)
        q_prev = self.system.home if q_prev is None else np.asarray(q_prev, dtype=float)
        inside = None if self.safety is None else self.safety.target(target)
        if inside is not None:
            where = dict(inside.evidence)
            return Solution.failed(Reason.KEEP_OUT, time.perf_counter() - t0, 0, "keep_out", where)
        q: Array | None = None
        ev: BeamTrace | None = None
        method, iters = "closed_form", 0
        reason: Reason | None = None
        evidence: dict[str, object] = {}
        first: list[Array] = []
        if self.closed_form is not None:
            q, ev, method, iters, reason, evidence, first = self._closed_form(
                target, normal, q_prev
            )
        if q is not None and ev is not None and self.options.optimal:
            q2, ev2, _, it = self._safe_nlp(q, target, normal, q_prev)
            iters = it
            better = self.accept(ev2, q2) and ev2.error <= max(ev.error, EXACT)
            if better and self.unsafe(q2, ev2) is None:
                q, ev, method = q2, ev2, method + "+ipopt"
        if q is None:
            method = "multistart"
            q, ev, it, (r2, e2) = self._multistart(target, normal, q_prev, first)
            iters += it
            if q is None:
                reason = reason or r2
                evidence = {**evidence, "nlp": e2}
        dt = time.perf_counter() - t0
        if q is None or ev is None:
            return Solution.failed(reason or Reason.SOLVER_FAILED, dt, iters, method, evidence)
        return Solution.solved(q, ev, dt, iters, method, evidence)
