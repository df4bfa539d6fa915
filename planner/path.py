"""Path tracking (SPEC section 4 ``targets.path``, issue 5): the public entry point.

:func:`plan_path` sweeps the spot along a resampled polyline: a warm start per sample
(:mod:`planner.path_warm`), then one IPOPT NLP over every feasible run of samples
(:mod:`planner.path_nlp`). Where the warm start finds no valid configuration the path is
split: each feasible run is solved separately and each gap is reported with where (samples,
arc length, point) and why. Points are in the world frame, lengths in metres, joints in rad.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import NamedTuple

import casadi as ca
import numpy as np

from planner.beam import system_params
from planner.path_nlp import PathOptions, path_nlp, sample_function, tangents
from planner.path_warm import PathContext, continuation_chain
from planner.system import System, Targets
from planner.transforms import Array

__all__ = [
    "PathGap",
    "PathOptions",
    "PathResult",
    "PathSegment",
    "arc_length",
    "plan_path",
    "resample_polyline",
    "sample_errors",
    "tangents",
]


class PathGap(NamedTuple):
    """Samples ``k0 <= k < k1`` (arc length s0..s1 m, starting at world point ``p``) have no
    valid configuration; ``reason`` is a SPEC status reason, ``detail`` the evidence."""

    k0: int
    k1: int
    s0: float
    s1: float
    p: Array
    reason: str
    detail: str


class PathSegment(NamedTuple):
    """A feasible run of samples ``k0 <= k < k1`` solved by one NLP."""

    k0: int
    k1: int
    status: str  # IPOPT return status, or "warm_start" if the NLP failed and the chain is kept
    iterations: int
    solve_time: float  # s, IPOPT only
    build_time: float  # s, NLP construction (0 when cached)


@dataclass(frozen=True)
class PathResult:
    """Joints per sample (``q``: K x nq, NaN in gaps), per-sample spot error (m) and validity."""

    q: Array
    ok: Array  # (K,) bool
    error: Array  # (K,) m
    arc: Array  # (K,) cumulative arc length of the samples, m
    segments: tuple[PathSegment, ...]
    gaps: tuple[PathGap, ...]
    warm_time: float  # s, chain + seed
    nlp_time: float  # s, build + solve of every segment

    @property
    def complete(self) -> bool:
        return not self.gaps


def arc_length(points: Array, closed: bool = False) -> Array:
    """Cumulative arc length (m) of a polyline's vertices, starting at 0."""
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    return np.concatenate([[0.0], np.cumsum(seg)])


def resample_polyline(points: Array, spacing: float, closed: bool = False,
                      normals: Array | None = None) -> tuple[Array, Array | None]:  # fmt: skip
    """Points every ~``spacing`` m along a polyline (vertices interpolated linearly; equal
    spacing that divides the length exactly; a closed path does not repeat its start)."""
    P = np.asarray(points, dtype=float)
    Nn = None if normals is None else np.asarray(normals, dtype=float)
    if closed:
        P = np.vstack([P, P[:1]])
        Nn = None if Nn is None else np.vstack([Nn, Nn[:1]])
    s = arc_length(P)
    n = max(1, int(np.ceil(s[-1] / spacing - 1e-9)))
    s_new = np.linspace(0.0, s[-1], n + 1)[: n if closed else n + 1]
    out = np.column_stack([np.interp(s_new, s, P[:, i]) for i in range(3)])
    if Nn is None:
        return out, None
    nn = np.column_stack([np.interp(s_new, s, Nn[:, i]) for i in range(3)])
    return out, nn / np.linalg.norm(nn, axis=1, keepdims=True)


def _runs(mask: Array) -> list[tuple[int, int]]:
    """Half-open index ranges of consecutive True values."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(int), [0]])))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def sample_errors(system: System, Q: Array, points: Array, normals: Array | None) -> Array:
    """SPEC spot error (m) of every sample through the beam function (NaN rows -> NaN)."""
    from planner.beam import beam_function

    f = beam_function(tuple(r.kinematics for r in system.robots))
    K = len(Q)
    geo = system_params(system)
    nrm = np.zeros((K, 3)) if normals is None else np.nan_to_num(np.asarray(normals, float))
    good = np.all(np.isfinite(Q), axis=1)
    err = np.full(K, np.nan)
    if good.any():
        n = int(good.sum())
        out = f.map(n)(Q[good].T, *geo.values(), points[good].T, nrm[good].T)
        err[good] = np.asarray(out[9], dtype=float).ravel()
    return err


def plan_path(
    system: System,
    targets: Targets,
    q_start: Array | None = None,
    solver_options: PathOptions | dict[str, object] | None = None,
) -> PathResult:
    """Joint configurations sweeping the spot along ``targets`` (resampled path, world frame).

    ``q_start`` (stacked joints, default the robots' home) seeds the first sample. Infeasible
    stretches are reported as :class:`PathGap` and the feasible runs solved separately.
    """
    opts = (
        solver_options if isinstance(solver_options, PathOptions)
        else PathOptions(**(solver_options or {}))  # type: ignore[arg-type]
    )  # fmt: skip
    q_start = system.home if q_start is None else np.asarray(q_start, dtype=float)
    ctx = PathContext(system, targets, opts)
    K, P = len(ctx.P), ctx.P
    arc = arc_length(P)
    t0 = time.perf_counter()
    Q, NB, why = continuation_chain(ctx, q_start)
    warm_time = time.perf_counter() - t0
    ok = np.all(np.isfinite(Q), axis=1)
    ds = float(arc[-1] / max(K - 1, 1)) or 1e-3
    weights = (opts.weight_velocity, opts.weight_acceleration, opts.weight_centring,
               opts.weight_reference, ds)  # fmt: skip
    segments, t1 = [], time.perf_counter()
    runs = _runs(ok)
    closed = bool(targets.closed) and runs == [(0, K)]
    for k0, k1 in runs:
        n = k1 - k0
        if n < 2:
            segments.append(PathSegment(k0, k1, "warm_start", 0, 0.0, 0.0))
            continue
        cached = path_nlp.cache_info().hits
        nlp = path_nlp(ctx.kin, n, closed, opts.max_iter)
        build = 0.0 if path_nlp.cache_info().hits > cached else nlp.build_time
        ks = list(range(k0, k1))
        Qs, stats = ctx.solve(nlp, ks, Q[k0:k1], NB[k0:k1], weights)
        status = str(stats.get("return_status", "unknown"))
        G, H, _ = sample_function(ctx.kin).map(n)(
            Qs.T, *[ca.repmat(g, 1, n) for g in ctx.geo], P[k0:k1].T, NB[k0:k1].T,
            ctx.has[k0:k1][None, :].astype(float),
            np.concatenate([tangents(nb) for nb in NB[k0:k1]], axis=1),
        )  # fmt: skip
        G, H = np.asarray(G), np.asarray(H)
        valid = all(ctx.why(k, Qs[i], G[:, i], H[:, i]) is None for i, k in enumerate(ks))
        if valid:
            Q[k0:k1] = Qs
        else:
            status = f"warm_start ({status})"
        segments.append(
            PathSegment(
                k0,
                k1,
                status,
                int(stats.get("iter_count", 0)),
                float(stats.get("t_wall_total", 0.0)),
                build,
            )
        )
    nlp_time = time.perf_counter() - t1
    gaps = []
    for k0, k1 in _runs(~ok):
        reason = str(why[k0] or "unreachable")
        s1 = float(arc[k1]) if k1 < K else float(arc[-1])
        gaps.append(PathGap(k0, k1, float(arc[k0]), s1, P[k0].copy(), reason.split(":")[0]
                            .split(" ")[0], reason))  # fmt: skip
    err = sample_errors(system, Q, P, targets.normals)
    return PathResult(Q, ok, err, arc, tuple(segments), tuple(gaps), warm_time, nlp_time)
