"""The spot along a plan's trajectory, re-verified with plain numpy (with the joint-limit
checks of :func:`planner.verify.trajectory.check_trajectory`: :func:`trajectory_findings`).

On ``path`` segments the spot stays within ``trajectory.path_tolerance`` of the target
polyline; during ``dwell`` and at the last sample of every ``approach``/``move`` (arrival) it
is within that tolerance of a target (matched through the solved configurations); every
solved point target is arrived at; the time on the path is about length / spot speed.
Segment masks are built in linear time (:func:`segment_mask`).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
import numpy.typing as npt

from planner.model.transforms import Array
from planner.verify.arm_models import checker_arm
from planner.verify.findings import Finding, Severity, trajectory_finding
from planner.verify.tolerances import Tolerances
from planner.verify.trajectory import (
    Solved,
    _plane_spots,
    _Robot,
    _robots,
    check_trajectory,
    matched_deviation,
    point_deviation,
    solved_targets,
    spot_deviation,
    trace_last_ray,
)
from schemas import defaults

Mask = npt.NDArray[np.bool_]
REL_DURATION = 0.1  # path segments lasting more than 10 % off length / speed: a warning


def segment_mask(t: Array, segments: Iterable[Mapping[str, Any]], kind: str) -> Mask:
    """Samples of the time grid ``t`` (s, sorted) inside segments of one kind (ends
    included, 1e-9 s slack); O(len(t) + segments)."""
    d = np.zeros(len(t) + 1, dtype=np.int64)
    for s in segments:
        if s["kind"] == kind:
            d[np.searchsorted(t, float(s["t0"]) - 1e-9, "left")] += 1
            d[np.searchsorted(t, float(s["t1"]) + 1e-9, "right")] -= 1
    return np.asarray(np.cumsum(d[:-1]) > 0)


def arrival_mask(t: Array, segments: Iterable[Mapping[str, Any]]) -> Mask:
    """The sample nearest the end of every ``approach``/``move`` segment that arrives on a
    target (not one that ends where a ``run_in`` starts, off the path on its extension)."""
    segs = list(segments)
    nxt = [s["kind"] for s in segs[1:]] + [None] * bool(segs)
    ends = np.array([float(s["t1"]) for s, n in zip(segs, nxt, strict=True)
                     if s["kind"] in ("approach", "move") and n != "run_in"])  # fmt: skip
    mask = np.zeros(len(t), dtype=bool)
    if len(ends) and len(t):
        i = np.clip(np.searchsorted(t, ends), 1, max(len(t) - 1, 1))
        i = np.where(np.abs(t[i - 1] - ends) <= np.abs(t[i] - ends), i - 1, i)
        mask[i] = True
    return mask


def _targets(plan: dict[str, Any]) -> tuple[Array, Array | None]:
    P = np.array([tg["p"] for tg in plan["targets"]], dtype=float)
    N = [tg.get("n") for tg in plan["targets"]]
    if all(n is None for n in N):
        return P, None
    return P, np.array([n if n is not None else [np.nan] * 3 for n in N], dtype=float)


def trajectory_findings(plan: dict[str, Any], tol: Tolerances | None = None) -> list[Finding]:
    """Every finding on ``plan["trajectory"]``: its time grid and joint limits
    (:func:`~planner.verify.trajectory.check_trajectory`), then the spot along it."""
    tol = tol or Tolerances.from_scenario(plan["scenario"])
    out = check_trajectory(plan, tol)
    traj = plan.get("trajectory")
    if traj:
        t = np.asarray(traj["t"], dtype=float)
        out += check_spot(plan, _robots(plan["scenario"]), t, tol)
    return out


def check_spot(plan: dict[str, Any], robots: list[_Robot], t: Array, tol: Tolerances
               ) -> list[Finding]:  # fmt: skip
    """Spot findings of a plan's trajectory (see the module docstring)."""

    traj, scn = plan["trajectory"], plan["scenario"]
    if any(checker_arm(r.model) is None for r in robots) or not plan.get("targets"):
        return []
    P, normals = _targets(plan)
    path_spec = (scn.get("targets") or {}).get("path")
    closed = bool(path_spec.get("closed", False)) if isinstance(path_spec, dict) else False
    solved = solved_targets(plan, robots)
    segments = traj.get("segments", [])
    Qall = np.hstack([np.asarray(traj["q"][r.name], dtype=float) for r in robots])
    out: list[Finding] = []
    arrivals = arrival_mask(t, segments)
    for kind in ("path", "dwell", "arrival"):
        mask = arrivals if kind == "arrival" else segment_mask(t, segments, kind)
        if not mask.any():
            continue
        q = {r.name: np.asarray(traj["q"][r.name], dtype=float)[mask] for r in robots}
        p, v = trace_last_ray(scn, q)
        if kind == "path":
            dev = spot_deviation(p, v, P, normals, closed)
        elif solved is not None:
            dev, _ = matched_deviation(p, v, Qall[mask], solved)
        else:
            dev = point_deviation(p, v, P, normals)
        i = int(np.argmax(np.where(np.isfinite(dev), dev, np.inf)))
        msg = (f"{kind}: max spot deviation {1e3 * dev[i]:.4f} mm at t = {t[mask][i]:.3f} s "
               f"(tolerance {1e3 * tol.path:.4f} mm, {mask.sum()} samples)")  # fmt: skip
        out.append(trajectory_finding("info" if tol.deviation_ok(dev[i]) else "error", f"{kind}_deviation",
                           msg, float(dev[i]), tol.path))  # fmt: skip
        if kind == "arrival" and path_spec is None and solved is not None:
            out += _unvisited(p, v, Qall[mask], t[mask], solved, tol)
    if isinstance(path_spec, dict):
        out.append(_path_duration(scn, P, closed, segments))
    return out


def _unvisited(p: Array, v: Array, Qa: Array, ta: Array, solved: Solved, tol: Tolerances
               ) -> list[Finding]:  # fmt: skip
    """Solved targets that no arrival reaches: for each, the arrival nearest in joint space
    must put the spot within the path tolerance of it."""
    from scipy.spatial import cKDTree

    _, j = cKDTree(Qa).query(solved.Q)
    j = np.asarray(j, dtype=int)
    spot = _plane_spots(p[j], v[j], solved.P, solved.N)
    dev = np.linalg.norm(spot - solved.P, axis=1)
    bad = np.flatnonzero(~(dev <= tol.path))
    if not len(bad):
        return [trajectory_finding("info", "not_visited", f"every one of {len(solved.Q)} solved targets "
                        "is arrived at", 0.0, 0.0)]  # fmt: skip
    k = int(bad[0])
    ids = ", ".join(str(int(x)) for x in solved.ids[bad[:5]])
    return [trajectory_finding("error", "not_visited", f"{len(bad)} solved target(s) never reached by the "
                    f"trajectory (targets {ids}{', ...' if len(bad) > 5 else ''}; target "
                    f"{int(solved.ids[k])}: nearest arrival at t = {ta[j[k]]:.3f} s puts the spot "
                    f"{1e3 * dev[k]:.3g} mm away)", float(len(bad)), 0.0)]  # fmt: skip


def _path_duration(scn: dict[str, Any], P: Array, closed: bool, segments: list[Any]) -> Finding:
    speed = float((scn.get("trajectory") or {}).get("spot_speed", defaults.SPOT_SPEED_MPS))
    length = float(np.linalg.norm(np.diff(P, axis=0), axis=1).sum())
    length += float(np.linalg.norm(P[0] - P[-1])) if closed else 0.0
    spent = sum(s["t1"] - s["t0"] for s in segments if s["kind"] == "path")
    ideal = length / speed
    sev: Severity = "warning" if abs(spent - ideal) > REL_DURATION * ideal else "info"
    return trajectory_finding(sev, "path_duration", f"path segments last {spent:.3f} s; length "
                   f"{1e3 * length:.1f} mm / {1e3 * speed:.1f} mm/s = {ideal:.3f} s",
                   spent, ideal)  # fmt: skip
