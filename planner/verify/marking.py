"""The laser gate of a plan, re-verified with plain numpy (a check of ``beamrelay check``).

``trajectory.laser_on`` lists the intervals (s) in which the laser is on. The checks: the
gate is on only inside ``path`` and ``dwell`` segments and on in all of them (so it is off
at every sample of an approach, move, run-in or run-out); at every laser-on sample the spot
is within the path tolerance of the path (of the scenario's own polyline as well, unless
``smooth``) or of its target while dwelling; and on a path the spot moves at the spot speed
within :data:`SPEED_SLACK` at every laser-on sample, first and last included (so a mark
never starts or stops from rest), except inside a reported slowdown (where it may only be
slower). The marked speeds also give the exposure (:func:`exposure`): fluence along the
path is power / speed (J/m), energy per dwell is power x dwell time (J). World frame, SI.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from planner.model.transforms import Array
from planner.verify.arm_models import checker_arm
from planner.verify.context import CheckResult, PlanContext, times
from planner.verify.findings import Finding
from planner.verify.numpy_beam import pose_matrix
from planner.verify.spot import Mask, segment_mask
from planner.verify.trajectory import (
    _robots,
    nearest_spots,
    ray_polyline_closest,
    spot_deviation,
    trace_last_ray,
)

SPEED_SLACK = 0.02  # fraction: the marked spot speed may differ this much from spot_speed
EDGE_SLACK = 1e-9  # s: a laser interval may reach this far beyond its segment
EXPOSURE_SLACK = 1e-4  # relative: marked speeds from joints written to 1e-10 rad, 40 um steps
MARK_KINDS = ("path", "dwell")
DARK_KINDS = ("approach", "move", "run_in", "run_out")


def laser_mask(t: Array, laser_on: Any) -> Mask:
    """Samples of the time grid ``t`` (s, sorted) at which the gate is on (closed intervals)."""
    d = np.zeros(len(t) + 1, dtype=np.int64)
    for t0, t1 in laser_on or []:
        d[np.searchsorted(t, float(t0) - EDGE_SLACK, "left")] += 1
        d[np.searchsorted(t, float(t1) + EDGE_SLACK, "right")] -= 1
    return np.asarray(np.cumsum(d[:-1]) > 0)


def _targets(plan: dict[str, Any]) -> tuple[Array, Array | None]:
    P = np.array([tg["p"] for tg in plan["targets"]], dtype=float).reshape(-1, 3)
    N = [tg.get("n") for tg in plan["targets"]]
    if all(n is None for n in N):
        return P, None
    return P, np.array([n if n is not None else [np.nan] * 3 for n in N], dtype=float)


def _segments(P: Array, closed: bool) -> tuple[Array, Array, Array]:
    a = P if closed else P[:-1]
    ab = (np.roll(P, -1, axis=0) if closed else P[1:]) - a
    return a, ab, np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300)


def path_planes(P: Array, closed: bool) -> Array:
    """Unit normal (K x 3) of the plane through each sample of a path and its neighbours
    (the path's osculating plane; a planar path's own plane), taken from the nearest sample
    where the path turns; NaN everywhere on a straight path."""
    K = len(P)
    n = np.full((K, 3), np.nan)
    if K < 3:
        return n
    back, ahead = P - np.roll(P, 1, axis=0), np.roll(P, -1, axis=0) - P
    c = np.cross(back, ahead)
    size = np.linalg.norm(c, axis=1)
    turns = size > 1e-6 * np.linalg.norm(back, axis=1) * np.linalg.norm(ahead, axis=1)
    if not closed:
        turns[[0, -1]] = False
    at = np.flatnonzero(turns)
    if not len(at):
        return n
    k = np.clip(np.searchsorted(at, np.arange(K)), 1, len(at) - 1) if len(at) > 1 else None
    nearest = (
        np.zeros(K, dtype=int)
        if k is None
        else np.where(
            np.abs(at[k] - np.arange(K)) < np.abs(at[k - 1] - np.arange(K)), at[k], at[k - 1]
        )
    )
    return np.asarray(c[nearest] / size[nearest, None])


def spots_on_path(p: Array, v: Array, P: Array, N: Array | None, closed: bool) -> Array:
    """The spot of each ray (M x 3) on a path of samples ``P``: where it meets the plane of
    the nearest sample (with normals); without normals, where it meets the path's plane at
    its nearest segment (:func:`path_planes`: exact for a planar path, whatever the chord
    between two samples cuts off a curve), else (a straight path, a grazing ray) its point
    of closest approach to the polyline."""
    if N is not None or len(P) < 2:
        return nearest_spots(p, v, P, N)[1]
    a, ab, ab2 = _segments(P, closed)
    plane = path_planes(P, closed)
    out = np.empty_like(p)
    step = max(1, (1 << 21) // max(len(P), 1))
    for i0 in range(0, len(p), step):
        sl = slice(i0, i0 + step)
        near = ray_polyline_closest(p[sl], v[sl], a, ab, ab2)
        n = plane[near.segment]
        with np.errstate(invalid="ignore", divide="ignore"):
            vn = np.einsum("ij,ij->i", v[sl], n)
            on = p[sl] + (np.einsum("ij,ij->i", a[near.segment] - p[sl], n) / vn)[:, None] * v[sl]
        use = np.isfinite(on).all(axis=1) & (np.abs(vn) > 0.05)
        use &= np.linalg.norm(on - near.point, axis=1) < np.sqrt(ab2[near.segment])
        out[sl] = np.where(use[:, None], on, near.point)
    return out


def _path_spec(scn: dict[str, Any]) -> dict[str, Any] | None:
    spec = (scn.get("targets") or {}).get("path")
    return spec if isinstance(spec, dict) else None


def laser_on_rays(plan: dict[str, Any], on: Mask) -> tuple[Array, Array] | None:
    """The last ray (origins, unit directions, each L x 3) at the laser-on samples ``on`` of
    a path plan's trajectory; None when the plan has no path or no trajectory, no sample is
    on, or an arm has no numpy model."""
    traj, scn = plan.get("trajectory") or {}, plan["scenario"]
    robots = _robots(scn)
    if _path_spec(scn) is None or not traj or not on.any():
        return None
    if any(checker_arm(r.model) is None for r in robots):
        return None
    return trace_last_ray(scn, {r.name: np.asarray(traj["q"][r.name], dtype=float)[on]
                                for r in robots})  # fmt: skip


def marked_speeds(plan: dict[str, Any], rays: tuple[Array, Array] | None = None
                  ) -> tuple[Array, Array, Array] | None:  # fmt: skip
    """Spot speed (m/s) over every step between consecutive laser-on samples of a path plan,
    the step's start time (s) and the marked arc length there (m, cumulated over the
    marks). None when the plan has no path, no laser-on step or an arm without a numpy
    model. ``rays``: the :func:`laser_on_rays` of the plan, when already traced."""
    traj = plan.get("trajectory") or {}
    spec = _path_spec(plan["scenario"])
    if spec is None or not traj:
        return None
    t = np.asarray(traj["t"], dtype=float)
    on = laser_mask(t, traj.get("laser_on"))
    step = on[:-1] & on[1:]
    if not step.any():
        return None
    if rays is None:
        rays = laser_on_rays(plan, on)
    if rays is None:  # an arm without a numpy model
        return None
    p, v = rays
    idx = np.flatnonzero(on)
    P, N = _targets(plan)
    spot = np.full((len(t), 3), np.nan)
    spot[idx] = spots_on_path(p, v, P, N, bool(spec.get("closed", False)))
    i = np.flatnonzero(step)
    ds = np.linalg.norm(spot[i + 1] - spot[i], axis=1)
    return ds / (t[i + 1] - t[i]), t[i], np.cumsum(ds) - ds


def exposure(plan: dict[str, Any], power: float | None) -> dict[str, float | None] | None:
    """``metrics.exposure`` of a plan for a laser of ``power`` W (None without one): fluence
    along the path (J/m) at its smallest and largest over the marked steps, and the energy
    per dwell (J, the scenario's dwell on points)."""
    if power is None:
        return None
    return _exposure(plan, power, marked_speeds(plan))


def _exposure(plan: dict[str, Any], power: float, speeds: tuple[Array, Array, Array] | None
              ) -> dict[str, float | None]:  # fmt: skip
    """:func:`exposure` from the plan's :func:`marked_speeds`."""
    out: dict[str, float | None] = {"fluence_min": None, "fluence_max": None, "dwell_energy": None}
    if speeds is not None and len(speeds[0]):
        v = speeds[0]
        out["fluence_min"] = float(power / v.max())
        out["fluence_max"] = float(power / v.min()) if v.min() > 0 else None  # at rest: no bound
    dwell = float((plan["scenario"].get("trajectory") or {}).get("dwell") or 0.0)
    if _path_spec(plan["scenario"]) is None and dwell > 0:
        out["dwell_energy"] = float(power * dwell)
    return out


def scenario_polyline(scn: dict[str, Any]) -> Array | None:
    """The scenario's own path vertices in the world frame (camera-frame paths through a
    fixed camera's pose), or None (no path, a smooth one, or a camera on a flange)."""
    spec = _path_spec(scn)
    tg = scn.get("targets") or {}
    if spec is None or spec.get("smooth"):
        return None
    V = np.asarray(spec["points"], dtype=float).reshape(-1, 3)
    if tg.get("frame", "world") == "camera":
        cam = (scn.get("system") or {}).get("camera") or {}
        if "world_T_camera" not in cam:
            return None
        T = pose_matrix(cam["world_T_camera"])
        V = V @ T[:3, :3].T + T[:3, 3]
    return np.vstack([V, V[:1]]) if spec.get("closed") else V


def _kind_at(segments: list[dict[str, Any]], t: float, kinds: tuple[str, ...]) -> str:
    for s in segments:
        if s["kind"] in kinds and float(s["t0"]) - EDGE_SLACK <= t <= float(s["t1"]) + EDGE_SLACK:
            return str(s["kind"])
    return "no segment"


def _gate_findings(
    t: Array, on: Mask, segments: list[dict[str, Any]]
) -> list[tuple[str, float, float]]:
    """(message, value, bound): the laser on outside path/dwell segments, or off inside."""
    mark = segment_mask(t, segments, "path") | segment_mask(t, segments, "dwell")
    out = []
    for bad, what in ((on & ~mark, "on"), (mark & ~on, "off")):
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            kind = _kind_at(segments, float(t[i]), DARK_KINDS if what == "on" else MARK_KINDS)
            out.append((f"laser {what} during {kind} at t = {t[i]:.3f} s ({int(bad.sum())} "
                        f"sample(s))", float(bad.sum()), 0.0))  # fmt: skip
    return out


def _deviation(plan: dict[str, Any], t: Array, on: Mask, rays: tuple[Array, Array] | None
               ) -> dict[str, tuple[float, float]]:  # fmt: skip
    """Largest distance (m) of the spot at laser-on samples (their ``rays``,
    :func:`laser_on_rays`) from the sampled path and from the scenario's own polyline, with
    the time (s) where it occurs."""
    scn = plan["scenario"]
    spec = _path_spec(scn)
    if spec is None or rays is None:
        return {}
    p, v = rays
    P, N = _targets(plan)
    closed = bool(spec.get("closed", False))
    out = {}
    dev = spot_deviation(p, v, P, N, closed)
    out["laser_on_deviation_max_m"] = (float(dev.max()), float(t[on][int(dev.argmax())]))
    V = scenario_polyline(scn)
    if V is not None and len(V) >= 2:
        a, ab, ab2 = _segments(V, False)
        if N is None:
            dv = ray_polyline_closest(p, v, a, ab, ab2)[0]
        else:
            spot = nearest_spots(p, v, P, N)[1]
            dv = point_deviation_to_segments(spot, a, ab, ab2)
        out["polyline_deviation_max_m"] = (float(dv.max()), float(t[on][int(dv.argmax())]))
    return out


def point_deviation_to_segments(x: Array, a: Array, ab: Array, ab2: Array) -> Array:
    """Distance (m) of each point (M x 3) to the nearest of segments ``a + u ab``."""
    u = np.clip(np.einsum("mkj,kj->mk", x[:, None, :] - a[None], ab) / ab2, 0, 1)
    return np.asarray(np.linalg.norm(x[:, None, :] - (a[None] + u[..., None] * ab[None]),
                                     axis=2).min(axis=1))  # fmt: skip


def _speed_findings(plan: dict[str, Any], rate: float, speeds: tuple[Array, Array, Array] | None
                    ) -> tuple[list[tuple[str, float, float]], dict[str, float]]:  # fmt: skip
    """Marked speed (the plan's :func:`marked_speeds`) against the spot speed (reported
    slowdowns may be slower only)."""
    if speeds is None:
        return [], {}
    v, ts, _ = speeds
    v0 = float((plan["scenario"].get("trajectory") or {}).get("spot_speed", 0.02))
    ratio = v / v0
    slow = np.zeros(len(ts), dtype=bool)
    for sd in plan["trajectory"].get("slowdowns") or []:
        slow |= (ts >= float(sd["t0"]) - 1.5 / rate) & (ts <= float(sd["t1"]) + 1.5 / rate)
    bad = (ratio > 1 + SPEED_SLACK) | ((ratio < 1 - SPEED_SLACK) & ~slow)
    figures = {"marked_speed_min_ratio": float(ratio.min()),
               "marked_speed_max_ratio": float(ratio.max())}  # fmt: skip
    if not bad.any():
        return [], figures
    i = int(np.flatnonzero(bad)[np.argmax(np.abs(ratio[bad] - 1))])
    starts = {float(t0) for t0, _ in plan["trajectory"]["laser_on"]}
    ends = {float(t1) for _, t1 in plan["trajectory"]["laser_on"]}
    first = [k for k in np.flatnonzero(bad) if any(abs(ts[k] - s) < 0.5 / rate for s in starts)]
    last = [
        k for k in np.flatnonzero(bad) if any(abs(ts[k] + 1 / rate - e) < 0.5 / rate for e in ends)
    ]
    msg = (f"marked spot speed {1e3 * v[i]:.3f} mm/s ({100 * ratio[i]:.1f}% of "
           f"{1e3 * v0:.3f} mm/s) at t = {ts[i]:.3f} s, {int(bad.sum())} step(s) beyond "
           f"{100 * SPEED_SLACK:g}% outside a reported slowdown")  # fmt: skip
    if first:
        msg += f"; a mark starts at {100 * ratio[first[0]]:.1f}% of the speed (t = {ts[first[0]]:.3f} s)"
    if last:
        msg += (
            f"; a mark ends at {100 * ratio[last[-1]]:.1f}% of the speed (t = {ts[last[-1]]:.3f} s)"
        )
    return [(msg, float(v[i]), v0)], figures


def _exposure_findings(plan: dict[str, Any], speeds: tuple[Array, Array, Array] | None
                       ) -> list[tuple[str, float, float]]:  # fmt: skip
    """``metrics.exposure`` against the one recomputed from the trajectory (its
    :func:`marked_speeds`) and power."""
    reported = (plan.get("metrics") or {}).get("exposure")
    power = ((plan["scenario"].get("system") or {}).get("laser") or {}).get("power")
    want = None if power is None else _exposure(plan, float(power), speeds)
    if reported is None and want is None:
        return []
    if reported is None or want is None:
        return [(f"metrics.exposure is {reported}, the plan gives {want}", 0.0, 0.0)]
    out = []
    for key, exp in want.items():
        got = reported.get(key)
        if (got is None) != (exp is None) or (
            got is not None and exp is not None and abs(got - exp) > EXPOSURE_SLACK * abs(exp)
        ):
            out.append((f"metrics.exposure.{key} is {got}, the plan gives {exp}",
                        float("nan") if got is None else float(got),
                        float("nan") if exp is None else float(exp)))  # fmt: skip
    return out


def check_marking(ctx: PlanContext) -> CheckResult:
    """The laser gate against the segments, the spot on the path at every laser-on sample,
    and the marked speed (see the module docstring)."""
    traj = ctx.plan.get("trajectory") or {}
    res = CheckResult("laser", 0)
    t = times(ctx.plan)
    if not len(t):
        return res
    if "laser_on" not in traj:
        res.findings.append(
            Finding("laser", None, "trajectory has no laser_on intervals", 0.0, 1.0)
        )
        return res
    on = laser_mask(t, traj["laser_on"])
    res.checked = int(on.sum())
    found = _gate_findings(t, on, list(traj.get("segments") or []))
    figures: dict[str, float] = {"laser_on_s": float(sum(b - a for a, b in traj["laser_on"]))}
    rays = laser_on_rays(ctx.plan, on)  # traced once for the deviation and the marked speeds
    for key, (value, at) in _deviation(ctx.plan, t, on, rays).items():
        figures[key] = value
        if not ctx.tol.deviation_ok(value):
            what = "the path" if key.startswith("laser") else "the scenario's polyline"
            found.append((f"laser on with the spot {1e3 * value:.4f} mm from {what} at t = "
                          f"{at:.3f} s (tolerance {1e3 * ctx.tol.path:.4f} mm)", value, ctx.tol.path))  # fmt: skip
    speeds = marked_speeds(ctx.plan, rays)
    speed, speed_figures = _speed_findings(ctx.plan, ctx.tol.rate, speeds)
    found += speed + _exposure_findings(ctx.plan, speeds)
    figures |= speed_figures
    res.findings += [Finding("laser", None, m, value, bound) for m, value, bound in found]
    res.figures = figures
    return res
