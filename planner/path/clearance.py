"""The path NLP with the clearance as constraints.

When a run's NLP result breaks a distance rule at some samples (arm-arm, arm-self,
arm-scene, the beam against an arm part or into a keep-out volume), the run is solved again,
warm-started from that result, with every sample's pairs within a margin of their required
distance as linearised rows at every sample that broke one (:mod:`planner.safety.linearize`;
at most :data:`PATH_ROWS` per sample, nearest to violation first; rows at every sample made
the re-solve from an optimum ill-conditioned), re-linearised at each new result, a few
rounds at most; a sample that breaks a rule in a later round gets rows too.
The caller keeps the result only if it is valid and breaks the rules at fewer samples than
the plain one; samples left unsafe become gaps afterwards
(:func:`planner.plan.gaps.check_path_safety`). World frame, metres, radians.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from planner.beam.trace import trace_beam
from planner.model.transforms import Array
from planner.path.nlp import path_nlp
from planner.path.warm import Indices, PathContext, valid_samples
from planner.safety.linearize import ClearanceRow, Linearizer, cut_matrix
from planner.safety.model import Safety

#: clearance rows per sample, and re-solves of a run
PATH_ROWS, PATH_ROUNDS = 4, 2
#: rules that are no distance (no row can fix them)
_APERTURES = ("laser_return", "camera_lens")


class ClearedRun(NamedTuple):
    """The run after the constrained re-solves: joints (len(ks) x nq), how many samples
    broke a rule before and after, IPOPT iterations spent, the last IPOPT status."""

    q: Array
    unsafe_before: int
    unsafe_after: int
    iterations: int
    status: str


def _polyline(ctx: PathContext, k: int, q: Array) -> Array:
    """The beam of sample ``k`` at ``q``: laser exit, mirror hits, spot (world, m)."""
    normal = ctx.nbar[k] if ctx.has[k] else None
    ev = trace_beam(ctx.system, q, ctx.P[k], normal)
    return np.vstack([ctx.system.world_T_laser[:3, 3], ev.hits, ev.spot])


def unsafe_mask(safety: Safety, ctx: PathContext, ks: Indices, Q: Array) -> tuple[Array, Array]:
    """Per sample of ``ks`` at joints ``Q``: broken by any rule, and by a distance rule."""
    from planner.safety.beam_cover import configs

    any_bad, dist_bad = np.zeros(len(ks), dtype=bool), np.zeros(len(ks), dtype=bool)
    if not len(ks):
        return any_bad, dist_bad
    P = np.array([_polyline(ctx, int(k), Q[i]) for i, k in enumerate(ks)])
    for i, bad in enumerate(configs(safety, Q, P)):
        any_bad[i] = bad is not None
        dist_bad[i] = bad is not None and bad.check.value not in _APERTURES
    return any_bad, dist_bad


def clear_run(
    ctx: PathContext, safety: Safety, ks: Indices, Q: Array, Q_warm: Array, NB: Array,
    weights: tuple[float, ...], closed: bool, linearizer: Linearizer | None = None,
) -> ClearedRun:  # fmt: skip
    """Re-solve the run ``ks`` (module docstring) given its NLP result ``Q`` (len(ks) x nq)
    and the warm start ``Q_warm`` it came from, with the target-plane normals ``NB``, NLP
    weights and closure of the plain solve. Every re-solve starts from the warm start, which
    stays the posture reference: the plain problem plus the rows (an interior-point start
    at the plain optimum, with its active constraints and no multipliers, did not
    converge)."""
    any_bad, dist_bad = unsafe_mask(safety, ctx, ks, Q)
    before = int(any_bad.sum())
    if not dist_bad.any():
        return ClearedRun(Q, before, before, 0, "")
    lin = linearizer or Linearizer(safety)
    n, nq = len(ks), ctx.system.nq
    rows: list[dict[tuple[str, int], ClearanceRow]] = [{} for _ in range(n)]
    nlp = path_nlp(ctx.kin, n, closed, ctx.opts.max_iter, PATH_ROWS)
    best, best_bad, iters, status = Q, before, 0, ""
    active = np.array(dist_bad, dtype=bool)
    idx = [int(k) for k in ks]
    for _ in range(PATH_ROUNDS):
        for i in np.flatnonzero(active):
            rows[i] |= {r.key: r for r in lin.rows(Q[i], _polyline(ctx, idx[i], Q[i]))}
        A, lb = np.zeros((n, PATH_ROWS, nq)), np.full((n, PATH_ROWS), -np.inf)
        for j in range(n):
            near = sorted(rows[j].values(), key=lambda r: r.distance - r.required)
            A[j], lb[j] = cut_matrix(near, PATH_ROWS, nq)
        Q2, stats = ctx.solve(nlp, idx, Q_warm, NB, weights, (A, lb))
        iters += int(stats.get("iter_count", 0))
        status = str(stats.get("return_status", "unknown"))
        if not valid_samples(ctx, ks, Q2, NB).all():
            break
        Q = Q2
        any_bad, dist_bad = unsafe_mask(safety, ctx, ks, Q)
        if any_bad.sum() < best_bad:
            best, best_bad = Q, int(any_bad.sum())
        if not dist_bad.any():
            break
        active = active | dist_bad
    return ClearedRun(best, before, best_bad, iters, status)
