"""Marking a path like a galvo scanner: sky-writing run-in/run-out and the laser gate.

Each stroke (a run of solved path samples marked in one go) is extended at both ends along
its tangent (run-in before the first sample, run-out after the last), solved by
equality-constrained Newton continuation from the stroke's end configurations. The whole
extended run is timed as one jerk-limited sweep from rest to rest
(:func:`planner.path.timing.profile`): the spot accelerates over the run-in and reaches the
path at the spot speed, crosses every marked sample at that speed (slower only where a
joint limit binds: a reported :class:`~planner.path.timing.Slowdown` with where, when and
which joint) and brakes over the run-out. The run-in and run-out are sized for the ramp
and the profile's look-ahead at the acceleration and jerk the joints allow, and lengthened
until the mark starts and ends at speed (:func:`sized_run`); where the extension has no
valid configuration that far, the slow end is reported as a slowdown. The sweep is
delayed by a fraction of a period so that a sample lands on the stroke's first vertex, and
cut into ``run_in``, ``path`` and ``run_out`` pieces: ``path`` holds the samples on the
stroke, from its first vertex to the last sample before its last vertex (at most one
period, spot_speed / rate, short of it). The laser is on exactly in the ``path`` pieces
(and in ``dwell``), off during approach, moves, run-in and run-out. World frame, metres,
seconds, radians.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from planner.errors import PlanError
from planner.model.polyline import runs as _runs
from planner.model.status import Failure, Reason
from planner.model.system import System, Targets
from planner.model.transforms import Array
from planner.path.nlp import PathOptions
from planner.path.profile import Profile, aligned, lookahead, profile, ramp_length, spot_ramp
from planner.path.timing import (
    MoveFn,
    Slowdown,
    Trajectory,
    _assemble,
    _Piece,
    profile_piece,
    ruckig_move,
)
from schemas import defaults
from schemas.plan_records import SegmentKind

RUN_MARGIN = 1.5  # run-in/run-out length as a multiple of the ramp / look-ahead distance
SPEED_SLACK = 0.02  # fraction: the marked speed may be this much below/above the spot speed
AT_SPEED = 1 - SPEED_SLACK / 2  # of the spot speed: a mark end this fast is at speed
RUN_TRIES = 4  # times a run-in/run-out is lengthened until the mark ends are at speed
ON_STROKE = 1e-9  # m: samples this close beyond a stroke's end vertex are on the stroke
_LIMITS = ("spot", "velocity", "acceleration", "jerk")


class MarkRun(NamedTuple):
    """A stroke ready to time: joints ``q`` (M x nq) at arc lengths ``arc`` (M, m, from 0,
    increasing) of which samples ``m0 <= k < m1`` are marked; ``offset`` (m) is the marked
    start's arc length along the whole path (for reports)."""

    q: Array
    arc: Array
    m0: int
    m1: int
    offset: float
    short: Failure | None = None  # why the run-in or run-out is shorter than asked


def tangent(P: Array, end: int) -> Array:
    """Unit direction of travel (3,) at the first (``end = 0``) or last (``end = -1``) sample
    of a run of points (M x 3, M >= 2): a one-sided second-order difference when M >= 3."""
    Q = P if end == -1 else P[::-1]
    d = Q[-1] - Q[-2] if len(Q) < 3 else 1.5 * Q[-1] - 2.0 * Q[-2] + 0.5 * Q[-3]
    d = d if end == -1 else -d
    return np.asarray(d / np.linalg.norm(d))


def _extend(system: System, P: Array, N: Array | None, Q: Array, n: int, h: float,
            opts: PathOptions) -> tuple[Array, Failure | None]:  # fmt: skip
    """Up to ``n`` configurations continuing the run's end (last rows of ``Q`` at points
    ``P``) along its tangent, ``h`` m apart; stops at the first sample with no valid
    solution. Returns (configurations in travel order away from the run, why it stopped
    short or None)."""
    from planner.path.warm import PathContext

    t = tangent(P, -1)
    ext = P[-1] + np.outer(h * np.arange(1, n + 1), t)
    nrm = None if N is None else np.tile(N[-1], (n, 1))
    ctx = PathContext(system, Targets(ext, nrm, kind="path"), opts)
    prev2, prev = (Q[-2] if len(Q) > 1 else Q[-1]), Q[-1]
    out: list[Array] = []
    short: Failure | None = None
    for k in range(n):
        q, why = ctx.newton(k, 2 * prev - prev2, ctx.plane(k, prev), centring=0.0)
        if why is not None and (
            why.reason == Reason.JOINT_LIMITS
            or (why.reason == Reason.UNREACHABLE and why.detail.startswith(("spot", "singular")))
        ):
            short = why  # the laser is off here: only the spot on the line and the joints matter
            break
        out.append(q)
        prev2, prev = prev, q
    return np.array(out).reshape(-1, Q.shape[1]), short


def run_samples(spot_speed: float, h: float, rate: float, a_s: float | None = None,
                j_s: float | None = None) -> int:  # fmt: skip
    """Samples ``h`` m apart in a run-in / run-out at ``spot_speed`` (m/s): ``RUN_MARGIN``
    times the longer of the ramp from rest and the profile's look-ahead
    (:func:`~planner.path.profile.lookahead`) at spot acceleration ``a_s`` and jerk ``j_s``
    (default nominal), plus two samples (the look-ahead window ends on a sample)."""
    a0, j0 = spot_ramp(spot_speed)
    a, j = a0 if a_s is None else a_s, j0 if j_s is None else j_s
    need = RUN_MARGIN * max(ramp_length(spot_speed, a, j), lookahead(spot_speed, a, j, rate))
    return max(2, int(np.ceil(need / h - 1e-9)) + 2)


def extend_run(
    system: System, targets: Targets, idx: Array, Q: Array, offset: float,
    spot_speed: float, opts: PathOptions | None = None, *, n: int | None = None,
    rate: float = defaults.SERVO_RATE_HZ,
) -> MarkRun:  # fmt: skip
    """The stroke of path samples ``idx`` (solved joints ``Q``, len(idx) x nq) extended by a
    run-in and a run-out of ``n`` samples each (default :func:`run_samples` at the nominal
    ramp), sampled at the stroke's own spacing (shorter where the extension has no valid
    configuration: ``MarkRun.short`` says why)."""
    opts = opts or PathOptions(max_incidence_deg=90.0)
    P = targets.points[idx]
    N = None if targets.normals is None else targets.normals[idx]
    seg = np.linalg.norm(np.diff(P, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    if len(idx) < 2 or arc[-1] <= 0:
        return MarkRun(Q, arc, 0, len(Q), offset)
    h = float(arc[-1] / (len(idx) - 1))
    n = run_samples(spot_speed, h, rate) if n is None else n
    q_out, short_out = _extend(system, P, N, Q, n, h, opts)
    q_in, short_in = _extend(system, P[::-1], None if N is None else N[::-1], Q[::-1], n, h, opts)
    n_in, n_out = len(q_in), len(q_out)
    Qx = np.vstack([q_in[::-1], Q, q_out])
    arcx = np.concatenate([-h * np.arange(n_in, 0, -1), arc, arc[-1] + h * np.arange(1, n_out + 1)])
    return MarkRun(Qx, arcx - arcx[0], n_in, n_in + len(Q), offset, short_in or short_out)


def marked_span(s: Array, run: MarkRun) -> tuple[int, int]:
    """First and last sample of a timed run's arc lengths ``s`` (m) on the stroke."""
    return _cut(s, float(run.arc[run.m0]) - ON_STROKE, float(run.arc[run.m1 - 1]) + ON_STROKE)


def sized_run(system: System, targets: Targets, idx: Array, Q: Array, offset: float,
              spot_speed: float, rate: float) -> MarkRun:  # fmt: skip
    """:func:`extend_run`, its run-in and run-out lengthened (for the ramp and look-ahead at
    the spot acceleration and jerk the joints allow, at least doubled each time, at most
    ``RUN_TRIES`` times) until the timed mark starts and ends at ``AT_SPEED`` of
    ``spot_speed``, a joint limit caps the speed on the stroke's end samples themselves, or
    the extension has no valid configuration further out."""
    run = extend_run(system, targets, idx, Q, offset, spot_speed, rate=rate)
    for _ in range(RUN_TRIES):
        if len(run.q) < 2 or run.short is not None or run.m1 - run.m0 < 2:
            return run
        prof = profile(run.q, run.arc, system.limits, spot_speed, rate)
        i0, i1 = marked_span(prof.s, run)
        floor = AT_SPEED * spot_speed
        if min(prof.sd[i0], prof.sd[i1]) >= floor:
            return run
        if min(prof.speed[run.m0], prof.speed[run.m1 - 1]) < floor:
            return run  # capped on the stroke: a slowdown, whatever the run-in
        h = float(run.arc[run.m1 - 1] - run.arc[run.m0]) / (run.m1 - run.m0 - 1)
        n = max(2 * run.m0, run_samples(spot_speed, h, rate, prof.a_s, prof.j_s))
        run = extend_run(system, targets, idx, Q, offset, spot_speed, n=n, rate=rate)
    return run


def mark_runs(system: System, targets: Targets, Q: Array, arc: Array, spot_speed: float,
              *, skywriting: bool = True, rate: float = defaults.SERVO_RATE_HZ) -> list[MarkRun]:  # fmt: skip
    """The marked runs of a path: each stroke (``targets.meta["strokes"]``, default the whole
    path, back to sample 0 when closed) cut at unsolved samples, extended by a run-in and a
    run-out sized for timing at ``rate`` (Hz, :func:`sized_run`) unless ``skywriting`` is
    off (then it is marked from rest to rest: for comparison only). ``Q``: joints per sample
    (NaN rows: unsolved), ``arc``: the samples' arc length (m)."""

    K = len(Q)
    default = (*range(K), 0) if targets.closed and K > 2 else tuple(range(K))
    strokes = targets.meta.get("strokes") or (default,)
    ok = np.asarray(np.isfinite(Q).all(axis=1), dtype=bool)
    runs = []
    for stroke in strokes:  # type: ignore[attr-defined]
        idx = np.asarray(stroke, dtype=int)
        for a, b in _runs(ok[idx]):
            sub = idx[a:b]
            if skywriting:
                runs.append(
                    sized_run(system, targets, sub, Q[sub], float(arc[sub[0]]), spot_speed, rate)
                )
                continue
            seg = np.linalg.norm(np.diff(targets.points[sub], axis=0), axis=1)
            local = np.concatenate([[0.0], np.cumsum(seg)])
            runs.append(MarkRun(Q[sub], local, 0, len(sub), float(arc[sub[0]])))
    return runs


def _cut(s: Array, lo: float, hi: float) -> tuple[int, int]:
    """First sample at or after ``lo`` and last at or before ``hi`` along increasing ``s``."""
    i0 = int(np.searchsorted(s, lo, side="left"))
    i1 = int(np.searchsorted(s, hi, side="right")) - 1
    return i0, max(i0, i1)


def marked_slowdowns(prof: Profile, run: MarkRun, i0: int, i1: int, spot_speed: float,
                     t0: float, rate: float) -> list[Slowdown]:  # fmt: skip
    """Spans of marked samples ``i0..i1`` of a timed run slower than the spot speed by more
    than half the speed slack, with the limit and joint that bind there (looked up in the
    speed caps from the span to its braking distance ahead; when no cap binds, the joint
    that capped the spot acceleration or jerk: a ramp that did not fit in the run-in; else,
    when the run-in or run-out could not be laid long enough, ``position`` (a joint limit)
    or ``reach`` (the spot line leaves the workspace) with joint -1; a slow span where
    nothing binds is not reported). Times from ``t0`` (s)."""
    sd = prof.sd[i0 : i1 + 1]
    slow = sd < (1 - SPEED_SLACK / 2) * spot_speed
    out: list[Slowdown] = []
    edges = np.flatnonzero(np.diff(np.concatenate([[0], slow.astype(int), [0]])))
    base = float(run.arc[run.m0])
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        s_lo, s_hi = prof.s[i0 + a], prof.s[i0 + b - 1]
        brake = lookahead(spot_speed, prof.a_s, prof.j_s, rate)
        k0, k1 = np.searchsorted(run.arc, [s_lo, s_hi + brake])
        window = np.arange(max(k0 - 1, 0), min(k1 + 1, len(run.arc)))
        capped = window[prof.code[window] != 0]
        if len(capped):
            k = int(capped[np.argmin(prof.speed[capped])])
            limit, joint = _LIMITS[int(prof.code[k])], int(prof.joint[k])
        elif prof.accel_joint >= 0:
            limit, joint = "acceleration", prof.accel_joint
        elif prof.jerk_joint >= 0:
            limit, joint = "jerk", prof.jerk_joint
        elif run.short is not None:  # the run-in / run-out could not be laid long enough
            limit = "position" if run.short.reason == Reason.JOINT_LIMITS else "reach"
            joint = -1
        else:
            continue  # no joint limit binds: not a slowdown (the check flags it)
        out.append(Slowdown(run.offset + s_lo - base, run.offset + s_hi - base, limit, joint,
                            float(sd[a:b].min()), t0 + (i0 + a) / rate,
                            t0 + (i0 + b - 1) / rate))  # fmt: skip
    return out


def time_run(run: MarkRun, lim: object, spot_speed: float, rate: float, t0: float
             ) -> tuple[list[_Piece], list[Slowdown]]:  # fmt: skip
    """Time one extended stroke from rest to rest, a sample on its first vertex
    (:func:`~planner.path.profile.aligned`), and cut it into run_in / path / run_out
    pieces; the path piece holds the samples on the stroke (:func:`marked_span`). ``t0``
    (s) is the run's start time, for the slowdowns' times."""
    prof = profile(run.q, run.arc, lim, spot_speed, rate)  # type: ignore[arg-type]
    prof = aligned(prof, float(run.arc[run.m0]), rate)
    whole = profile_piece(prof, run.q[-1])
    i0, i1 = marked_span(prof.s, run)
    pieces = []
    spans = ((SegmentKind.RUN_IN, 0, i0), (SegmentKind.PATH, i0, i1),
             (SegmentKind.RUN_OUT, i1, len(prof.s) - 1))  # fmt: skip
    for kind, a, b in spans:
        if b > a or kind is SegmentKind.PATH:
            sl = slice(a, b + 1)
            pieces.append(_Piece(whole.q[sl], whole.qd[sl], whole.qdd[sl], kind))
    return pieces, marked_slowdowns(prof, run, i0, i1, spot_speed, t0, rate)


def marking_trajectory(
    system: System, runs: list[MarkRun], q_start: Array | None = None,
    spot_speed: float = 0.02, rate: float = defaults.SERVO_RATE_HZ, move: MoveFn | None = None,
) -> Trajectory:  # fmt: skip
    """Approach from ``q_start`` (default home) to the first run's start, each run timed by
    :func:`time_run`, rest-to-rest ``move`` between runs (laser off; from one run's run-out
    end to the next run's run-in start), both made by ``move`` (default
    :func:`~planner.path.timing.ruckig_move`; a safety mover detours them around
    collisions). The laser is on in the ``path`` segments only (``Trajectory.laser_on``)."""
    move = move or ruckig_move
    lim = system.limits
    prev = system.home if q_start is None else np.asarray(q_start, dtype=float)
    pieces: list[_Piece] = []
    slow: list[Slowdown] = []
    n_samples = 1
    for n, run in enumerate(runs):
        Qm, QDm, QDDm = move(prev, run.q[0], lim, rate)
        pieces.append(_Piece(Qm, QDm, QDDm, SegmentKind.APPROACH if n == 0 else SegmentKind.MOVE))
        n_samples += len(Qm) - 1
        prev = run.q[0]
        if len(run.q) < 2:
            continue
        ps, sl = time_run(run, lim, spot_speed, rate, (n_samples - 1) / rate)
        pieces += ps
        slow += sl
        n_samples += sum(len(p.q) - 1 for p in ps)
        prev = run.q[-1]
    if not pieces:
        raise PlanError("no feasible path run to time")
    return _assemble(pieces, rate, tuple(slow))
