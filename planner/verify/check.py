"""Independent re-verification of a plan.json with plain numpy (no CasADi).

The geometry comes from the plan's own resolved ``scenario`` echo; the UR5e forward
kinematics (standard DH, SPEC section 2) and the reflection chain (written again from SPEC
section 3) are :mod:`planner.verify.numpy_beam`'s, shared with the trajectory check; URDF arms use
Pinocchio's numeric FK.

Checks are plain functions ``check(ctx) -> CheckResult`` in :data:`CHECKS`: the solved
targets (spot, mirrors, joint limits) and the dense trajectory sampled at the scenario
``rate`` (:mod:`planner.verify.trajectory`: time grid, position/velocity/acceleration/jerk
limits, spot deviation on path/dwell segments and at every arrival). Other stages may append
their own with :func:`register_check`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from planner.errors import InputError
from planner.model.transforms import Array
from planner.verify.numpy_beam import limits_from_dict, trace_rays, ur5e_dh_fk
from planner.verify.numpy_beam import pose_matrix as pose

if TYPE_CHECKING:
    from planner.verify.trajectory import Finding as TrajectoryFinding

LIMIT_SLACK = 1e-12  # rad
ROI_SLACK = 1e-12  # m


@dataclass(frozen=True)
class ArmGeometry:
    """One robot as the checker sees it (all SI, world frame)."""

    name: str
    fk: Callable[[Array], Array]  # q -> base_T_flange
    world_T_base: Array
    flange_T_mirror: Array
    roi_half: Array
    lower: Array
    upper: Array


def _arm(r: dict[str, Any], i: int, base_dir: Path) -> ArmGeometry:
    where = f"scenario.system.robots[{i}]"
    try:
        mirror = r["mirror"]
        size = np.asarray(mirror["size"], dtype=float)
        margin = float(mirror.get("roi_margin", 0.005))
        if r.get("urdf"):
            from planner.model.kinematics import RobotKinematics

            urdf = Path(r["urdf"])
            kin = RobotKinematics.from_urdf(urdf if urdf.is_absolute() else base_dir / urdf)
            fk: Callable[[Array], Array] = kin.fk
            n = kin.nq
        else:
            fk, n = ur5e_dh_fk, 6
        limits = limits_from_dict(r.get("limits"), n)
        return ArmGeometry(
            name=str(r["name"]),
            fk=fk,
            world_T_base=pose(r.get("world_T_base", {"matrix": np.eye(4).tolist()}), where),
            flange_T_mirror=pose(mirror["flange_T_mirror"], f"{where}.mirror"),
            roi_half=size / 2 - margin,
            lower=limits.lower,
            upper=limits.upper,
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"cannot read robot geometry: {exc!r}", where) from exc


class Trace:
    """Numpy beam trace of one configuration (SPEC section 3)."""

    def __init__(self, world_T_laser: Array, arms: list[ArmGeometry], q: dict[str, Array]):
        world_T_mirrors = [
            arm.world_T_base @ arm.fk(np.asarray(q[arm.name], dtype=float)) @ arm.flange_T_mirror
            for arm in arms
        ]
        rays = trace_rays(world_T_laser, [M[None] for M in world_T_mirrors])
        self.hits = [h[0] for h in rays.hits]
        self.uv = [uv[0] for uv in rays.uv]
        self.front = [float(f[0]) for f in rays.front]
        self.ahead = [float(t[0]) for t in rays.ahead]
        self.p, self.v = rays.p[0], rays.v[0]

    def spot(self, target: Array, normal: Array | None) -> tuple[Array, float, float]:
        """(spot, ray parameter s, incidence rad) for a target (optionally with a normal)."""
        if normal is None:
            s = float(np.dot(self.v, target - self.p))
            return self.p + s * self.v, s, 0.0
        s = float(np.dot(normal, target - self.p) / np.dot(normal, self.v))
        inc = float(np.arccos(min(abs(float(np.dot(self.v, normal))), 1.0)))
        return self.p + s * self.v, s, inc


@dataclass(frozen=True)
class Finding:
    check: str
    target: int | None
    message: str
    value: float
    bound: float


@dataclass
class CheckResult:
    name: str
    checked: int
    findings: list[Finding] = field(default_factory=list)  # violations: exit status 1
    figures: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)  # worth a look, not a violation


class PlanContext:
    """A parsed plan: geometry, targets and solved configurations, traced once lazily."""

    def __init__(self, plan: dict[str, Any], base_dir: Path = Path(".")) -> None:
        try:
            scn = plan["scenario"]
            system = scn["system"]
            self.world_T_laser = pose(system["laser"]["world_T_laser"], "scenario.system.laser")
            self.arms = [_arm(r, i, base_dir) for i, r in enumerate(system["robots"])]
            solver = scn.get("solver") or {}
            self.tolerance = float(solver.get("tolerance", 1e-9))
            inc = solver.get("max_incidence_deg")
            self.max_incidence = None if inc is None else float(np.radians(inc))
            self.targets = {int(t["id"]): t for t in plan["targets"]}
            self.solutions = list(plan["solutions"])
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"not a plan document: missing or bad {exc!r}") from exc
        self.plan = plan

    @property
    def solved(self) -> list[dict[str, Any]]:
        return [s for s in self.solutions if s.get("status") == "ok"]

    @cached_property
    def traces(self) -> dict[int, Trace]:
        return {int(s["target"]): Trace(self.world_T_laser, self.arms, s["q"]) for s in self.solved}

    @cached_property
    def trajectory_findings(self) -> list[TrajectoryFinding]:
        from planner.verify.trajectory import check_trajectory

        return check_trajectory(self.plan)

    def target(self, k: int) -> tuple[Array, Array | None]:
        t = self.targets[k]
        n = t.get("n")
        return np.asarray(t["p"], dtype=float), None if n is None else np.asarray(n, dtype=float)


def check_spots(ctx: PlanContext) -> CheckResult:
    """Spot error <= solver tolerance, target ahead, incidence limit, reported spot matches."""
    res = CheckResult("spot", len(ctx.solved))
    errors = []
    for sol in ctx.solved:
        k = int(sol["target"])
        p, n = ctx.target(k)
        spot, s, inc = ctx.traces[k].spot(p, n)
        err = float(np.linalg.norm(spot - p))
        errors.append(err)
        if not err <= ctx.tolerance:
            res.findings.append(
                Finding("spot", k, "spot error above tolerance", err, ctx.tolerance)
            )
        if not s > 0:
            res.findings.append(Finding("spot", k, "target behind the last mirror", s, 0.0))
        if n is not None and ctx.max_incidence is not None and inc > ctx.max_incidence:
            res.findings.append(Finding("spot", k, "incidence above limit", inc, ctx.max_incidence))
        if sol.get("spot") is not None:
            gap = float(np.linalg.norm(np.asarray(sol["spot"]) - spot))
            if gap > max(1e-9, ctx.tolerance):
                res.findings.append(Finding("spot", k, "reported spot differs", gap, 1e-9))
    if errors:
        res.figures = {"error_max_m": max(errors), "error_median_m": float(np.median(errors))}
    return res


def check_mirrors(ctx: PlanContext) -> CheckResult:
    """Every bounce: mirror ahead (t > 0), front face (-n.v > 0), hit inside the ROI."""
    res = CheckResult("mirrors", len(ctx.solved))
    worst_roi = np.inf
    for sol in ctx.solved:
        k = int(sol["target"])
        tr = ctx.traces[k]
        for i, arm in enumerate(ctx.arms):
            if not tr.ahead[i] > 0:
                res.findings.append(Finding("mirrors", k, f"{arm.name}: mirror behind the beam",
                                            tr.ahead[i], 0.0))  # fmt: skip
            if not tr.front[i] > 0:
                res.findings.append(Finding("mirrors", k, f"{arm.name}: back face hit",
                                            tr.front[i], 0.0))  # fmt: skip
            margin = float(np.min(arm.roi_half - np.abs(tr.uv[i])))
            worst_roi = min(worst_roi, margin)
            if margin < -ROI_SLACK:
                res.findings.append(Finding("mirrors", k, f"{arm.name}: hit outside the ROI",
                                            margin, 0.0))  # fmt: skip
    if ctx.solved:
        res.figures = {"roi_margin_min_m": worst_roi}
    return res


def check_limits(ctx: PlanContext) -> CheckResult:
    """Every solved configuration within the joint position limits."""
    res = CheckResult("joint limits", len(ctx.solved))
    worst = -np.inf
    for sol in ctx.solved:
        k = int(sol["target"])
        for arm in ctx.arms:
            q = np.asarray(sol["q"][arm.name], dtype=float)
            viol = float(max(np.max(q - arm.upper), np.max(arm.lower - q)))
            worst = max(worst, viol)
            if viol > LIMIT_SLACK:
                res.findings.append(Finding("joint limits", k, f"{arm.name}: outside limits",
                                            viol, 0.0))  # fmt: skip
    if ctx.solved:
        res.figures = {"limit_slack_min_rad": -worst}
    return res


_LIMIT_CODES = ("time_grid", "joint_limits", "velocity", "acceleration", "jerk")
_SPOT_CODES = ("path_deviation", "dwell_deviation", "arrival_deviation", "path_duration")


def _trajectory_result(ctx: PlanContext, name: str, codes: tuple[str, ...]) -> CheckResult:
    """Trajectory findings of some codes as a CheckResult: errors are violations, warnings
    are listed, figures are the worst value per code (ratios to the limit for joint rates)."""
    traj = ctx.plan.get("trajectory") or {}
    res = CheckResult(name, len(traj.get("t") or []))
    for f in ctx.trajectory_findings:
        if f.code not in codes:
            continue
        if f.severity == "error":
            res.findings.append(Finding(name, None, f.message, f.value, f.limit))
        elif f.severity == "warning":
            res.warnings.append(f.message)
        if f.code in ("velocity", "acceleration", "jerk"):
            key, value = f"{f.code}_max_ratio", f.value / f.limit
        elif f.code == "path_duration":
            res.figures["path_duration_ideal_s"] = f.limit
            key, value = "path_duration_s", f.value
        elif f.code.endswith("deviation"):
            key, value = f"{f.code}_max_m", f.value
        else:
            continue
        res.figures[key] = max(value, res.figures.get(key, -np.inf))
    if not traj:
        res.warnings.append("plan has no trajectory")
    return res


def check_trajectory_limits(ctx: PlanContext) -> CheckResult:
    """The dense trajectory on the 1/rate grid, within position, velocity, acceleration and
    jerk limits (finite differences, small slack)."""
    return _trajectory_result(ctx, "trajectory limits", _LIMIT_CODES)


def check_trajectory_spot(ctx: PlanContext) -> CheckResult:
    """The spot on the path during ``path`` segments, on a target during ``dwell`` and at the
    end of every move; path duration vs length / spot speed."""
    return _trajectory_result(ctx, "trajectory spot", _SPOT_CODES)


CHECKS: list[Callable[[PlanContext], CheckResult]] = [
    check_spots,
    check_mirrors,
    check_limits,
    check_trajectory_limits,
    check_trajectory_spot,
]


def register_check(fn: Callable[[PlanContext], CheckResult]) -> None:
    """Add a check (e.g. the trajectory checks of the timing stage) to :data:`CHECKS`."""
    if fn not in CHECKS:
        CHECKS.append(fn)


def check_plan(plan: dict[str, Any], base_dir: Path = Path(".")) -> list[CheckResult]:
    """Run every registered check on a plan document."""
    ctx = PlanContext(plan, base_dir)
    return [check(ctx) for check in CHECKS]
