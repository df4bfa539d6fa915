"""Safety of timed trajectories: collision-free moves and the dense check of a whole plan.

:class:`SafeMover` makes the rest-to-rest moves of a trajectory: a Ruckig move, swept-checked
(:func:`~planner.safety.sweep.check_sweep`); on a collision a small sampling search in joint
space looks for an intermediate waypoint (clear itself, both Ruckig legs clear) and the move
goes through it, else the collision is recorded. :func:`check_trajectory` checks a whole
trajectory densely: the arms swept between every pair of samples, and the beam at every
sample while the laser is on (``path`` and ``dwell`` segments, or explicit ``laser_on``
intervals), its end being the point of the last ray nearest the targets (or 2 m out when it
is not on one): coal measures the samples that conservative advancement from the last
measured one cannot certify (:mod:`planner.safety.beam_cover`; same result as measuring
every sample). Times in s, joints in rad, world frame, metres.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from functools import lru_cache
from typing import Any, NamedTuple

import casadi as ca
import numpy as np

from planner.model.system import Limits
from planner.model.transforms import Array
from planner.safety.beam_cover import advance, coverable, pair_slack, pair_table
from planner.safety.model import Safety, Violation
from planner.safety.sweep import SweepViolation, check_sweep
from schemas.plan_records import LASER_KINDS

MoveFn = Callable[[Array, Array, Limits, float], tuple[Array, Array, Array]]
#: waypoints tried per colliding move
DETOUR_TRIES = 40


class MoveFailure(NamedTuple):
    """A move q0 -> q1 (stacked rad) with no collision-free detour found: its violation."""

    q0: Array
    q1: Array
    violation: SweepViolation


class SafeMover:
    """A drop-in for a rest-to-rest move function ``move(q0, q1, limits, rate)``: checks
    the move swept against the arms' clearance and detours around a collision (see the
    module docstring). ``failures`` lists the moves left colliding; ``detours`` counts the
    moves re-planned through a waypoint."""

    def __init__(
        self, safety: Safety, move: MoveFn, tries: int = DETOUR_TRIES, seed: int = 0,
        guard: bool = True,
    ) -> None:  # fmt: skip
        self.safety = safety
        self.move = move
        self.tries = tries
        self.guard = guard  # False: plain moves (a dense check of the whole result follows)
        self.rng = np.random.default_rng(seed)
        self.failures: list[MoveFailure] = []
        self.detours = 0

    def _sweep(self, Q: Array, rate: float) -> SweepViolation | None:
        s = self.safety
        return check_sweep(s.world, np.arange(len(Q)) / rate, Q, s.settings.clearance)

    def __call__(
        self, q0: Array, q1: Array, lim: Limits, rate: float
    ) -> tuple[Array, Array, Array]:
        Q, QD, QDD = self.move(q0, q1, lim, rate)
        if not self.guard:
            return Q, QD, QDD
        bad = self._sweep(Q, rate)
        if bad is None:
            return Q, QD, QDD
        detour = self._detour(q0, q1, lim, rate)
        if detour is not None:
            self.detours += 1
            return detour
        self.failures.append(MoveFailure(np.array(q0), np.array(q1), bad))
        return Q, QD, QDD

    def _detour(
        self, q0: Array, q1: Array, lim: Limits, rate: float
    ) -> tuple[Array, Array, Array] | None:
        """Two Ruckig legs through a sampled waypoint, both clear, or None."""
        mid = (np.asarray(q0) + np.asarray(q1)) / 2
        spread = float(np.abs(np.asarray(q1) - q0).max()) / 2 + 0.2  # rad
        for i in range(self.tries):
            sigma = spread * (0.3 + 1.7 * i / max(self.tries - 1, 1))
            qw = np.clip(mid + self.rng.normal(0.0, sigma, len(mid)), lim.lower, lim.upper)
            if self.safety.arms(qw) is not None:
                continue
            A = self.move(q0, qw, lim, rate)
            if self._sweep(A[0], rate) is not None:
                continue
            B = self.move(qw, q1, lim, rate)
            if self._sweep(B[0], rate) is not None:
                continue
            return tuple(np.vstack([a, b[1:]]) for a, b in zip(A, B, strict=True))  # type: ignore[return-value]
        return None


class TrajectoryCheck(NamedTuple):
    """The dense check of one trajectory: the first swept arm violation, the first beam
    violation while the laser is on (time s, violation), the samples checked, the time
    the check took (s), how many beam samples coal measured (the rest certified by
    conservative advancement) and the time the beam part took (s)."""

    sweep: SweepViolation | None
    beam: tuple[float, Violation] | None
    samples: int
    beam_samples: int
    seconds: float
    beam_exact: int = 0
    beam_seconds: float = 0.0

    @property
    def ok(self) -> bool:
        return self.sweep is None and self.beam is None


def laser_mask(t: Array, segments: Sequence[tuple[str, float, float]],
               laser_on: Sequence[Sequence[float]] | None = None) -> Array:  # fmt: skip
    """Samples at which the laser may be on: inside ``laser_on`` intervals when given, else
    inside ``path`` and ``dwell`` segments (``(kind, t0, t1)``, s)."""
    mask = np.zeros(len(t), dtype=bool)
    spans = laser_on if laser_on is not None else [(a, b) for k, a, b in segments
                                                   if k in LASER_KINDS]  # fmt: skip
    for a, b in spans:
        mask |= (t >= a - 1e-9) & (t <= b + 1e-9)
    return mask


#: configurations per call of the mapped trace function (the last call is padded)
TRACE_CHUNK = 512


@lru_cache(maxsize=16)
def _trace_function(kinematics: tuple[Any, ...], surfaces: tuple[Any, ...]) -> ca.Function:
    """The mirror hits (3 x N) and the last direction of a chain of robot models and mirror
    surfaces, symbolic in q and the geometry (the beam function's chain without its target
    outputs; cached per chain)."""
    from planner.beam.graph import beam_chain, chain_symbols

    sym = chain_symbols(kinematics)
    hits, _, dirs, _, _, _ = beam_chain(sym.q, sym.world_T_laser, sym.bases, sym.mounts,
                                        kinematics, surfaces)  # fmt: skip
    names = ["q", "world_T_laser", "world_T_base", "flange_T_mirror"]
    return ca.Function("trace", [sym.q, sym.world_T_laser, sym.world_T_base,
                                 sym.flange_T_mirror], [ca.horzcat(*hits), dirs[-1]],
                       names, ["hits", "dir"])  # fmt: skip


@lru_cache(maxsize=64)
def _trace_map(kinematics: tuple[Any, ...], surfaces: tuple[Any, ...], n: int) -> ca.Function:
    return _trace_function(kinematics, surfaces).map(n)


def trace_batch(safety: Safety, Q: Array) -> tuple[Array, Array]:
    """The beams of configurations ``Q`` (M x nq) through the planner's beam chain: the
    polylines laser exit + N mirror hits (M x (N + 1) x 3, world, m) and the unit directions
    leaving the last mirror (M x 3)."""
    from planner.beam.graph import system_params

    system = safety.system
    N, M = system.n_robots, len(Q)
    prm = system_params(system)
    geo = [prm["world_T_laser"], prm["world_T_base"], prm["flange_T_mirror"]]
    n = min(TRACE_CHUNK, 1 << max(M - 1, 0).bit_length())
    f = _trace_map(system.kinematics, system.surfaces, n)
    hits, dirs = np.empty((M, N, 3)), np.empty((M, 3))
    for a in range(0, M, n):
        q = Q[a : a + n]
        m = len(q)
        if m < n:
            q = np.vstack([q, np.repeat(q[-1:], n - m, axis=0)])
        h, d = f(q.T, *geo)
        hits[a : a + m] = np.asarray(h).T.reshape(n, N, 3)[:m]
        dirs[a : a + m] = np.asarray(d).T[:m]
    p0 = np.broadcast_to(system.world_T_laser[:3, 3], (M, 1, 3))
    return np.concatenate([p0, hits], axis=1), dirs


#: m: a ray passing this close to a target ends there; else it runs on for BEYOND m
ON_TARGET, BEYOND = 0.01, 2.0


def beam_ends(p: Array, v: Array, targets: Array, chunk: int = 1024) -> Array:
    """Where each ray (p, unit v: M x 3) ends: at its point nearest the target closest to it
    (ahead of p) when that target is within :data:`ON_TARGET`; otherwise the beam is not on
    a target and runs on :data:`BEYOND` m (it must stay clear all that way). The nearest
    target is found with matrix products (|w|^2 - s^2), its distance then recomputed
    directly."""
    out = p + BEYOND * v
    T = np.asarray(targets, dtype=float).reshape(-1, 3)
    if not len(T):
        return out
    T2 = (T * T).sum(axis=1)
    for a in range(0, len(p), chunk):
        P, V = p[a : a + chunk], v[a : a + chunk]
        s = V @ T.T - (P * V).sum(axis=1)[:, None]  # (m, K): along-ray distance
        w2 = T2[None, :] - 2.0 * (P @ T.T) + (P * P).sum(axis=1)[:, None]
        perp2 = np.where(s > 0, w2 - s * s, np.inf)
        k = np.argmin(perp2, axis=1)
        w = T[k] - P
        sk = (w * V).sum(axis=1)
        perp = np.linalg.norm(w - sk[:, None] * V, axis=1)
        on = (sk > 0) & (perp <= ON_TARGET)
        out[a : a + chunk] = np.where(on[:, None], P + sk[:, None] * V, out[a : a + chunk])
    return out


def check_beam_samples(
    safety: Safety, t: Array, Q: Array, mask: Array, targets: Array
) -> tuple[tuple[float, Violation] | None, int, int]:
    """The first beam violation among the masked samples (repeated configurations, as in a
    dwell, are checked once), how many configurations were cleared up to it (all when
    none) and how many of them coal measured: the others were certified from the last
    measured one by conservative advancement (:mod:`planner.safety.beam_cover`)."""
    idx = np.flatnonzero(mask)
    if len(idx):
        keep = np.r_[True, np.any(Q[idx[1:]] != Q[idx[:-1]], axis=1)]
        idx = idx[keep & np.all(np.isfinite(Q[idx]), axis=1)]
    if not len(idx):
        return None, 0, 0
    Qs = Q[idx]
    pts, v = trace_batch(safety, Qs)
    ends = beam_ends(pts[:, -1], v, targets)
    polylines = np.concatenate([pts, ends[:, None, :]], axis=1)
    rows = np.flatnonzero(np.all(np.isfinite(polylines), axis=(1, 2)))
    first_aperture = safety.apertures_batch(polylines)
    stop = len(idx) if first_aperture is None else first_aperture[0]
    table = pair_table(safety) if coverable(safety) else None
    i, exact = 0, 0
    while i < len(rows) and rows[i] < stop:
        m = int(rows[i])
        bad = safety.beam(Qs[m], polylines[m], apertures=False)
        exact += 1
        if bad is not None:
            return (float(t[idx[m]]), bad), m + 1, exact
        if table is None:
            i += 1
            continue
        i = advance(table, pair_slack(safety, table), rows, i, Qs, polylines)
    if first_aperture is not None:
        return (float(t[idx[stop]]), first_aperture[1]), stop + 1, exact
    return None, len(idx), exact


def check_trajectory(
    safety: Safety,
    t: Array,
    Q: Array,
    segments: Sequence[tuple[str, float, float]],
    targets: Array,
    laser_on: Sequence[Sequence[float]] | None = None,
) -> TrajectoryCheck:
    """Dense safety check of a trajectory ``(t, Q)`` (see the module docstring);
    ``targets`` (K x 3, world) locate the spot while the laser is on."""
    t0 = time.perf_counter()
    t, Q = np.asarray(t, dtype=float), np.asarray(Q, dtype=float)
    sweep = check_sweep(safety.world, t, Q, safety.settings.clearance) if len(t) else None
    mask = laser_mask(t, segments, laser_on)
    t1 = time.perf_counter()
    beam, n, exact = check_beam_samples(safety, t, Q, mask, np.asarray(targets, dtype=float))
    t2 = time.perf_counter()
    return TrajectoryCheck(sweep, beam, len(t), n, t2 - t0, exact, t2 - t1)
