"""Time-parameterisation: dense, jerk-limited joint trajectories at the servo rate.

Data in, data out. Discrete targets: visit order (``optimal``: nearest neighbour + 2-opt
on the rest-to-rest move time in joint space, candidates from a k-d tree, memory linear in
the target count, :mod:`planner.path.tour`; ``given``: the targets' own order), then
time-optimal rest-to-rest Ruckig moves with an optional dwell on each target. Paths: the joint samples ``q_k`` are
splined against the spot's arc length s (metres) and the path parameter s(t) is generated
by a 1-DOF online Ruckig whose velocity limit is the spot speed, lowered ahead of time where
a joint velocity, acceleration or jerk limit would bind (reported as :class:`Slowdown`).

Every trajectory lives on the grid t = i / rate (s); q in rad, qd rad/s, qdd rad/s^2,
joints of all robots stacked in robot order. Check the result by sampling
(:mod:`planner.verify.trajectory`); it is not assumed.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from planner.errors import PlanError
from planner.io.plan import Trajectory as PlanTrajectory
from planner.model.system import Limits, System
from planner.model.transforms import Array
from planner.path.profile import Profile, path_speed_limit, profile
from planner.path.rest_to_rest import move_time
from planner.path.tour import visit_order
from schemas import defaults
from schemas.plan_records import LASER_KINDS, SegmentKind

__all__ = ["Profile", "path_speed_limit", "profile"]  # re-exported

#: a rest-to-rest move ``(q0, q1, limits, rate) -> (q, qd, qdd)`` sampled at ``rate``
MoveFn = Callable[[Array, Array, Limits, float], tuple[Array, Array, Array]]


class Segment(NamedTuple):
    kind: SegmentKind
    t0: float  # s
    t1: float  # s


class Slowdown(NamedTuple):
    """Where the spot runs slower than requested: arc length s0..s1 (m), the binding limit
    (velocity | acceleration | jerk), the joint index (stacked) and the speed reached (m/s);
    ``t0``..``t1`` (s, NaN if not timed) the span of trajectory time it covers."""

    s0: float
    s1: float
    limit: str
    joint: int
    speed: float
    t0: float = float("nan")
    t1: float = float("nan")


@dataclass(frozen=True)
class Trajectory:
    """Dense trajectory: ``t`` (M,), ``q``/``qd``/``qdd`` (M x nq), labelled segments."""

    t: Array
    q: Array
    qd: Array
    qdd: Array
    segments: tuple[Segment, ...]
    slowdowns: tuple[Slowdown, ...] = ()

    @property
    def duration(self) -> float:
        return float(self.t[-1]) if len(self.t) else 0.0

    def span(self, kind: str) -> float:
        """Total time (s) spent in segments of one kind."""
        return float(sum(s.t1 - s.t0 for s in self.segments if s.kind == kind))

    @property
    def laser_on(self) -> tuple[tuple[float, float], ...]:
        """Time intervals (s) in which the laser gate is on: the ``path`` and ``dwell``
        segments, adjacent ones merged."""
        out: list[tuple[float, float]] = []
        for s in self.segments:
            if s.kind not in LASER_KINDS:
                continue
            if out and s.t0 <= out[-1][1] + 1e-12:
                out[-1] = (out[-1][0], max(out[-1][1], s.t1))
            else:
                out.append((s.t0, s.t1))
        return tuple(out)

    def to_plan_arrays(self, system: System) -> dict[str, Any]:
        """The plan.json ``trajectory`` mapping (per robot name) with its dense tables as
        arrays (views of this trajectory's, no copy): what
        :func:`planner.io.plan_file.write_plan` writes and ``read_plan`` reads back."""

        def per_robot(X: Array) -> dict[str, Array]:
            out, i = {}, 0
            for r in system.robots:
                out[r.name] = X[:, i : i + r.nq]
                i += r.nq
            return out

        return {
            "t": self.t,
            "q": per_robot(self.q),
            "qd": per_robot(self.qd),
            "qdd": per_robot(self.qdd),
            "segments": [{"kind": s.kind.value, "t0": s.t0, "t1": s.t1} for s in self.segments],
            "laser_on": [[t0, t1] for t0, t1 in self.laser_on],
            "slowdowns": [_slowdown_dict(system, s) for s in self.slowdowns],
        }

    def to_plan(self, system: System) -> PlanTrajectory:
        """The plan's :class:`~planner.io.plan.Trajectory` (per robot name; its tables are
        read-only views of this trajectory's, no copy)."""
        return PlanTrajectory.from_document(self.to_plan_arrays(system))

    def to_plan_dict(self, system: System) -> dict[str, Any]:
        """The plan.json ``trajectory`` mapping as plain lists (a reply on the bus)."""
        out = self.to_plan_arrays(system)
        out["t"] = self.t.tolist()
        for key in ("q", "qd", "qdd"):
            out[key] = {r: X.tolist() for r, X in out[key].items()}
        return out


def _slowdown_dict(system: System, s: Slowdown) -> dict[str, object]:
    """A slowdown as plan.json writes it: the joint as robot name and index within it."""
    robot: str | None = None
    j = s.joint
    for r in system.robots:
        if 0 <= j < r.nq:
            robot = r.name
            break
        j -= r.nq
    j = j if robot is not None else -1
    return {"s0": s.s0, "s1": s.s1, "t0": s.t0, "t1": s.t1, "limit": s.limit,
            "robot": robot, "joint": int(j), "speed": s.speed}  # fmt: skip


class _Piece(NamedTuple):
    q: Array
    qd: Array
    qdd: Array
    kind: SegmentKind


# ------------------------------------------------------------------------------------------
# rest-to-rest moves (their closed-form durations: planner.path.rest_to_rest)
# ------------------------------------------------------------------------------------------
def ruckig_move(q0: Array, q1: Array, lim: Limits, rate: float) -> tuple[Array, Array, Array]:
    """Time-optimal jerk-limited rest-to-rest move sampled at ``rate`` (includes both ends;
    the last interval is padded at rest so the move lasts a whole number of periods)."""
    from ruckig import InputParameter, Result, Ruckig
    from ruckig import Trajectory as RuckigTrajectory

    n = len(q0)
    inp = InputParameter(n)
    inp.current_position, inp.target_position = list(q0), list(q1)
    inp.current_velocity = inp.current_acceleration = [0.0] * n
    inp.target_velocity = inp.target_acceleration = [0.0] * n
    inp.max_velocity, inp.max_acceleration = list(lim.velocity), list(lim.acceleration)
    inp.max_jerk = list(lim.jerk)
    traj = RuckigTrajectory(n)
    result = Ruckig(n).calculate(inp, traj)
    if result not in (Result.Working, Result.Finished):
        raise PlanError(f"Ruckig failed ({result}) for a move from {list(q0)} to {list(q1)}")
    m = int(np.ceil(traj.duration * rate - 1e-9))
    ts = np.minimum(np.arange(m + 1) / rate, traj.duration)
    Q, QD, QDD = (np.empty((m + 1, n)) for _ in range(3))
    for i, t in enumerate(ts):
        Q[i], QD[i], QDD[i] = traj.at_time(float(t))
    Q[-1], QD[-1], QDD[-1] = q1, 0.0, 0.0
    return Q, QD, QDD


# ------------------------------------------------------------------------------------------
# visit order
# ------------------------------------------------------------------------------------------
class VisitReport(NamedTuple):
    order: np.ndarray  # indices into the solved targets
    duration: float  # s, the optimised (or given) trajectory
    duration_given: float  # s, estimate visiting in the given order (same dwell)
    duration_optimised: float  # s, estimate in the chosen order


class _Joiner:
    """Pieces joined end to start (a piece starts where the last one ended) into one
    trajectory on t = i/rate. Memory stays near one trajectory, not two: pieces are copied
    into blocks of about ``block`` samples as they come (the small arrays freed for the
    next pieces), and the blocks into the final arrays one at a time, each freed once copied."""

    def __init__(self, rate: float, block: int = 1 << 16) -> None:
        self.rate, self.block = rate, block
        self.blocks: list[tuple[Array, Array, Array]] = []
        self.pending: list[tuple[Array, Array, Array]] = []
        self.pending_n = 0
        self.segs: list[Segment] = []
        self.i0 = 0

    def add(self, p: _Piece) -> None:
        skip = 1 if self.segs or self.blocks or self.pending else 0
        self.pending.append((p.q[skip:], p.qd[skip:], p.qdd[skip:]))
        self.pending_n += len(p.q) - skip
        i1 = self.i0 + len(p.q) - 1
        if i1 > self.i0:
            self.segs.append(Segment(p.kind, self.i0 / self.rate, i1 / self.rate))
        self.i0 = i1
        if self.pending_n >= self.block:
            self._flush()

    def _flush(self) -> None:
        if self.pending:
            q, qd, qdd = zip(*self.pending, strict=True)
            self.blocks.append((np.vstack(q), np.vstack(qd), np.vstack(qdd)))
            self.pending, self.pending_n = [], 0

    def trajectory(self, slowdowns: tuple[Slowdown, ...] = ()) -> Trajectory:
        self._flush()
        m = sum(len(b[0]) for b in self.blocks)
        out = [np.empty((m, self.blocks[0][k].shape[1])) for k in range(3)]
        o = 0
        self.blocks.reverse()
        while self.blocks:
            b = self.blocks.pop()
            for k in range(3):
                out[k][o : o + len(b[k])] = b[k]
            o += len(b[0])
            del b
        q, qd, qdd = out
        return Trajectory(np.arange(m) / self.rate, q, qd, qdd, tuple(self.segs), slowdowns)


def _assemble(
    pieces: list[_Piece], rate: float, slowdowns: tuple[Slowdown, ...] = ()
) -> Trajectory:
    """Concatenate pieces that share end/start samples into one trajectory on t = i/rate."""
    joiner = _Joiner(rate)
    for p in pieces:
        joiner.add(p)
    return joiner.trajectory(slowdowns)


def _hold(q: Array, seconds: float, rate: float, kind: SegmentKind) -> _Piece:
    m = round(seconds * rate)
    Q = np.tile(q, (m + 1, 1))
    return _Piece(Q, np.zeros_like(Q), np.zeros_like(Q), kind)


def points_trajectory(
    system: System, Q: Array, q_start: Array | None = None, dwell: float = 0.0,
    rate: float = defaults.SERVO_RATE_HZ, order: str = "optimal", progress: Callable[[int], None] | None = None,
    move: MoveFn | None = None,
) -> tuple[Trajectory, VisitReport]:  # fmt: skip
    """Rest-to-rest moves visiting every row of ``Q`` (solved targets, n x nq; NaN rows are
    skipped), ``dwell`` s on each. ``order``: ``given`` visits the rows as they come (the
    scenario's target order), ``optimal`` shortens the total move time
    (:func:`planner.path.tour.visit_order`, memory linear in n). ``progress(n)`` is called after
    the n-th move. ``move`` (default :func:`ruckig_move`) makes each rest-to-rest move."""
    move = move or ruckig_move
    lim = system.limits
    q0 = system.home if q_start is None else np.asarray(q_start, dtype=float)
    idx = np.flatnonzero(np.all(np.isfinite(Q), axis=1))
    given = np.arange(len(idx))
    seq = visit_order(Q[idx], q0, lim) if order == "optimal" else given

    def estimate(o: np.ndarray) -> float:
        P = np.vstack([q0, Q[idx][o]])
        return float(move_time(P[:-1], P[1:], lim).sum() + dwell * len(o))

    joiner = _Joiner(rate)  # the moves joined as they come: a 10^5-target plan is 3.7 M samples
    prev = q0
    for n, k in enumerate(idx[seq]):
        Qm, QDm, QDDm = move(prev, Q[k], lim, rate)
        joiner.add(_Piece(Qm, QDm, QDDm, SegmentKind.APPROACH if n == 0 else SegmentKind.MOVE))
        if dwell > 0:
            joiner.add(_hold(Q[k], dwell, rate, SegmentKind.DWELL))
        prev = Q[k]
        if progress is not None:
            progress(n)
    if not len(idx):
        joiner.add(_hold(q0, 0.0, rate, SegmentKind.DWELL))
    traj = joiner.trajectory()
    return traj, VisitReport(idx[seq], traj.duration, estimate(given), estimate(seq))


# ------------------------------------------------------------------------------------------
# paths
# ------------------------------------------------------------------------------------------


def _slowdowns(arc: Array, speed: Array, code: Array, joint: Array) -> tuple[Slowdown, ...]:
    names = ("spot", "velocity", "acceleration", "jerk")
    out, k, K = [], 0, len(arc)
    while k < K:
        if code[k] == 0:
            k += 1
            continue
        k1 = k
        while k1 + 1 < K and code[k1 + 1] != 0:
            k1 += 1
        i = k + int(np.argmin(speed[k : k1 + 1]))
        out.append(
            Slowdown(float(arc[k]), float(arc[k1]), names[code[i]], int(joint[i]), float(speed[i]))
        )
        k = k1 + 1
    return tuple(out)


def profile_piece(prof: Profile, q_end: Array, kind: SegmentKind = SegmentKind.PATH) -> _Piece:
    """Joints, velocities and accelerations along a timed profile (the last sample exactly
    ``q_end``)."""
    spline, s, sd, sdd = prof.spline, prof.s, prof.sd, prof.sdd
    q = spline(s)  # type: ignore[operator]
    d1, d2 = spline(s, 1), spline(s, 2)  # type: ignore[operator]
    q[-1] = q_end
    return _Piece(q, d1 * sd[:, None], d2 * sd[:, None] ** 2 + d1 * sdd[:, None], kind)


def time_path(
    q_path: Array, arc: Array, lim: Limits, spot_speed: float, rate: float
) -> tuple[_Piece, tuple[Slowdown, ...]]:
    """Sample s(t) from rest to rest along the path at ``rate`` and map it to joints."""
    prof = profile(q_path, arc, lim, spot_speed, rate)
    piece = profile_piece(prof, q_path[-1])
    return piece, _slowdowns(arc, prof.speed, prof.code, prof.joint)


def path_trajectory(
    system: System, runs: list[tuple[Array, Array]], q_start: Array | None = None,
    spot_speed: float = defaults.SPOT_SPEED_MPS, rate: float = defaults.SERVO_RATE_HZ,
    move: MoveFn | None = None,
) -> Trajectory:  # fmt: skip
    """Approach from ``q_start`` (default home), then each feasible run ``(q_k K x nq,
    arc_k K)`` swept at ``spot_speed`` (m/s) from rest to rest, with no run-in or run-out
    (:mod:`planner.path.marking` adds them); rest-to-rest ``move`` between runs, made by
    ``move`` (default :func:`ruckig_move`). Slowdowns carry the arc length along the whole
    path and their trajectory times."""
    move = move or ruckig_move
    lim = system.limits
    prev = system.home if q_start is None else np.asarray(q_start, dtype=float)
    pieces: list[_Piece] = []
    slow: list[Slowdown] = []
    i0 = 0  # index of the current piece's first sample
    for n, (Qp, arc) in enumerate(runs):
        Qm, QDm, QDDm = move(prev, Qp[0], lim, rate)
        pieces.append(_Piece(Qm, QDm, QDDm, SegmentKind.APPROACH if n == 0 else SegmentKind.MOVE))
        i0 += len(Qm) - 1
        if len(Qp) < 2:
            prev = Qp[0]
            continue
        prof = profile(Qp, arc - arc[0], lim, spot_speed, rate)
        pieces.append(profile_piece(prof, Qp[-1]))
        for sd in _slowdowns(arc - arc[0], prof.speed, prof.code, prof.joint):
            k0, k1 = np.searchsorted(prof.s, [sd.s0, sd.s1])
            slow.append(sd._replace(s0=sd.s0 + arc[0], s1=sd.s1 + arc[0], t0=(i0 + k0) / rate,
                                    t1=(i0 + min(k1, len(prof.s) - 1)) / rate))  # fmt: skip
        i0 += len(prof.s) - 1
        prev = Qp[-1]
    if not pieces:
        raise PlanError("no feasible path run to time")
    return _assemble(pieces, rate, tuple(slow))
