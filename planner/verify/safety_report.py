"""Keep-out figures of a plan (what ``make demo`` prints for the face scenario), from the
checker's numpy geometry: per keep-out volume, the targets inside it, how many failed as
``keep_out``, and how close the beam came at the solved targets and while the laser was on.
World frame, metres."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from planner.model.transforms import Array
from planner.verify import batch_distances as bd
from planner.verify.context import PlanContext, spots, times
from planner.verify.safety import Setup, laser_mask, polylines, target_hits
from planner.verify.safety_shapes import Shape


def _beam_distance(v: Shape, P: Array) -> Array:
    """Per beam (P: M x S x 3) its least distance (m) to keep-out volume ``v`` (0 inside;
    a hull only says 0 or NaN)."""
    d = np.full(len(P), np.inf)
    for k in range(P.shape[1] - 1):
        A, B = P[:, k], P[:, k + 1]
        if v.kind == "sphere":
            dk = np.maximum(bd.point_segment(v.A, A, B) - v.r, 0.0)
        elif v.kind == "box":
            dk = bd.segment_box(A, B, v.T, v.ext)
        else:
            dk = np.where(bd.segment_hull_meets(A, B, v.planes), 0.0, np.nan)
        d = np.fmin(d, dk)
    return d


def keep_out_summary(plan: dict[str, Any], base_dir: Path = Path(".")) -> list[dict[str, Any]]:
    """Per keep-out volume: the targets inside it, how many of them failed as ``keep_out``,
    and the least distance (m) from it of the beam at every solved
    target and at every trajectory sample while the laser may be on."""

    ctx = PlanContext(plan, base_dir)
    setup = Setup.from_plan(plan, base_dir)
    P_all = np.array([t["p"] for t in plan["targets"]], dtype=float).reshape(-1, 3)
    beams = np.zeros((0, len(setup.robots) + 2, 3))
    if ctx.solved:
        spot, _, _ = spots(ctx.rays.p, ctx.rays.v, ctx.P, ctx.N)
        beams = polylines(setup, ctx.Q, spot, ctx.P)
    traj = plan.get("trajectory") or {}
    t = times(plan)
    lit = np.flatnonzero(laser_mask(traj, t)) if len(t) else np.zeros(0, dtype=int)
    lit_beams = np.zeros((0, beams.shape[1], 3))
    if len(lit):
        Q = {r["name"]: np.asarray(traj["q"][r["name"]], dtype=float)[lit] for r in setup.robots}
        lit_beams = polylines(setup, Q, None, P_all)
    out = []
    for v in setup.keep:
        inside = {h.row for h in target_hits(setup, P_all) if v.name in h.what}
        failed = [s for s in plan["solutions"]
                  if s.get("reason") == "keep_out" and int(s["target"]) in inside]  # fmt: skip
        out.append({
            "volume": v.name,
            "targets_inside": len(inside),
            "beam_min_m": float(np.nanmin(_beam_distance(v, beams), initial=np.inf)),
            "laser_on_min_m": float(np.nanmin(_beam_distance(v, lit_beams), initial=np.inf)),
            "laser_on_samples": len(lit), "failed_keep_out": len(failed),
        })  # fmt: skip
    return out
