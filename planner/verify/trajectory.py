"""Independent re-verification of a plan's trajectory with plain numpy (no CasADi, no
Pinocchio): SPEC section 5 ``beamrelay check``.

Samples the trajectory at the scenario ``rate``; checks the time grid, joint position
limits, velocity/acceleration/jerk by finite differences (with a small slack), and the spot
deviation from the target path at every sample of a ``path`` segment, from the nearest
target during ``dwell`` and at the last sample of every ``approach``/``move`` (arrival),
through the numpy UR DH forward kinematics and mirror reflection model of
:mod:`planner.verify.numpy_beam` (shared with :mod:`planner.verify.check`).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from planner.model.system import Limits
from planner.model.transforms import Array
from planner.verify.numpy_beam import limits_from_dict, pose_matrix, trace_rays, ur5e_dh_fk

NUMPY_FK = {"ur5e": ur5e_dh_fk}  # model -> batched base_T_flange (M x 6 -> M x 4 x 4)


class Finding(NamedTuple):
    """One check result: ``severity`` error | warning | info, a machine ``code``, a message
    with the evidence, the worst ``value`` and the ``limit`` it was compared with."""

    severity: str
    code: str
    message: str
    value: float = float("nan")
    limit: float = float("nan")


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
    """Last ray (origin, unit direction), each (M x 3), after every mirror (SPEC section 3)."""
    world_T_mirrors = [
        r.world_T_base @ NUMPY_FK[r.model](np.atleast_2d(q[r.name])) @ r.flange_T_mirror
        for r in _robots(scenario)
    ]
    rays = trace_rays(pose_matrix(scenario["system"]["laser"]["world_T_laser"]), world_T_mirrors)
    return rays.p, rays.v


def nearest_spots(p: Array, v: Array, targets: Array, normals: Array | None) -> tuple[Array, Array]:
    """Per ray: the index k of the target it passes nearest (ahead of it), and the spot where
    the ray meets that target's plane (its normal, or perpendicular to the ray)."""
    w = targets[None, :, :] - p[:, None, :]
    along = np.einsum("mkj,mj->mk", w, v)
    perp = np.linalg.norm(w - along[..., None] * v[:, None, :], axis=2)
    k = np.argmin(np.where(along > 0, perp, np.inf), axis=1)
    nb = -v if normals is None else np.where(np.isfinite(normals[k]), normals[k], -v)
    s = np.einsum("ij,ij->i", nb, targets[k] - p) / np.einsum("ij,ij->i", nb, v)
    return k, p + s[:, None] * v


def point_deviation(p: Array, v: Array, targets: Array, normals: Array | None) -> Array:
    """Distance (m) from each ray's spot to the nearest target point (dwell, arrivals)."""
    out = np.empty(len(p))
    for i0 in range(0, len(p), 256):
        k, spot = nearest_spots(p[i0 : i0 + 256], v[i0 : i0 + 256], targets, normals)
        out[i0 : i0 + 256] = np.linalg.norm(spot - targets[k], axis=1)
    return out


def spot_deviation(
    p: Array, v: Array, targets: Array, normals: Array | None, closed: bool
) -> Array:
    """Distance (m) from each sample's spot to the target polyline. The spot is where the ray
    meets the plane of the nearest target (its normal, or perpendicular to the ray)."""
    if len(targets) < 2:
        return point_deviation(p, v, targets, normals)
    out = np.empty(len(p))
    segs_a = targets if closed else targets[:-1]
    segs_b = np.roll(targets, -1, axis=0) if closed else targets[1:]
    ab = segs_b - segs_a
    ab2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300)
    for i0 in range(0, len(p), 256):
        _, spot = nearest_spots(p[i0 : i0 + 256], v[i0 : i0 + 256], targets, normals)
        u = np.clip(np.einsum("mkj,kj->mk", spot[:, None, :] - segs_a[None], ab) / ab2, 0, 1)
        near = segs_a[None] + u[..., None] * ab[None]
        out[i0 : i0 + 256] = np.linalg.norm(spot[:, None, :] - near, axis=2).min(axis=1)
    return out


def _limit_finding(code: str, X: Array, bound: Array, slack: float, t: Array, unit: str) -> Finding:
    ratio = np.abs(X) / bound[None, :]
    i, j = (int(x) for x in np.unravel_index(int(np.argmax(ratio)), ratio.shape))
    worst, lim = float(abs(X[i, j])), float(bound[j])
    bad = ratio[i, j] > 1 + slack
    msg = f"{code}: max |{X[i, j]:.4g}| {unit} on joint {j} at t = {t[min(i, len(t) - 1)]:.3f} s"
    msg += f" ({100 * ratio[i, j]:.1f}% of limit {lim:.4g})"
    return Finding("error" if bad else "info", code, msg, worst, lim)


def check_trajectory(
    plan: dict[str, Any],
    deviation_tol: float = 5e-5,
    slack: float = 0.02,
    rel_duration: float = 0.1,
) -> list[Finding]:
    """Re-verify ``plan["trajectory"]`` (plan.json mapping). Errors are violations; info
    findings carry the measured figures (max deviation, duration, % of joint limits)."""
    traj = plan.get("trajectory")
    if not traj:
        return [Finding("info", "trajectory_absent", "plan has no trajectory")]
    scn = plan["scenario"]
    rate = float((scn.get("trajectory") or {}).get("rate", 500.0))
    t = np.asarray(traj["t"], dtype=float)
    out: list[Finding] = []
    dt = np.diff(t)
    if len(dt) and np.abs(dt - 1 / rate).max() > 1e-6 / rate:
        out.append(Finding("error", "time_grid", f"samples not on the 1/{rate:g} s grid "
                           f"(dt in [{dt.min():.6g}, {dt.max():.6g}])", float(dt.max()), 1 / rate))  # fmt: skip
    robots = _robots(scn)
    for r in robots:
        q = np.asarray(traj["q"][r.name], dtype=float)
        if r.model not in NUMPY_FK:
            out.append(
                Finding("warning", "model_unchecked", f"{r.name}: no numpy model for {r.model}")
            )
        lo, hi = r.limits.lower, r.limits.upper
        viol = np.maximum(lo - q, q - hi).max()
        if viol > 1e-9:
            out.append(Finding("error", "joint_limits", f"{r.name}: position limit exceeded by "
                               f"{viol:.3g} rad", float(viol), 0.0))  # fmt: skip
        for order, (code, unit) in enumerate(
            [("velocity", "rad/s"), ("acceleration", "rad/s^2"), ("jerk", "rad/s^3")], start=1
        ):
            X = np.diff(q, n=order, axis=0) * rate**order
            if len(X):
                f = _limit_finding(f"{code}", X, getattr(r.limits, code), slack, t, unit)
                out.append(f._replace(message=f"{r.name}: {f.message}"))
    out += _check_spot(plan, robots, t, deviation_tol, rel_duration)
    return out


def _check_spot(
    plan: dict[str, Any], robots: list[_Robot], t: Array, tol: float, rel_duration: float
) -> list[Finding]:
    traj, scn = plan["trajectory"], plan["scenario"]
    if any(r.model not in NUMPY_FK for r in robots) or not plan.get("targets"):
        return []
    P = np.array([tg["p"] for tg in plan["targets"]], dtype=float)
    N = [tg.get("n") for tg in plan["targets"]]
    normals = None if all(n is None for n in N) else np.array(
        [n if n is not None else [np.nan] * 3 for n in N], dtype=float)  # fmt: skip
    path_spec = (scn.get("targets") or {}).get("path")
    closed = bool(path_spec.get("closed", False)) if isinstance(path_spec, dict) else False
    out: list[Finding] = []
    segments = traj.get("segments", [])
    arrivals = np.zeros(len(t), dtype=bool)
    for s in segments:
        if s["kind"] in ("approach", "move"):
            arrivals[int(np.argmin(np.abs(t - s["t1"])))] = True
    for kind in ("path", "dwell", "arrival"):
        mask = arrivals.copy() if kind == "arrival" else np.zeros(len(t), dtype=bool)
        for s in segments:
            if s["kind"] == kind:
                mask |= (t >= s["t0"] - 1e-9) & (t <= s["t1"] + 1e-9)
        if not mask.any():
            continue
        q = {r.name: np.asarray(traj["q"][r.name], dtype=float)[mask] for r in robots}
        p, v = trace_last_ray(scn, q)
        if kind == "path":
            dev = spot_deviation(p, v, P, normals, closed)
        else:
            dev = point_deviation(p, v, P, normals)
        i = int(np.argmax(dev))
        msg = (f"{kind}: max spot deviation {1e3 * dev[i]:.4f} mm at t = {t[mask][i]:.3f} s "
               f"(tolerance {1e3 * tol:.4f} mm, {mask.sum()} samples)")  # fmt: skip
        out.append(Finding("error" if dev[i] > tol else "info", f"{kind}_deviation", msg,
                           float(dev[i]), tol))  # fmt: skip
    if path_spec is not None:
        speed = float((scn.get("trajectory") or {}).get("spot_speed", 0.02))
        length = float(np.linalg.norm(np.diff(P, axis=0), axis=1).sum())
        length += float(np.linalg.norm(P[0] - P[-1])) if closed else 0.0
        spent = sum(s["t1"] - s["t0"] for s in traj.get("segments", []) if s["kind"] == "path")
        ideal = length / speed
        sev = "warning" if abs(spent - ideal) > rel_duration * ideal else "info"
        out.append(Finding(sev, "path_duration", f"path segments last {spent:.3f} s; length "
                           f"{1e3 * length:.1f} mm / {1e3 * speed:.1f} mm/s = {ideal:.3f} s",
                           spent, ideal))  # fmt: skip
    return out
