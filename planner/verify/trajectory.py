"""Independent re-verification of a plan's trajectory with plain numpy (no CasADi, no
Pinocchio), for ``beamrelay check`` and the check ``beamrelay plan`` runs on what it wrote.

Samples the trajectory at the scenario ``rate``; checks that a trajectory is there when the
plan has solved targets (unless it says none was requested: ``trajectory_requested: false``,
a plan answering a request that did not ask to execute), the time grid, joint position
limits, velocity/acceleration/jerk by finite differences, the declared ``qd``/``qdd`` against
the differences of ``q``/``qd``, and the spot: its distance from the target path at every
sample of a ``path`` segment, from its target during ``dwell`` and at the last sample of
every ``approach``/``move`` (arrival), and that every solved point target is arrived at.
Bounds and slack are :mod:`planner.verify.tolerances`'. The forward kinematics and mirror
reflection are :mod:`planner.verify.numpy_beam`'s (shared with :mod:`planner.verify.check`). Memory is
linear in the number of samples and targets (targets matched through a k-d tree of the
solved configurations).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, NamedTuple

import numpy as np

from planner.model.limits import Limits
from planner.model.status import Status
from planner.model.transforms import Array
from planner.verify.arm_models import checker_arm
from planner.verify.findings import Finding, trajectory_finding
from planner.verify.numpy_beam import limits_from_dict, pose_matrix, trace_rays
from planner.verify.tolerances import (
    DERIVATIVE_SLACK,
    JOINT_SLACK,
    RATE_SLACK,
    TIME_GRID_SLACK,
    Tolerances,
)

CHUNK_ELEMENTS = 1 << 21  # rays x targets per block of the brute-force nearest search
CHUNK_ROWS = 1 << 18  # trajectory samples per block of the limit checks (~10 MB a table)


def _fk(model: str) -> Any:
    """The checker's batched ``base_T_flange`` of ``model`` (callers skip a model without
    a twin, :func:`~planner.verify.arm_models.checker_arm`)."""
    arm = checker_arm(model)
    assert arm is not None, model
    return arm.fk


class _Robot(NamedTuple):
    name: str
    model: str
    world_T_base: Array
    flange_T_mirror: Array
    limits: Limits


def _robots(scenario: dict[str, Any]) -> list[_Robot]:
    out = []
    for r in scenario["system"]["robots"]:
        lim = r.get("limits") or {}
        limits = limits_from_dict(lim, len(lim.get("lower") or [0.0] * 6))
        model = "urdf:" + str(r["urdf"]) if r.get("urdf") else str(r.get("model") or "ur5e")
        out.append(_Robot(r["name"], model, pose_matrix(r.get("world_T_base") or {}),
                          pose_matrix(r["mirror"].get("flange_T_mirror") or {}), limits))  # fmt: skip
    return out


def trace_last_ray(scenario: dict[str, Any], q: dict[str, Array]) -> tuple[Array, Array]:
    """Last ray (origin, unit direction), each (M x 3), after every mirror."""
    world_T_mirrors = [
        r.world_T_base @ _fk(r.model)(np.atleast_2d(q[r.name])) @ r.flange_T_mirror
        for r in _robots(scenario)
    ]
    rays = trace_rays(pose_matrix(scenario["system"]["laser"]["world_T_laser"]), world_T_mirrors)
    return rays.p, rays.v


def _chunk(n_targets: int) -> int:
    return max(1, min(256, CHUNK_ELEMENTS // max(n_targets, 1)))


def nearest_spots(p: Array, v: Array, targets: Array, normals: Array | None) -> tuple[Array, Array]:
    """Per ray: the index k of the target it passes nearest (ahead of it), and the spot where
    the ray meets that target's plane (its normal, or perpendicular to the ray)."""
    w = targets[None, :, :] - p[:, None, :]
    along = np.einsum("mkj,mj->mk", w, v)
    perp = np.linalg.norm(w - along[..., None] * v[:, None, :], axis=2)
    k = np.argmin(np.where(along > 0, perp, np.inf), axis=1)
    return k, _plane_spots(p, v, targets[k], None if normals is None else normals[k])


def _plane_spots(p: Array, v: Array, targets: Array, normals: Array | None) -> Array:
    """Where each ray meets its target's plane (normal, NaN or None: perpendicular to the ray)."""
    nb = -v if normals is None else np.where(np.isfinite(normals), normals, -v)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.einsum("ij,ij->i", nb, targets - p) / np.einsum("ij,ij->i", nb, v)
    return p + s[:, None] * v


def point_deviation(p: Array, v: Array, targets: Array, normals: Array | None) -> Array:
    """Distance (m) from each ray's spot to the nearest target point (brute force over the
    targets, in blocks of bounded memory)."""
    out = np.empty(len(p))
    step = _chunk(len(targets))
    for i0 in range(0, len(p), step):
        k, spot = nearest_spots(p[i0 : i0 + step], v[i0 : i0 + step], targets, normals)
        out[i0 : i0 + step] = np.linalg.norm(spot - targets[k], axis=1)
    return out


def spot_deviation(
    p: Array, v: Array, targets: Array, normals: Array | None, closed: bool
) -> Array:
    """Distance (m) from each sample's spot to the target polyline. With normals the spot is
    where the ray meets the plane of the nearest target; without, the distance is the ray's
    closest approach to the polyline (a target is hit when the ray passes through it, so a
    beam grazing along the path is measured where it crosses it, not at whichever sample
    lies nearest its line)."""
    if len(targets) < 2:
        return point_deviation(p, v, targets, normals)
    out = np.empty(len(p))
    segs_a = targets if closed else targets[:-1]
    segs_b = np.roll(targets, -1, axis=0) if closed else targets[1:]
    ab = segs_b - segs_a
    ab2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300)
    step = _chunk(len(targets))
    if normals is None:
        for i0 in range(0, len(p), step):
            sl = slice(i0, i0 + step)
            out[sl] = ray_polyline_closest(p[sl], v[sl], segs_a, ab, ab2)[0]
        return out
    for i0 in range(0, len(p), step):
        _, spot = nearest_spots(p[i0 : i0 + step], v[i0 : i0 + step], targets, normals)
        u = np.clip(np.einsum("mkj,kj->mk", spot[:, None, :] - segs_a[None], ab) / ab2, 0, 1)
        near = segs_a[None] + u[..., None] * ab[None]
        out[i0 : i0 + step] = np.linalg.norm(spot[:, None, :] - near, axis=2).min(axis=1)
    return out


class RayPolyline(NamedTuple):
    """Closest approach of rays to a polyline: distance (m, M), the ray's point there
    (M x 3) and the index of the nearest segment (M)."""

    distance: Array
    point: Array
    segment: Array


def ray_polyline_closest(p: Array, v: Array, a: Array, ab: Array, ab2: Array
                         ) -> RayPolyline:  # fmt: skip
    """Closest approach (m) of each ray (origins ``p``, unit directions ``v``, M x 3; the
    part ahead, t >= 0) to segments ``a + u ab`` (u in [0, 1]; ``ab2`` = |ab|^2), the
    minimum over the segments (M,), the ray's point there (M x 3) and that segment."""
    w = p[:, None, :] - a[None]  # M x S x 3
    b = np.einsum("mj,sj->ms", v, ab)
    d = np.einsum("mj,msj->ms", v, w)
    e = np.einsum("sj,msj->ms", ab, w)
    denom = ab2[None] - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.where(denom > 1e-18 * ab2[None], (e - d * b) / denom, 0.0)
    u = np.clip(u, 0.0, 1.0)
    t = np.maximum(u * b - d, 0.0)
    u = np.clip((e + t * b) / ab2[None], 0.0, 1.0)
    gap = w + t[..., None] * v[:, None, :] - u[..., None] * ab[None]
    dist = np.linalg.norm(gap, axis=2)
    j = np.argmin(dist, axis=1)
    rows = np.arange(len(p))
    return RayPolyline(np.asarray(dist[rows, j]), p + t[rows, j][:, None] * v, j)


class Solved(NamedTuple):
    """The solved targets of a plan: stacked joints (M x nq, robot order), target points and
    normals (M x 3, NaN rows without a normal), target ids."""

    Q: Array
    P: Array
    N: Array
    ids: Array


def solved_targets(plan: dict[str, Any], robots: list[_Robot]) -> Solved | None:
    """The plan's solved targets (None when it lists no solved solution)."""
    sols = [s for s in plan.get("solutions") or [] if s.get("status") == Status.OK]
    if not sols:
        return None
    tg = {int(t["id"]): t for t in plan["targets"]}
    ids = np.array([int(s["target"]) for s in sols])
    Q = np.hstack([np.array([s["q"][r.name] for s in sols], dtype=float) for r in robots])
    P = np.array([tg[k]["p"] for k in ids], dtype=float)
    N = np.array([tg[k].get("n") or [np.nan] * 3 for k in ids], dtype=float)
    return Solved(Q, P, N, ids)


def matched_deviation(p: Array, v: Array, q: Array, solved: Solved, k: int = 8
                      ) -> tuple[Array, Array]:  # fmt: skip
    """Per sample (rays ``p``, ``v`` M x 3 of stacked joints ``q`` M x nq): the distance (m)
    from its spot to the nearest of the ``k`` solved targets whose configurations are
    nearest in joint space, and that target's row in ``solved``. O(M log n) time, O(M k)
    memory."""
    from scipy.spatial import cKDTree

    kk = min(k, len(solved.Q))
    _, cand = cKDTree(solved.Q).query(q, k=kk)
    cand = np.asarray(cand).reshape(len(q), kk)
    dev = np.full((len(q), kk), np.inf)
    for j in range(kk):
        c = cand[:, j]
        spot = _plane_spots(p, v, solved.P[c], solved.N[c])
        dev[:, j] = np.linalg.norm(spot - solved.P[c], axis=1)
    dev = np.where(np.isfinite(dev), dev, np.inf)
    best = np.argmin(dev, axis=1)
    return dev[np.arange(len(q)), best], cand[np.arange(len(q)), best]


class _Worst(NamedTuple):
    row: int
    joint: int
    value: float  # the table's entry there
    ratio: float  # its ratio to the bound (NaN where the entry is not a number)


def _worst(rows: int, block: Any) -> _Worst:
    """The largest ratio of a derived table of ``rows`` rows that ``block(a, b)`` gives
    (rows a..b: the table, its ratios to their bounds), a block of :data:`CHUNK_ROWS` at a
    time, so that a plan of millions of samples is checked in bounded memory. A NaN ratio
    is the largest (it never passes)."""
    best, best_key = _Worst(0, 0, float("nan"), -np.inf), -np.inf
    for a in range(0, rows, CHUNK_ROWS):
        X, ratio = block(a, min(rows, a + CHUNK_ROWS))
        key = np.where(np.isnan(ratio), np.inf, ratio)  # ratios are >= 0: the first block wins
        i, j = (int(x) for x in np.unravel_index(int(np.argmax(key)), key.shape))
        if key[i, j] > best_key:
            best, best_key = _Worst(a + i, j, float(X[i, j]), float(ratio[i, j])), key[i, j]
    return best


def _limit_finding(code: str, q: Array, order: int, rate: float, bound: Array, slack: float,
                   t: Array, unit: str) -> Finding:  # fmt: skip
    """The largest ``order``-th finite difference of ``q`` (a joint rate) against ``bound``."""

    def block(a: int, b: int) -> tuple[Array, Array]:
        X = np.diff(q[a : b + order], n=order, axis=0) * rate**order
        return X, np.abs(X) / bound[None, :]

    w = _worst(len(q) - order, block)
    i, j = w.row, w.joint
    bad = not w.ratio <= 1 + slack
    msg = f"{code}: max |{w.value:.4g}| {unit} on joint {j} at t = {t[min(i, len(t) - 1)]:.3f} s"
    msg += f" ({100 * w.ratio:.1f}% of limit {float(bound[j]):.4g})"
    return trajectory_finding("error" if bad else "info", code, msg, abs(w.value), float(bound[j]))


def _differences(q: Array, rate: float) -> tuple[Array, Array]:
    """Velocity and acceleration estimates at the interior rows of joint rows ``q`` sampled
    at ``rate``: central first and second differences ((M - 2) x n)."""
    v = (q[2:] - q[:-2]) * (rate / 2)
    a = (q[2:] - 2 * q[1:-1] + q[:-2]) * rate**2
    return v, a


def _declared(r: _Robot, traj: dict[str, Any], q: Array, t: Array, rate: float) -> list[Finding]:
    """Declared qd and qdd against the central differences of q. The bound per joint is
    :data:`DERIVATIVE_SLACK` of the limit plus the differences' own error for a
    jerk-limited motion (j h^2 for qd, j h for qdd at a jerk switch; h = 1/rate)."""
    out: list[Finding] = []
    if len(q) < 3:
        return out
    h, jerk = 1.0 / rate, r.limits.jerk
    for k, key, code, lim, disc, unit in zip(
        (0, 1), ("qd", "qdd"), ("velocity_declared", "acceleration_declared"),
        (r.limits.velocity, r.limits.acceleration), (jerk * h * h, jerk * h),
        ("rad/s", "rad/s^2"), strict=True,
    ):  # fmt: skip
        declared = np.asarray(traj[key][r.name], dtype=float).reshape(q.shape)
        bound = DERIVATIVE_SLACK * lim + disc

        def block(a: int, b: int, k: int = k, declared: Array = declared,
                  bound: Array = bound) -> tuple[Array, Array]:  # fmt: skip
            X = declared[a + 1 : b + 1]
            gap = np.abs(X - _differences(q[a : b + 2], rate)[k]) / bound[None, :]
            return X, np.where(np.isfinite(gap), gap, np.inf)

        w = _worst(len(q) - 2, block)
        i, j, g = w.row, w.joint, w.ratio
        msg = (f"{r.name}: declared {key} on joint {j} at t = {t[i + 1]:.3f} s is {w.value:.4g} "
               f"{unit}, {g * bound[j]:.4g} {unit} off the differences of the "
               f"positions (allowed {bound[j]:.3g} {unit})")  # fmt: skip
        out.append(trajectory_finding("info" if g <= 1.0 else "error", code, msg,
                           float(g * bound[j]), float(bound[j])))  # fmt: skip
    return out


def _position_excess(q: Array, limits: Limits) -> float:
    """The largest excess (rad) of ``q`` over its position limits (negative inside), a
    block of rows at a time."""
    worst = -np.inf
    for a in range(0, len(q), CHUNK_ROWS):
        Q = q[a : a + CHUNK_ROWS]
        worst = max(worst, float(np.maximum(limits.lower - Q, Q - limits.upper).max()))
    return worst


def trajectory_expected(plan: dict[str, Any]) -> bool:
    """Whether the plan must carry a trajectory: it has a solved target and does not say
    ``trajectory_requested: false``."""
    solved = any(s.get("status") == Status.OK for s in plan.get("solutions") or [])
    return solved and plan.get("trajectory_requested") is not False


def check_trajectory(plan: dict[str, Any], tol: Tolerances | None = None) -> list[Finding]:
    """Re-verify ``plan["trajectory"]`` (plan.json mapping) with the scenario's bounds
    (``tol``, default from the plan's scenario): its time grid and joint limits (the spot
    along it: :func:`planner.verify.spot.trajectory_findings`). Errors are violations; info
    findings carry the measured figures (% of joint limits)."""
    scn = plan["scenario"]
    tol = tol or Tolerances.from_scenario(scn)
    traj = plan.get("trajectory")
    if not traj:
        if trajectory_expected(plan):
            return [trajectory_finding("error", "trajectory_missing", "the plan has solved targets but no "
                            "trajectory (and does not say trajectory_requested: false)", 0.0, 1.0)]  # fmt: skip
        return [trajectory_finding("info", "trajectory_absent", "plan has no trajectory")]
    rate = tol.rate
    t = np.asarray(traj["t"], dtype=float)
    out: list[Finding] = []
    dt = np.diff(t)
    if len(dt) and not np.abs(dt - 1 / rate).max() <= TIME_GRID_SLACK / rate:
        out.append(trajectory_finding("error", "time_grid", f"samples not on the 1/{rate:g} s grid "
                           f"(dt in [{dt.min():.6g}, {dt.max():.6g}])", float(dt.max()), 1 / rate))  # fmt: skip
    robots = _robots(scn)
    for r in robots:
        q = np.asarray(traj["q"][r.name], dtype=float)
        if checker_arm(r.model) is None:
            out.append(
                trajectory_finding(
                    "warning", "model_unchecked", f"{r.name}: no numpy model for {r.model}"
                )
            )
        viol = _position_excess(q, r.limits)
        if not viol <= JOINT_SLACK:
            out.append(trajectory_finding("error", "joint_limits", f"{r.name}: position limit exceeded by "
                               f"{viol:.3g} rad", float(viol), 0.0))  # fmt: skip
        for order, (code, unit) in enumerate(
            [("velocity", "rad/s"), ("acceleration", "rad/s^2"), ("jerk", "rad/s^3")], start=1
        ):
            if len(q) > order:
                f = _limit_finding(code, q, order, rate, getattr(r.limits, code), RATE_SLACK,
                                   t, unit)  # fmt: skip
                out.append(replace(f, message=f"{r.name}: {f.message}"))
        out += _declared(r, traj, q, t, rate)
    return out
