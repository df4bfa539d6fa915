"""``metrics`` of a plan: computed once from per-target figures (:func:`summary_metrics`,
used by planning to write them) and recomputed from a written plan document to check them
(:func:`metric_findings`, used by ``beamrelay check``). Errors in m, times in s, ratios are
fractions of the joint limits.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

import numpy as np

from planner.model.status import Status
from planner.verify.context import times
from planner.verify.numpy_beam import limits_from_dict
from planner.verify.spot import segment_mask
from planner.verify.tolerances import METRIC_SLACK

RATIO_SLACK = 1e-9  # absolute, on ratios recomputed from qd/qdd rounded to 1e-10 in the file


def summary_metrics(
    errors: Iterable[float], solve_times: Iterable[float], reasons: Iterable[str | None],
    n_targets: int, duration: float | None,
) -> dict[str, Any]:  # fmt: skip
    """``metrics`` from the solved targets' spot errors (m) and solve times (s), the failed
    targets' reasons, the target count and the trajectory duration (s, None without one):
    medians over solved targets, None when nothing was solved."""
    err = np.asarray(list(errors), dtype=float)
    dt = np.asarray(list(solve_times), dtype=float)
    failures: dict[str, float] = {}
    for reason in reasons:
        failures[f"failed_{reason}"] = failures.get(f"failed_{reason}", 0) + 1
    ok = len(err) > 0
    return {
        "n_targets": int(n_targets),
        "n_ok": len(err),
        "error_max": float(err.max()) if ok else None,
        "error_median": float(np.median(err)) if ok else None,
        "solve_time_median": float(np.median(dt)) if ok else None,
        "solve_time_p95": float(np.percentile(dt, 95)) if ok else None,
        "duration": duration,
        "extra": failures,
    }


def _recomputed(plan: dict[str, Any]) -> dict[str, Any]:
    """The metrics a plan document implies (the ``extra`` figures that can be recomputed)."""
    sols = plan["solutions"]
    ok = [s for s in sols if s.get("status") == Status.OK]
    t = times(plan)
    out = summary_metrics([float(s.get("error") or 0.0) for s in ok],
                          [float(s.get("solve_time") or 0.0) for s in ok],
                          [s.get("reason") for s in sols if s.get("status") != Status.OK],
                          len(sols), float(t[-1]) if len(t) else None)  # fmt: skip
    out["extra"] |= _trajectory_figures(plan) if len(t) else {}
    return out


def _trajectory_figures(plan: dict[str, Any]) -> dict[str, float]:
    """Largest |qd|, |qdd| as fractions of the limits (also on the path), time on the path
    and the path's length, from the written trajectory and targets."""
    traj, scn = plan["trajectory"], plan["scenario"]
    t = np.asarray(traj["t"], dtype=float)
    on_path = segment_mask(t, traj.get("segments", []), "path")
    v = a = vp = 0.0
    for r in scn["system"]["robots"]:
        qd = np.asarray(traj["qd"][r["name"]], dtype=float)
        lim = limits_from_dict(r.get("limits"), qd.shape[1])
        v = max(v, float((np.abs(qd) / lim.velocity).max()))
        a = max(a, float((np.abs(np.asarray(traj["qdd"][r["name"]])) / lim.acceleration).max()))
        if on_path.any():
            vp = max(vp, float((np.abs(qd[on_path]) / lim.velocity).max()))
    out = {"joint_speed_max_ratio": v, "joint_acceleration_max_ratio": a}
    if on_path.any():
        out["path_joint_speed_max_ratio"] = vp
    if isinstance((scn.get("targets") or {}).get("path"), dict):
        P = np.array([tg["p"] for tg in plan["targets"]], dtype=float).reshape(-1, 3)
        seg = np.linalg.norm(np.diff(P, axis=0), axis=1)
        out["path_length"] = float(np.concatenate([[0.0], np.cumsum(seg)])[-1])
        out["path_time"] = float(sum(s["t1"] - s["t0"] for s in traj.get("segments", [])
                                     if s["kind"] == "path"))  # fmt: skip
    return out


def _differs(reported: Any, expected: Any, abs_tol: float) -> bool:
    if reported is None or expected is None:
        return reported is not expected
    try:
        return not math.isclose(float(reported), float(expected), rel_tol=METRIC_SLACK,
                                abs_tol=abs_tol)  # fmt: skip
    except (TypeError, ValueError):
        return True


def metric_findings(plan: dict[str, Any]) -> list[tuple[str, float, float]]:
    """(message, reported, recomputed) for every metric of ``plan`` that differs from the one
    recomputed from its solutions and trajectory (``n_targets`` also against ``targets``)."""
    m = plan.get("metrics") or {}
    want = _recomputed(plan)
    out: list[tuple[str, float, float]] = []

    def add(key: str, got: Any, exp: Any) -> None:
        g = float("nan") if got is None else float(got)
        e = float("nan") if exp is None else float(exp)
        out.append((f"metrics.{key} is {got}, the plan gives {exp}", g, e))

    if len(plan.get("targets") or []) != len(plan["solutions"]):
        add("n_targets", len(plan.get("targets") or []), len(plan["solutions"]))
    for key in ("n_targets", "n_ok", "error_max", "error_median", "solve_time_median",
                "solve_time_p95", "duration"):  # fmt: skip
        if _differs(m.get(key), want[key], 0.0):
            add(key, m.get(key), want[key])
    extra = m.get("extra") or {}
    failed = {k for k in extra if k.startswith("failed_")} | {k for k in want["extra"]
                                                              if k.startswith("failed_")}  # fmt: skip
    for key in sorted(failed):
        if _differs(extra.get(key), want["extra"].get(key), 0.0):
            add(f"extra.{key}", extra.get(key), want["extra"].get(key))
    for key, exp in want["extra"].items():
        if (
            not key.startswith("failed_")
            and key in extra
            and _differs(extra[key], exp, RATIO_SLACK)
        ):
            add(f"extra.{key}", extra[key], exp)
    return out
