"""The moves between a path's strokes (from one stroke's run-out to the next one's run-in)
go through the same collision-free mover as the moves between point targets: a direct move
that sweeps one arm through the other is detoured (clear by the checker's numpy geometry at
every sample), and a stroke no detour reaches fails whole as ``collision``."""

from __future__ import annotations

import numpy as np

from planner.path.marking import MarkRun, marking_trajectory
from planner.path.timing import ruckig_move
from planner.safety import check_sweep
from planner.safety.model import Safety, SafetySettings
from planner.safety.trajectory import SafeMover
from tests.planner.safety.numpy_rules import hits, setup
from tests.planner.safety.worlds import UPRIGHT, relay

RATE = 500.0


def _stroke(q: np.ndarray, joint: int) -> MarkRun:
    """Five samples 1 mm apart, one joint of arm1 turning 0.01 rad over them."""
    Q = np.tile(q, (5, 1))
    Q[:, joint] += np.linspace(0.0, 0.01, 5)
    return MarkRun(Q, np.linspace(0.0, 0.004, 5), 1, 4, 0.0)


def _strokes() -> list[MarkRun]:
    """arm1 stretched out: the first stroke on one side of arm0, the second 180 deg round
    (the direct move between them pans arm1 through arm0's space, gap 0.9 m)."""
    a = np.r_[UPRIGHT, [np.pi / 2, 0.0, 0.0, 0.0, 0.0, 0.0]]
    b = np.r_[UPRIGHT, [3 * np.pi / 2, 0.0, 0.0, 0.0, 0.0, 0.0]]
    return [_stroke(a, 10), _stroke(b, 10)]


def _move_between(traj) -> tuple[int, int]:  # type: ignore[no-untyped-def]
    kinds = [s.kind for s in traj.segments]
    i = kinds.index("move")
    assert kinds[i - 1] == "run_out" and kinds[i + 1] == "run_in"
    seg = traj.segments[i]
    return round(seg.t0 * RATE), round(seg.t1 * RATE)


def test_colliding_move_between_strokes_is_detoured() -> None:
    system = relay(gap=0.9)
    rules = Safety(system)
    runs = _strokes()
    plain = marking_trajectory(system, runs, runs[0].q[0], 0.002, RATE)
    i0, i1 = _move_between(plain)
    bad = check_sweep(rules.world, plain.t, plain.q)
    assert bad is not None and i0 <= bad.sample <= i1  # the direct move collides
    assert bad.clearance.check.value == "arm_arm"
    mover = SafeMover(rules, ruckig_move)
    traj = marking_trajectory(system, runs, runs[0].q[0], 0.002, RATE, move=mover)
    assert mover.detours == 1 and not mover.failures
    assert check_sweep(rules.world, traj.t, traj.q) is None
    j0, j1 = _move_between(traj)
    np.testing.assert_allclose(traj.q[j0], runs[0].q[-1])  # from the run-out end
    np.testing.assert_allclose(traj.q[j1], runs[1].q[0])  # to the next run-in start
    s = setup(system)
    assert all(not hits(s, system, q) for q in traj.q[::3])  # the checker's numpy geometry


def test_stroke_without_a_detour_fails_whole_as_collision() -> None:
    from planner.plan.safe_timing import _whole_strokes

    system = relay(gap=0.9)
    rules = Safety(system, settings=SafetySettings(clearance=0.45))  # never met
    runs = _strokes()
    mover = SafeMover(rules, ruckig_move, tries=3)
    marking_trajectory(system, runs, runs[0].q[0], 0.002, RATE, move=mover)
    assert len(mover.failures) >= 1
    f = mover.failures[-1]
    np.testing.assert_allclose(f.q1, runs[1].q[0])
    assert f.violation.reason == "collision" and f.violation.clearance.required == 0.45
    assert f.violation.clearance.check.value == "arm_arm"
    # the sample nearest the move's end is blamed; the whole stroke it starts fails with it
    from types import SimpleNamespace

    from planner.safety.model import clearance_violation

    v = clearance_violation(f.violation.clearance)
    sols = [SimpleNamespace(ok=True) for _ in range(10)]
    path = SimpleNamespace(ok=np.ones(10, dtype=bool))
    strokes = [[0, 1, 2, 3, 4], [4, 5, 6, 7, 8, 9]]  # sharing vertex 4
    out = _whole_strokes({4: v}, mover, sols, path, strokes)  # type: ignore[arg-type]
    assert sorted(out) == [4, 5, 6, 7, 8, 9] and all(x is v for x in out.values())
    assert v.reason == "collision" and v.evidence["required_m"] == 0.45
    assert {str(v.evidence["a"]).split("/")[0], str(v.evidence["b"]).split("/")[0]} == {
        "arm0",
        "arm1",
    }
    # without strokes: the run of solved samples
    path.ok[3] = False
    out = _whole_strokes({5: v}, mover, sols, path, None)  # type: ignore[arg-type]
    assert sorted(out) == [4, 5, 6, 7, 8, 9]
