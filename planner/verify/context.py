"""What every check of :mod:`planner.verify.check` reads: the plan parsed once
(:class:`PlanContext`: the checker's own arm geometry, tolerances, targets, solved
configurations, traced lazily, and the safety setup, built lazily) and what a check returns
(:class:`CheckResult`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from planner.errors import InputError
from planner.model.status import Status
from planner.model.transforms import Array
from planner.verify.arm_models import checker_arm
from planner.verify.findings import Finding
from planner.verify.numpy_beam import BeamRays, limits_from_dict, trace_rays
from planner.verify.numpy_beam import pose_matrix as pose
from planner.verify.safety_setup import Setup
from planner.verify.spot import trajectory_findings
from planner.verify.tolerances import Tolerances
from planner.verify.urdf import UrdfChain


def times(plan: Mapping[str, Any]) -> Array:
    """The trajectory's times (s), empty without a trajectory (its tables may be arrays,
    :func:`planner.io.plan_file.read_plan`, or lists)."""
    t = (plan.get("trajectory") or {}).get("t")
    return np.asarray([] if t is None else t, dtype=float)


@dataclass(frozen=True)
class ArmGeometry:
    """One robot as the checker sees it (all SI, world frame); ``batched``: ``fk`` takes
    joint rows (M x nq -> M x 4 x 4), else one configuration at a time."""

    name: str
    fk: Callable[[Array], Array]  # q -> base_T_flange
    world_T_base: Array
    flange_T_mirror: Array
    roi_half: Array
    lower: Array
    upper: Array
    batched: bool = False

    def world_T_mirror(self, Q: Array) -> Array:
        """Mirror poses (M x 4 x 4) of joint rows ``Q`` (M x nq, rad)."""
        Q = np.atleast_2d(np.asarray(Q, dtype=float))
        if self.batched:
            F = self.fk(Q).reshape(len(Q), 4, 4)
        else:
            F = np.array([self.fk(q) for q in Q]).reshape(len(Q), 4, 4)
        return self.world_T_base @ F @ self.flange_T_mirror


def _arm(r: dict[str, Any], i: int, base_dir: Path, urdfs: dict[Path, UrdfChain]
         ) -> ArmGeometry:  # fmt: skip
    """Robot ``i`` of the scenario as the checker sees it (a URDF it reads is kept in
    ``urdfs`` by its path)."""
    where = f"scenario.system.robots[{i}]"
    try:
        mirror = r["mirror"]
        size = np.asarray(mirror["size"], dtype=float)
        margin = float(mirror.get("roi_margin", 0.005))
        batched = False
        if r.get("urdf"):
            urdf = Path(r["urdf"])
            urdf = urdf if urdf.is_absolute() else base_dir / urdf
            kin = urdfs[urdf] = UrdfChain(urdf)
            fk: Callable[[Array], Array] = kin.fk
            n = kin.nq
        elif (arm := checker_arm(r.get("model"))) is not None:
            fk, n, batched = arm.fk, arm.nq, True
        else:  # never check an arm with another arm's kinematics
            raise InputError(f"no independent kinematics for robot model {r['model']!r}", where)
        limits = limits_from_dict(r.get("limits"), n)
        return ArmGeometry(
            name=str(r["name"]),
            fk=fk,
            world_T_base=pose(r.get("world_T_base", {"matrix": np.eye(4).tolist()}), where),
            flange_T_mirror=pose(mirror["flange_T_mirror"], f"{where}.mirror"),
            roi_half=size / 2 - margin,
            lower=limits.lower,
            upper=limits.upper,
            batched=batched,
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"cannot read robot geometry: {exc!r}", where) from exc


def trace_arms(world_T_laser: Array, arms: list[ArmGeometry], q: Mapping[str, Any]) -> BeamRays:
    """The checker's beam trace of the joint rows ``q[arm name]`` ((M, nq) or one (nq,)
    configuration, rad), every arm's mirror in chain order."""
    return trace_rays(world_T_laser, [arm.world_T_mirror(q[arm.name]) for arm in arms])


def spots(p: Array, v: Array, targets: Array, normals: Array) -> tuple[Array, Array, Array]:
    """Spots of M rays (origins ``p``, unit directions ``v``, M x 3) on their targets (M x 3)
    with normals (M x 3, NaN rows = none): the ray meets the plane through the target normal
    to its normal (without one: the ray's closest point). Returns (spot M x 3, ray parameter
    s M (m, > 0 when the target is ahead), incidence M (rad, 0 without a normal))."""
    has = np.all(np.isfinite(normals), axis=1)
    nb = np.where(has[:, None], normals, 0.0)
    w = targets - p
    nv = np.einsum("ij,ij->i", nb, v)
    with np.errstate(divide="ignore", invalid="ignore"):
        s_plane = np.einsum("ij,ij->i", nb, w) / nv
    s = np.where(has, s_plane, np.einsum("ij,ij->i", v, w))
    inc = np.where(has, np.arccos(np.minimum(np.abs(nv), 1.0)), 0.0)
    return p + s[:, None] * v, s, inc


def _tables_as_arrays(plan: dict[str, Any]) -> dict[str, Any]:
    """The plan with its trajectory's ``t``, ``q``, ``qd`` and ``qdd`` tables as float64
    arrays (as :func:`planner.io.plan_file.read_plan` gives them), so that the checks do not
    each convert a document's lists again; the document itself is left as it is. A table
    that is not numeric is left as a list (each check reads it as before)."""
    traj = plan.get("trajectory")
    if not isinstance(traj, dict):
        return plan
    tables: dict[str, Any] = {}
    try:
        if traj.get("t") is not None:
            tables["t"] = np.asarray(traj["t"], dtype=float)
        for key in ("q", "qd", "qdd"):
            if isinstance(traj.get(key), dict):
                tables[key] = {n: np.asarray(v, dtype=float) for n, v in traj[key].items()}
    except (TypeError, ValueError):
        return plan
    return {**plan, "trajectory": {**traj, **tables}}


@dataclass
class CheckResult:
    name: str
    checked: int
    findings: list[Finding] = field(default_factory=list)  # violations: exit status 1
    figures: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)  # worth a look, not a violation


class PlanContext:
    """A parsed plan: geometry, tolerances, targets and solved configurations, traced once
    (batched) lazily; :attr:`plan` is the document with its trajectory's tables as arrays."""

    def __init__(self, plan: dict[str, Any], base_dir: Path = Path(".")) -> None:
        try:
            scn = plan["scenario"]
            system = scn["system"]
            self.world_T_laser = pose(system["laser"]["world_T_laser"], "scenario.system.laser")
            self.urdfs: dict[Path, UrdfChain] = {}  # the URDFs read, by path
            self.arms = [_arm(r, i, base_dir, self.urdfs) for i, r in enumerate(system["robots"])]
            self.tol = Tolerances.from_scenario(scn)
            self.targets = {int(t["id"]): t for t in plan["targets"]}
            self.solutions = list(plan["solutions"])
            self.solved = [s for s in self.solutions if s.get("status") == Status.OK]
            self.ids = np.array([int(s["target"]) for s in self.solved], dtype=int)
            self.P = np.array([self.targets[k]["p"] for k in self.ids], dtype=float).reshape(-1, 3)
            self.N = np.array([self.targets[k].get("n") or [np.nan] * 3 for k in self.ids],
                              dtype=float).reshape(-1, 3)  # fmt: skip
            self.Q = {a.name: np.array([s["q"][a.name] for s in self.solved], dtype=float)
                      for a in self.arms}  # fmt: skip
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"not a plan document: missing or bad {exc!r}") from exc
        self.plan = _tables_as_arrays(plan)

    @property
    def tolerance(self) -> float:
        """The spot tolerance (m)."""
        return self.tol.spot

    @cached_property
    def rays(self) -> BeamRays:
        """Every solved configuration traced side by side (rows in :attr:`solved` order)."""
        if not self.solved:
            empty = np.zeros((0, 3))
            return BeamRays(empty, empty, [], [], [], [])
        return trace_arms(self.world_T_laser, self.arms, self.Q)

    @cached_property
    def safety_setup(self) -> Setup:
        """The plan's safety setup, built once for every safety check (relative scene-mesh
        and URDF paths from the working directory: the plan's echo has them absolute)."""
        return Setup.from_plan(self.plan, Path("."), self.urdfs)

    @cached_property
    def trajectory_findings(self) -> list[Finding]:

        return trajectory_findings(self.plan, self.tol)

    def target(self, k: int) -> tuple[Array, Array | None]:
        t = self.targets[k]
        n = t.get("n")
        return np.asarray(t["p"], dtype=float), None if n is None else np.asarray(n, dtype=float)
