"""Independent re-verification of a plan.json with plain numpy (no CasADi).

The geometry comes from the plan's own resolved ``scenario`` echo; the UR5e forward
kinematics (standard DH) and the reflection chain are :mod:`planner.verify.numpy_beam`'s, written
from the conventions rather than taken from the planner, and shared with the trajectory
check; URDF arms use the checker's own numpy URDF kinematics (:mod:`planner.verify.urdf`). Every bound is the one the planner accepted the
plan with (:mod:`planner.verify.tolerances`), so planning and checking cannot disagree.

Checks are plain functions ``check(ctx) -> CheckResult`` in :data:`CHECKS`: the solved
targets (spot, incidence, mirrors, joint limits), the dense trajectory sampled at the
scenario ``rate`` (:mod:`planner.verify.trajectory`: presence, time grid, position, velocity,
acceleration and jerk limits, declared velocities and accelerations against finite
differences, the spot on the path, on its target while dwelling and at every arrival, every
solved target visited) and the ``metrics``, recomputed from the solutions and the trajectory.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from planner.model.status import Reason
from planner.model.transforms import Array
from planner.model.validity import MIN_AHEAD, MIN_FRONT, ahead_ok, front_ok
from planner.verify.context import CheckResult, PlanContext, spots, times
from planner.verify.findings import Finding
from planner.verify.marking import check_marking
from planner.verify.metrics import metric_findings
from planner.verify.safety import check_safety, check_trajectory_safety
from planner.verify.tolerances import (
    INCIDENCE_SLACK,
    REPORT_SLACK,
    ROI_SLACK,
    TRACE_SLACK,
    joints_ok,
    roi_ok,
)


def check_spots(ctx: PlanContext) -> CheckResult:
    """Spot error within the solver tolerance, target ahead, incidence within the limit, and
    the reported spot, error and incidence match the recomputed ones."""
    tol = ctx.tol
    res = CheckResult("spot", len(ctx.solved))
    if not ctx.solved:
        return res
    spot, s, inc = spots(ctx.rays.p, ctx.rays.v, ctx.P, ctx.N)
    err = np.linalg.norm(spot - ctx.P, axis=1)
    add = res.findings.append
    for i in np.flatnonzero(~(err <= tol.spot)):
        add(Finding("spot", int(ctx.ids[i]), f"spot error {1e3 * err[i]:.3g} mm above the "
                    f"tolerance {1e3 * tol.spot:.3g} mm", float(err[i]), tol.spot, Reason.SOLVER_FAILED))  # fmt: skip
    for i in np.flatnonzero(~ahead_ok(s, TRACE_SLACK)):
        add(Finding("spot", int(ctx.ids[i]), "target behind the last mirror", float(s[i]), MIN_AHEAD,
                    Reason.BACK_FACE))  # fmt: skip
    if tol.max_incidence is not None:
        for i in np.flatnonzero([not tol.incidence_ok(x) for x in inc]):
            add(Finding("spot", int(ctx.ids[i]), f"incidence {np.degrees(inc[i]):.7f} deg above "
                        f"the limit {np.degrees(tol.max_incidence):.7f} deg", float(inc[i]),
                        tol.max_incidence, Reason.UNREACHABLE))  # fmt: skip
    _reported(ctx, res, spot, err, inc)
    res.figures = {"error_max_m": float(np.max(err)), "error_median_m": float(np.median(err))}
    if np.isfinite(ctx.N).all(axis=1).any():
        res.figures["incidence_max_deg"] = float(np.degrees(inc[np.isfinite(ctx.N[:, 0])].max()))
    return res


def _reported(ctx: PlanContext, res: CheckResult, spot: Array, err: Array, inc: Array) -> None:
    """The solutions' own ``spot``, ``error`` and ``incidence`` against the recomputed ones."""
    bound = max(REPORT_SLACK, ctx.tol.spot)
    for i, sol in enumerate(ctx.solved):
        k = int(sol["target"])
        if sol.get("spot") is not None:
            gap = float(np.linalg.norm(np.asarray(sol["spot"], dtype=float) - spot[i]))
            if not gap <= bound:
                res.findings.append(Finding("spot", k, f"reported spot is {1e3 * gap:.3g} mm "
                                            "from the recomputed one", gap, bound))  # fmt: skip
        reported = sol.get("error")
        if reported is not None and not abs(float(reported) - err[i]) <= bound:
            res.findings.append(Finding("spot", k, f"reported error {1e3 * float(reported):.3g} mm"
                                        f", recomputed {1e3 * err[i]:.3g} mm",
                                        float(reported), float(err[i])))  # fmt: skip
        rinc = sol.get("incidence")
        if rinc is not None and not abs(float(rinc) - inc[i]) <= INCIDENCE_SLACK:
            res.findings.append(Finding("spot", k, f"reported incidence {np.degrees(rinc):.4f} deg"
                                        f", recomputed {np.degrees(inc[i]):.4f} deg",
                                        float(rinc), float(inc[i])))  # fmt: skip


def check_mirrors(ctx: PlanContext) -> CheckResult:
    """Every bounce: mirror ahead (t > 0), front face (-n.v > 0), hit inside the ROI."""
    res = CheckResult("mirrors", len(ctx.solved))
    if not ctx.solved:
        return res
    rays, worst_roi = ctx.rays, np.inf
    for a, arm in enumerate(ctx.arms):
        margin = np.min(arm.roi_half[None, :] - np.abs(rays.uv[a]), axis=1)
        worst_roi = min(worst_roi, float(margin.min()))
        for i in np.flatnonzero(~ahead_ok(rays.ahead[a], TRACE_SLACK)):
            res.findings.append(Finding("mirrors", int(ctx.ids[i]), f"{arm.name}: mirror behind "
                                        "the beam", float(rays.ahead[a][i]), MIN_AHEAD, Reason.UNREACHABLE))  # fmt: skip
        for i in np.flatnonzero(~front_ok(rays.front[a], TRACE_SLACK)):
            res.findings.append(Finding("mirrors", int(ctx.ids[i]), f"{arm.name}: back face hit",
                                        float(rays.front[a][i]), MIN_FRONT, Reason.BACK_FACE))  # fmt: skip
        for i in np.flatnonzero([not roi_ok(m) for m in margin]):
            res.findings.append(Finding("mirrors", int(ctx.ids[i]), f"{arm.name}: hit "
                                        f"{1e3 * -margin[i]:.3g} mm outside the ROI",
                                        float(margin[i]), -ROI_SLACK, Reason.OUTSIDE_ROI))  # fmt: skip
    res.figures = {"roi_margin_min_m": worst_roi}
    return res


def check_limits(ctx: PlanContext) -> CheckResult:
    """Every solved configuration within the joint position limits."""
    res = CheckResult("joint limits", len(ctx.solved))
    if not ctx.solved:
        return res
    worst = -np.inf
    for arm in ctx.arms:
        Q = ctx.Q[arm.name]
        viol = np.max(np.maximum(Q - arm.upper, arm.lower - Q), axis=1)
        worst = max(worst, float(viol.max()))
        for i in np.flatnonzero([not joints_ok(v) for v in viol]):
            res.findings.append(Finding("joint limits", int(ctx.ids[i]), f"{arm.name}: "
                                        f"{viol[i]:.3g} rad outside the limits", float(viol[i]),
                                        0.0, Reason.JOINT_LIMITS))  # fmt: skip
    res.figures = {"limit_slack_min_rad": -worst}
    return res


def target_findings(plan: dict[str, Any], base_dir: Path = Path("."),
                    surfaces: Mapping[str, Mapping[str, Any]] | None = None) -> list[Finding]:  # fmt: skip
    """The per-target violations (spot, mirrors, joint limits) of a plan's solved targets:
    what planning uses to decide that a solution is ok. ``surfaces``: the mirrors' shapes
    when not flat (:class:`~planner.verify.context.PlanContext`)."""
    ctx = PlanContext(plan, base_dir, surfaces)
    return [f for check in (check_spots, check_mirrors, check_limits) for f in check(ctx).findings]


_LIMIT_CODES = ("trajectory_missing", "time_grid", "joint_limits", "velocity", "acceleration",
                "jerk", "velocity_declared", "acceleration_declared")  # fmt: skip
_SPOT_CODES = ("path_deviation", "dwell_deviation", "arrival_deviation", "path_duration",
               "not_visited")  # fmt: skip


def _trajectory_result(ctx: PlanContext, name: str, codes: tuple[str, ...]) -> CheckResult:
    """Trajectory findings of some codes as a CheckResult: errors are violations, warnings
    are listed, figures are the worst value per code (ratios to the limit for joint rates)."""
    traj = ctx.plan.get("trajectory") or {}
    res = CheckResult(name, len(times(ctx.plan)))
    for f in ctx.trajectory_findings:
        if f.code not in codes:
            continue
        if f.severity == "error":
            res.findings.append(replace(f, check=name))
        elif f.severity == "warning":
            res.warnings.append(f.message)
        if f.code in ("velocity", "acceleration", "jerk"):
            key, value = f"{f.code}_max_ratio", f.value / f.bound
        elif f.code.endswith("_declared"):
            key, value = f"{f.code}_gap_max_ratio", f.value / f.bound
        elif f.code == "path_duration":
            res.figures["path_duration_ideal_s"] = f.bound
            key, value = "path_duration_s", f.value
        elif f.code.endswith("deviation"):
            key, value = f"{f.code}_max_m", f.value
        else:
            continue
        res.figures[key] = max(value, res.figures.get(key, -np.inf))
    if not traj and name == "trajectory limits":
        res.warnings.append("plan has no trajectory")
    return res


def check_trajectory_limits(ctx: PlanContext) -> CheckResult:
    """The dense trajectory (present when one is expected) on the 1/rate grid, within
    position, velocity, acceleration and jerk limits (finite differences, small slack), its
    declared velocities and accelerations matching the differences of q and qd."""
    return _trajectory_result(ctx, "trajectory limits", _LIMIT_CODES)


def check_trajectory_spot(ctx: PlanContext) -> CheckResult:
    """The spot on the path during ``path`` segments, on a target during ``dwell`` and at the
    end of every move, every solved target visited; path duration vs length / spot speed."""
    return _trajectory_result(ctx, "trajectory spot", _SPOT_CODES)


def check_metrics(ctx: PlanContext) -> CheckResult:
    """``metrics`` recomputed from the solutions and the trajectory (:mod:`planner.verify.metrics`)."""

    res = CheckResult("metrics", len(ctx.plan.get("metrics") or {}))
    for message, value, bound in metric_findings(ctx.plan):
        res.findings.append(Finding("metrics", None, message, value, bound))
    return res


def check_laser(ctx: PlanContext) -> CheckResult:
    """The laser gate: on only (and always) in path and dwell segments, the spot on the path
    and at the spot speed while it is on (:mod:`planner.verify.marking`)."""

    return check_marking(ctx)


CHECKS: list[Callable[[PlanContext], CheckResult]] = [
    check_spots,
    check_mirrors,
    check_limits,
    check_trajectory_limits,
    check_trajectory_spot,
    check_laser,
    check_metrics,
    check_safety,
    check_trajectory_safety,
]


def check_plan(plan: dict[str, Any], base_dir: Path = Path(".")) -> list[CheckResult]:
    """Run every check of :data:`CHECKS` on a plan document."""
    ctx = PlanContext(plan, base_dir)
    return [check(ctx) for check in CHECKS]
