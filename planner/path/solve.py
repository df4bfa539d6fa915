"""Path tracking (scenario ``targets.path``): the public entry point.

:func:`plan_path` sweeps the spot along a resampled polyline: a warm start per sample
(:mod:`planner.path.warm`: the continuation chain, or for paths sampled finer than
``coarse_spacing`` the chain on every m-th sample, splined and projected onto every target
at once), then one IPOPT NLP over every feasible run of samples (:mod:`planner.path.nlp`),
then a batched minimum-norm Gauss-Newton polish that puts every sample at machine precision
(IPOPT stops at its ~1e-11 m tolerance; the correction is far below any smoothness scale).
Where the warm start finds no valid configuration the path is split: each feasible run is
solved separately and each gap is reported with where (samples, arc length, point) and why.
Points are in the world frame, lengths in metres, joints in rad.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import numpy as np

from planner.beam.graph import system_params
from planner.model.polyline import arc_length, resample_polyline, runs
from planner.model.status import Failure, Reason
from planner.model.system import System, Targets
from planner.model.transforms import Array
from planner.path.nlp import PathOptions, path_nlp, tangents
from planner.path.result import PathGap, PathResult, PathSegment

if TYPE_CHECKING:
    from planner.safety.model import Safety

from planner.path.warm import (
    Indices,
    PathContext,
    Seeder,
    coarse_indices,
    continuation_chain,
    project,
    valid_samples,
)
from planner.safety.samples import safer_warm_start

__all__ = [
    "PathGap",
    "PathOptions",
    "PathResult",
    "PathSegment",
    "acceleration_weight",
    "arc_length",
    "jacobian_condition",
    "plan_path",
    "resample_polyline",
    "sample_errors",
    "tangents",
]


def jacobian_condition(system: System, Q: Array, max_samples: int = 5000) -> Array:
    """Condition number of each arm's 6 x nq flange Jacobian (rows: linear velocity m/s and
    angular velocity rad/s, base axes) at the finite rows of ``Q`` (M x nq, stacked), the
    largest over the arms; at most ``max_samples`` rows, evenly spread. Near-singular arm
    postures give large values (a UR5e with its elbow straight: hundreds)."""
    good = np.flatnonzero(np.all(np.isfinite(Q), axis=1))
    good = good[np.unique(np.linspace(0, len(good) - 1, min(len(good), max_samples)).astype(int))]
    out = np.zeros(len(good))
    for k, i in enumerate(good):
        parts = system.split_q(Q[i])
        out[k] = max(np.linalg.cond(r.kinematics.jacobian(parts[r.name])) for r in system.robots)
    return out


def sample_errors(system: System, Q: Array, points: Array, normals: Array | None) -> Array:
    """Spot error (m) of every sample through the beam function (NaN rows -> NaN)."""
    from planner.beam.graph import beam_function

    f = beam_function(tuple(r.kinematics for r in system.robots))
    K = len(Q)
    geo = system_params(system)
    nrm = np.zeros((K, 3)) if normals is None else np.nan_to_num(np.asarray(normals, float))
    good = np.all(np.isfinite(Q), axis=1)
    err = np.full(K, np.nan)
    if good.any():
        n = int(good.sum())
        out = f.map(n)(q=Q[good].T, **geo, target=points[good].T, normal=nrm[good].T)
        err[good] = np.asarray(out["error"], dtype=float).ravel()
    return err


def acceleration_weight(opts: PathOptions, ds: float) -> float:
    """Weight of the second-difference term at sample spacing ``ds`` (m).

    The term is sum |d2q|^2 * w / ds^3 (the integral of |q''|^2 over arc length); its
    stiffness relative to the first-difference term grows like 1/ds^2, so the KKT system's
    conditioning degrades like K^4 and IPOPT needs ever more iterations (111 at 0.03 mm
    spacing). Below ``opts.acceleration_spacing`` the weight is scaled by (ds / that)^2: the
    stiffness ratio stays at its value for that spacing, the velocity term (which carries
    the smoothness) is untouched, and scenario spacings >= that spacing are unchanged."""
    ref = max(opts.acceleration_spacing, 1e-12)
    return float(opts.weight_acceleration * min(1.0, (ds / ref) ** 2))


def _weights(opts: PathOptions, ds: float) -> tuple[float, ...]:
    """The path NLP's ``weights`` parameter at sample spacing ``ds`` (m)."""
    return (opts.weight_velocity, acceleration_weight(opts, ds), opts.weight_centring,
            opts.weight_reference, ds)  # fmt: skip


def _clearance(ctx: PathContext, safety: Safety, ks: Indices, Qs: Array, Q0: Array, NB: Array,
               ds: float, closed: bool, seg: PathSegment
               ) -> tuple[Array, PathSegment, int]:  # fmt: skip
    """The run's NLP result ``Qs`` (from the warm start ``Q0``) re-solved with the clearance
    as constraints where it breaks a distance rule (:func:`planner.path.clearance.clear_run`); kept when it breaks
    the rules at fewer samples. Also returns at how many samples the kept result breaks a
    rule."""
    from planner.path.clearance import clear_run

    t0 = time.perf_counter()
    res = clear_run(ctx, safety, ks, Qs, Q0, NB, _weights(ctx.opts, ds), closed)
    if res.unsafe_after >= res.unsafe_before:
        return Qs, seg, res.unsafe_before
    status = (f"{seg.status} +clearance ({res.status}; unsafe samples {res.unsafe_before} -> "
              f"{res.unsafe_after})")  # fmt: skip
    return res.q, seg._replace(status=status, iterations=seg.iterations + res.iterations,
                               solve_time=seg.solve_time + time.perf_counter() - t0
                               ), res.unsafe_after  # fmt: skip


def _solve_run(ctx: PathContext, ks: Indices, Q0: Array, NB: Array, ds: float, closed: bool
               ) -> tuple[Array, PathSegment, bool]:  # fmt: skip
    """One path NLP over samples ``ks`` (``ds`` m apart) from ``Q0``; returns (Q, segment,
    every sample valid). An invalid NLP result is reported; the caller keeps ``Q0``."""
    opts, n = ctx.opts, len(ks)
    weights = _weights(opts, ds)
    cached = path_nlp.cache_info().hits
    nlp = path_nlp(ctx.kin, n, closed, opts.max_iter)
    build = 0.0 if path_nlp.cache_info().hits > cached else nlp.build_time
    t0 = time.perf_counter()
    Qs, stats = ctx.solve(nlp, list(ks), Q0, NB, weights)
    solve_time = time.perf_counter() - t0
    status = str(stats.get("return_status", "unknown"))
    valid = bool(valid_samples(ctx, ks, Qs, NB).all())
    seg = PathSegment(int(ks[0]), int(ks[-1]) + 1, status if valid else f"warm_start ({status})",
                      int(stats.get("iter_count", 0)), solve_time, build)  # fmt: skip
    return Qs, seg, valid


def _coarse_to_fine(ctx: PathContext, q_start: Array, arc: Array, closed: bool
                    ) -> tuple[Array, Array] | None:  # fmt: skip
    """Warm start of a finely sampled path: the continuation chain on every m-th sample
    (about ``coarse_spacing`` apart), a cubic spline of the joints in arc length through
    them, then every sample projected onto its target at once (:func:`project`). Smoother
    than a per-sample chain at fine spacing and ~m times cheaper. None when that does not
    give a valid configuration at every sample (the caller then walks every sample)."""
    from scipy.interpolate import CubicSpline

    K = len(ctx.P)
    ds = float(arc[-1] / max(K - 1, 1))
    idx = coarse_indices(K, ds, ctx.opts.coarse_spacing)
    if closed:
        idx = idx[idx <= K - 1 - (idx[1] - idx[0]) // 2]  # the wrap-around step ~ m samples
    if len(idx) < 4 or len(idx) * 2 > K:
        return None
    Qc, _, _ = continuation_chain(ctx, q_start, idx)
    if not np.all(np.isfinite(Qc)):
        return None
    x = arc[idx]
    if closed:
        x = np.append(x, arc[-1] + np.linalg.norm(ctx.P[-1] - ctx.P[0]))
        Qc = np.vstack([Qc, Qc[:1]])
    spline = CubicSpline(x, Qc, axis=0, bc_type="periodic" if closed else "not-a-knot")
    ks = np.arange(K)
    Q, NB, _ = project(ctx, ks, spline(arc))
    if not valid_samples(ctx, ks, Q, NB).all():
        return None
    return Q, NB


def _from_previous(ctx: PathContext, q_warm: Array) -> tuple[Array, Array] | None:
    """Warm start from the joints of a solved path over nearly the same samples (K x nq,
    rad): every row projected onto its sample (:func:`project`). None when a row is missing
    (NaN, another K) or not valid there (the caller then builds its own warm start)."""
    Q0 = np.asarray(q_warm, dtype=float)
    K = len(ctx.P)
    if Q0.shape != (K, len(ctx.lower)) or not np.all(np.isfinite(Q0)):
        return None
    ks = np.arange(K)
    Q, NB, _ = project(ctx, ks, Q0)
    if not valid_samples(ctx, ks, Q, NB).all():
        return None
    return Q, NB


def _solve_feasible(ctx: PathContext, safety: Safety | None, targets: Targets, Q: Array,
                    NB: Array, k0: int, k1: int, ds: float, closed: bool, reused: bool
                    ) -> PathSegment:  # fmt: skip
    """Solve the feasible run ``k0 <= k < k1`` of the warm start ``Q`` in place (see
    :func:`plan_path`); ``reused``: ``Q`` is a nearby solved path projected onto these
    samples, taken as the NLP's result (it is that NLP's optimum up to the projection; IPOPT
    started at it ran out of iterations) and checked for clearance like one."""
    if k1 - k0 < 2:
        return PathSegment(k0, k1, "warm_start", 0, 0.0, 0.0)
    ks = np.arange(k0, k1)
    if reused:
        Qs, seg, valid = Q[k0:k1].copy(), PathSegment(k0, k1, "previous path", 0, 0.0, 0.0), True
    else:
        Qs, seg, valid = _solve_run(ctx, ks, Q[k0:k1], NB[k0:k1], ds, closed)
    unsafe = None  # samples of Qs breaking a rule, when known
    if valid and safety is not None:
        Qs, seg, unsafe = _clearance(ctx, safety, ks, Qs, Q[k0:k1], NB[k0:k1], ds, closed, seg)
    if valid and safety is not None and safer_warm_start(safety, Qs, Q[k0:k1], ks, targets,
                                                         unsafe):  # fmt: skip
        valid, seg = False, seg._replace(status=f"warm_start (NLP result unsafe: {seg.status})")
    if valid:
        Q[k0:k1] = Qs
    return seg


def plan_path(
    system: System,
    targets: Targets,
    q_start: Array | None = None,
    solver_options: PathOptions | dict[str, object] | None = None,
    safety: Safety | None = None,
    q_warm: Array | None = None,
    *,
    seeder: Seeder | None = None,
) -> PathResult:
    """Joint configurations sweeping the spot along ``targets`` (resampled path, world frame).

    ``q_start`` (stacked joints, default the robots' home) seeds the first sample.
    ``q_warm`` (K x nq, rad), the solution of a path whose samples lie close to these (the
    same path moved onto its surface), projected onto these samples, is the result when it
    is valid at every one (no NLP; clearance rules and polish as for an NLP result).
    Infeasible stretches are reported as :class:`PathGap`, the feasible runs solved apart.
    Long finely sampled paths are warm-started coarse-to-fine; every solved sample is
    polished to machine precision by a minimum-norm Gauss-Newton step (never worse).
    ``seeder`` finds a sample's configuration from scratch (the pipeline passes the IK's
    closed-form family search, under the same ``safety`` rules:
    :func:`planner.plan.scenario_planner.path_seeder`); without one, a multi-start one-sample
    NLP does. With ``safety`` a run's NLP result that breaks a distance rule is re-solved
    with the clearance as constraints (:mod:`planner.path.clearance`), and one that still
    breaks them at more samples than its warm start is dropped for it (checked after:
    :func:`planner.plan.gaps.check_path_safety`).
    """
    opts = (
        solver_options if isinstance(solver_options, PathOptions)
        else PathOptions(**(solver_options or {}))  # type: ignore[arg-type]
    )  # fmt: skip
    q_start = system.home if q_start is None else np.asarray(q_start, dtype=float)
    ctx = PathContext(system, targets, opts, seeder)
    K, P = len(ctx.P), ctx.P
    arc = arc_length(P)
    t0 = time.perf_counter()
    closed_path = bool(targets.closed)
    warm = None if q_warm is None else _from_previous(ctx, q_warm)
    reused = warm is not None
    if warm is None and K > 2:
        warm = _coarse_to_fine(ctx, q_start, arc, closed_path)
    if warm is not None:
        Q, NB = warm
        why: list[Failure | None] = [None] * K
    else:
        Q, NB, why = continuation_chain(ctx, q_start)
    warm_time = time.perf_counter() - t0
    ok = np.all(np.isfinite(Q), axis=1)
    ds = float(arc[-1] / max(K - 1, 1)) or 1e-3
    t1 = time.perf_counter()
    feasible = runs(ok)
    closed = closed_path and feasible == [(0, K)]
    segments = [_solve_feasible(ctx, safety, targets, Q, NB, k0, k1, ds, closed, reused)
                for k0, k1 in feasible]  # fmt: skip
    if opts.polish and ok.any():
        _polish(ctx, Q, NB, ok)
    nlp_time = time.perf_counter() - t1
    err = sample_errors(system, Q, P, targets.normals)
    gaps = _gaps(P, arc, ok, why)
    return PathResult(Q, ok, err, arc, tuple(segments), gaps, warm_time, nlp_time)


def _polish(ctx: PathContext, Q: Array, NB: Array, ok: Array) -> None:
    """Every solved sample (``ok``) of ``Q`` to machine precision by a minimum-norm
    Gauss-Newton step, kept where it is still valid (in place)."""
    ks = np.flatnonzero(ok)
    Qp, _, _ = project(ctx, ks, Q[ks], NB[ks])
    keep = valid_samples(ctx, ks, Qp, NB[ks])
    Q[ks[keep]] = Qp[keep]


def _gaps(P: Array, arc: Array, ok: Array, why: list[Failure | None]) -> tuple[PathGap, ...]:
    """The unsolved stretches (runs of not ``ok``) with the first sample's failure."""
    gaps = []
    for k0, k1 in runs(np.logical_not(ok)):
        failure = why[k0] or Failure(Reason.UNREACHABLE)
        s1 = float(arc[k1]) if k1 < len(P) else float(arc[-1])
        gaps.append(PathGap(k0, k1, float(arc[k0]), s1, P[k0].copy(), failure.reason,
                            failure.detail))  # fmt: skip
    return tuple(gaps)
