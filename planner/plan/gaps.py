"""Dropping solved targets and path samples: a target fails with a reason and its evidence
(:func:`failed_with`); path samples become gaps (:func:`split_path`: their solutions fail,
the path result loses them and its feasible segments split around them), for a blocked beam
(:mod:`planner.plan.occlusion`), a broken safety rule (:func:`check_path_safety`) or an
unsafe timed trajectory (:mod:`planner.plan.safe_timing`). World frame, metres, radians.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np

from planner.ik import Solution
from planner.model.polyline import runs
from planner.model.status import Reason
from planner.model.system import System
from planner.model.transforms import Array
from planner.path.result import PathGap, PathResult
from planner.safety.beam_cover import configs
from planner.safety.model import Safety


def failed_with(sol: Solution, reason: Reason | str, evidence: dict[str, object]) -> Solution:
    """``sol`` as a failed target (no configuration, spot or hits) with ``reason``; the
    evidence is kept under the reason's key."""
    why = Reason(reason)
    evidence = {**sol.evidence, str(why): evidence}
    return Solution.failed(why, sol.solve_time, sol.iterations, sol.method, evidence)


def check_path_safety(
    system: System, safety: Safety, solutions: list[Solution], path: PathResult
) -> tuple[list[Solution], PathResult]:
    """Path samples whose configuration or beam breaks a safety rule (arm collision, beam
    through an arm, into a keep-out volume or back into the laser or camera) become gaps
    with the rule's reason (``collision``, ``occluded``, ``keep_out``) and evidence."""
    gaps: dict[int, SampleGap] = {}
    p0 = system.world_T_laser[:3, 3]
    ks, qs, polylines = [], [], []
    for k, sol in enumerate(solutions):
        if not sol.ok or sol.q is None or sol.hits is None or sol.spot is None:
            continue
        ks.append(k)
        qs.append(np.asarray(sol.q, dtype=float))
        polylines.append(np.vstack([p0, sol.hits, sol.spot]))
    if not ks:
        return split_path(solutions, path, gaps)
    Q, P = np.array(qs), np.array(polylines)
    for k, bad in zip(ks, configs(safety, Q, P), strict=True):
        sol = solutions[k]
        if bad is not None:
            point = np.asarray(bad.evidence.get("point", sol.spot), dtype=float)
            gaps[k] = SampleGap(bad.reason, dict(bad.evidence), bad.text, point)
    return split_path(solutions, path, gaps)


class SampleGap(NamedTuple):
    """Why one path sample is dropped: status ``reason``, ``evidence``, a one-line
    ``detail`` and the world ``point`` (m) where it happens."""

    reason: str
    evidence: dict[str, object]
    detail: str
    point: Array


def split_path(
    solutions: list[Solution], path: PathResult, gaps: dict[int, SampleGap]
) -> tuple[list[Solution], PathResult]:
    """Drop the samples in ``gaps`` (by sample index): their solutions fail with the gap's
    reason and evidence, the path result loses them (q NaN, ok False), consecutive dropped
    samples with one reason become one :class:`~planner.path.solve.PathGap`, and the
    feasible segments split around them."""
    if not gaps:
        return solutions, path
    out = list(solutions)
    for k, gap in gaps.items():
        out[k] = failed_with(solutions[k], gap.reason, gap.evidence)
    mask = np.zeros(len(solutions), dtype=bool)
    mask[list(gaps)] = True
    q, ok = path.q.copy(), path.ok & ~mask
    q[mask] = np.nan
    new_gaps = list(path.gaps)
    for k0, k1 in runs(mask):
        for a, b in _same_reason(gaps, k0, k1):
            g = gaps[a]
            p = solutions[a].spot if solutions[a].spot is not None else g.point
            new_gaps.append(PathGap(a, b, float(path.arc[a]), float(path.arc[b - 1]),
                                    np.asarray(p), Reason(g.reason), g.detail))  # fmt: skip
    segments = []
    for seg in path.segments:
        for a, b in runs(ok[seg.k0 : seg.k1]):
            segments.append(seg._replace(k0=seg.k0 + a, k1=seg.k0 + b))
    new = dataclasses.replace(path, q=q, ok=ok, segments=tuple(segments),
                              gaps=tuple(sorted(new_gaps, key=lambda g: g.k0)))  # fmt: skip
    return out, new


def _same_reason(gaps: dict[int, SampleGap], k0: int, k1: int) -> list[tuple[int, int]]:
    """Split the run k0..k1 of dropped samples where the reason changes."""
    out, a = [], k0
    for k in range(k0 + 1, k1 + 1):
        if k == k1 or gaps[k].reason != gaps[a].reason:
            out.append((a, k))
            a = k
    return out
