"""Timing under the safety rules: time the solved targets with collision-free moves, check
the whole trajectory densely, and drop what cannot be made safe.

:func:`safe_timing` times the solutions through a caller's timing function with plain moves
and runs :func:`~planner.safety.trajectory.check_trajectory` on the result; when that finds
a collision in a move it times again, every move now made by a
:class:`~planner.safety.trajectory.SafeMover` (swept, detoured around arm collisions): the
approach, the moves between targets and between a path's strokes. A move left colliding
fails its destination target (``collision``; for a path, the whole stroke it leads to); a swept collision inside a path or
dwell, or a beam violation while the laser is on, fails the solved target or path sample
whose configuration is nearest in joint space (a path sample becomes a gap); then the rest
is timed again, a few rounds at most. What remains is reported in the check. Times in s,
joints in rad, world frame, metres.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from planner.model.polyline import runs
from planner.model.transforms import Array
from planner.plan.gaps import SampleGap, failed_with, split_path
from planner.safety.model import Safety, Violation, clearance_violation, emit_warning
from planner.safety.trajectory import MoveFn, SafeMover, TrajectoryCheck, check_trajectory

if TYPE_CHECKING:
    from planner.ik import Solution
    from planner.path.result import PathResult

#: re-timing rounds after dropping unsafe targets
ROUNDS = 4
TimeFn = Callable[[list["Solution"], "PathResult | None", MoveFn], Any]


class SafeTiming(NamedTuple):
    """The solutions and path result after the unsafe ones were dropped, the timed result of
    the caller's timing function (None if nothing is left to time), the last dense check
    and figures for plan.json ``metrics.extra`` (s, counts)."""

    solutions: list[Solution]
    path: PathResult | None
    timed: Any
    check: TrajectoryCheck | None
    figures: dict[str, float]


def safe_timing(
    safety: Safety,
    solutions: list[Solution],
    path: PathResult | None,
    targets: Array,
    time_fn: TimeFn,
    move: MoveFn,
    start: Array,
    rounds: int = ROUNDS,
    strokes: Sequence[Sequence[int]] | None = None,
) -> SafeTiming:
    """Time ``solutions`` (see the module docstring). ``time_fn(solutions, path, mover)``
    returns an object with a ``trajectory`` (``t``, ``q``, ``segments``) or None; ``move``
    is the plain rest-to-rest move the mover wraps; ``targets`` (K x 3, world) locate the
    spot while the laser is on; ``start`` (stacked rad) is where the trajectory starts: if it
    breaks the rules itself, a warning says so and no target is blamed for it. ``strokes``
    (a path's sample index sequences marked in one go; default: every run of solved
    samples) say which samples fail with a move to a stroke that has no collision-free
    detour: the whole stroke."""
    figures = {"safety_detours": 0.0, "safety_dropped": 0.0, "safety_check_time": 0.0}
    unsafe_start = safety.arms(start)
    if unsafe_start is not None:  # no target is to blame for that
        emit_warning(f"the start configuration breaks the safety rules: {unsafe_start.text}")
        figures["safety_start_unsafe"] = 1.0
    timed, check, guard = None, None, False
    for n in range(rounds):
        mover = SafeMover(safety, move, guard=guard)
        timed = time_fn(solutions, path, mover)
        figures["safety_detours"] += mover.detours
        if timed is None:
            return SafeTiming(solutions, path, None, None, figures)
        traj = timed.trajectory
        segs = [(s.kind, s.t0, s.t1) for s in traj.segments]
        check = check_trajectory(safety, traj.t, traj.q, segs, targets,
                                 getattr(traj, "laser_on", None))  # fmt: skip
        figures["safety_check_time"] = check.seconds
        figures["safety_beam_samples"] = float(check.beam_samples)
        figures["safety_beam_measured"] = float(check.beam_exact)
        figures["safety_beam_time"] = check.beam_seconds
        if not guard and _in_a_move(check, traj) and n < rounds - 1:
            guard = True  # re-time with every move swept and detoured where needed
            continue
        blamed = _blame(solutions, mover, check, traj)
        if path is not None:
            blamed = _whole_strokes(blamed, mover, solutions, path, strokes)
        if not blamed or n == rounds - 1:
            break
        figures["safety_dropped"] += len(blamed)
        solutions, path = _drop(solutions, path, blamed)
    figures["safety_unresolved"] = float(check is not None and not check.ok)
    return SafeTiming(solutions, path, timed, check, figures)


def _in_a_move(check: TrajectoryCheck, traj: Any) -> bool:
    """The swept check found a collision inside an approach or move segment."""
    if check.sweep is None:
        return False
    t = check.sweep.t
    return any(s.kind in ("approach", "move") and s.t0 <= t <= s.t1 for s in traj.segments)


def _nearest(solutions: list[Solution], q: Array) -> int | None:
    idx = [k for k, s in enumerate(solutions) if s.ok and s.q is not None]
    if not idx:
        return None
    Q = np.array([solutions[k].q for k in idx])
    return idx[int(np.argmin(np.linalg.norm(Q - q, axis=1)))]


def _blame(
    solutions: list[Solution], mover: SafeMover, check: TrajectoryCheck, traj: Any
) -> dict[int, Violation]:
    """Solution index -> the violation that fails it."""
    out: dict[int, Violation] = {}
    for f in mover.failures:
        if f.violation.sample == 0 and f.violation.t == 0.0:
            continue  # the move starts in violation: not the destination's fault
        k = _nearest(solutions, f.q1)
        if k is not None:
            v = clearance_violation(f.violation.clearance)
            out.setdefault(k, _at(v, f.violation.t, "no collision-free move to it found"))
    if out:
        return out
    events: list[tuple[float, Violation]] = []
    if check.sweep is not None:
        events.append((check.sweep.t, clearance_violation(check.sweep.clearance)))
    if check.beam is not None:
        events.append(check.beam)
    for t, v in events:
        i = int(np.clip(np.searchsorted(traj.t, t), 0, len(traj.t) - 1))
        seg = next((s for s in traj.segments if s.t0 <= t <= s.t1), None)
        if seg is not None and seg.kind in ("approach", "move"):  # blame the destination
            i = int(np.clip(np.searchsorted(traj.t, seg.t1), 0, len(traj.t) - 1))
        k = _nearest(solutions, traj.q[i])
        if k is not None:
            out.setdefault(k, _at(v, t, "on the timed trajectory"))
    return out


def _whole_strokes(
    blamed: dict[int, Violation], mover: SafeMover, solutions: list[Solution],
    path: PathResult, strokes: Sequence[Sequence[int]] | None,
) -> dict[int, Violation]:  # fmt: skip
    """A path sample blamed for a move with no collision-free detour (the move to its
    stroke's run-in) fails with every solved sample of its stroke: dropping it alone would
    only move the run-in start a sample along, into the same collision."""
    if not mover.failures:
        return blamed
    spans = [list(s) for s in strokes] if strokes else [list(range(a, b)) for a, b in
                                                          runs(np.asarray(path.ok))]  # fmt: skip
    out = dict(blamed)
    for k, v in blamed.items():
        mine = [s for s in spans if k in s]
        for i in min(mine, key=lambda s: s.index(k), default=[k]):
            if solutions[i].ok:
                out.setdefault(i, v)
    return out


def _at(v: Violation, t: float, where: str) -> Violation:
    evidence = {**v.evidence, "t": float(t), "where": where}
    return Violation(v.check, v.margin, f"{v.text} at t = {t:.3f} s ({where})", evidence)


def _drop(
    solutions: list[Solution], path: PathResult | None, blamed: dict[int, Violation]
) -> tuple[list[Solution], PathResult | None]:
    if path is not None:
        gaps = {k: SampleGap(v.reason, dict(v.evidence), v.text,
                             np.asarray(v.evidence.get("point", [np.nan] * 3), dtype=float))
                for k, v in blamed.items()}  # fmt: skip
        return split_path(solutions, path, gaps)
    out = list(solutions)
    for k, v in blamed.items():
        out[k] = failed_with(solutions[k], v.reason, dict(v.evidence))
    return out, None
