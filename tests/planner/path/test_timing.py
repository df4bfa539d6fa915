"""Timing: closed-form move time vs Ruckig, sampled limits, visit order, path speed."""

from __future__ import annotations

import numpy as np
import pytest
from ruckig import InputParameter, Result, Ruckig, Trajectory

from planner.model.build import build_system
from planner.model.transforms import make_T
from planner.path.rest_to_rest import move_time, rest_to_rest_time
from planner.path.timing import path_trajectory, points_trajectory, ruckig_move, visit_order

RATE = 500.0


@pytest.fixture(scope="module")
def system():
    return build_system(make_T(p=[0.5, 0, 0.3]))


@pytest.mark.parametrize("d", [1e-4, 0.05, 0.5, 3.0])
def test_rest_to_rest_time_matches_ruckig(d):
    inp = InputParameter(1)
    inp.current_position, inp.target_position = [0.0], [d]
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = [np.pi], [5.0], [50.0]
    traj = Trajectory(1)
    assert Ruckig(1).calculate(inp, traj) in (Result.Working, Result.Finished)
    assert rest_to_rest_time(np.array(d), np.pi, 5.0, 50.0) == pytest.approx(
        traj.duration, rel=1e-6
    )


def _fd(q, n):
    return np.diff(q, n=n, axis=0) * RATE**n


def test_ruckig_move_respects_limits(system):
    lim = system.limits
    q0, q1 = system.home, system.home + np.array([1.0, -0.5, 0.3, 0.0, 0.2, -2.0])
    Q, QD, _ = ruckig_move(q0, q1, lim, RATE)
    np.testing.assert_allclose(Q[[0, -1]], [q0, q1], atol=1e-12)
    assert np.abs(QD[[0, -1]]).max() < 1e-9
    for n, bound in ((1, lim.velocity), (2, lim.acceleration), (3, lim.jerk)):
        assert (np.abs(_fd(Q, n)) <= bound * 1.02 + 1e-9).all()
    assert len(Q) - 1 == pytest.approx(move_time(q0, q1, lim) * RATE, abs=1.5)


def test_visit_order_beats_given_on_shuffled_line(system):
    lim = system.limits
    rng = np.random.default_rng(0)
    xs = np.linspace(0.1, 1.0, 30)
    Q = system.home + np.outer(rng.permutation(xs), np.ones(6)) * 0.5
    order = visit_order(Q, system.home, lim)
    assert sorted(order.tolist()) == list(range(30))
    np.testing.assert_allclose(np.sort(Q[order, 0]), Q[order, 0])  # monotone sweep is optimal
    traj, rep = points_trajectory(system, Q, dwell=0.05, rate=RATE)
    P = np.vstack([system.home, np.sort(Q, axis=0)])
    best = move_time(P[:-1], P[1:], lim).sum() + 30 * 0.05  # sorted sweep, computed directly
    assert rep.duration_optimised == pytest.approx(best, rel=1e-9)
    assert rep.duration_given > 1.5 * best
    assert traj.span("dwell") == pytest.approx(30 * 0.05, abs=1e-9)
    assert [s.kind for s in traj.segments[:3]] == ["approach", "dwell", "move"]
    assert traj.duration == pytest.approx(rep.duration_optimised, rel=0.05)


def test_path_speed_and_slowdown(system):
    lim = system.limits
    arc = np.linspace(0.0, 0.1, 101)
    slow = system.home + np.outer(arc, np.ones(6))  # 1 rad per m: the spot speed binds
    traj = path_trajectory(system, [(slow, arc)], spot_speed=0.02, rate=RATE)
    # L / v plus the jerk-limited ramp v/a + a/j with a = 20 v, j = 20 a (= 0.1 s)
    assert traj.span("path") == pytest.approx(0.1 / 0.02 + 0.1, abs=0.005)
    assert not traj.slowdowns
    fast = system.home + np.outer(arc, [300.0, 0, 0, 0, 0, 0])  # 300 rad/m: velocity binds
    traj = path_trajectory(system, [(fast, arc)], spot_speed=0.02, rate=RATE)
    assert traj.span("path") > 0.1 / (0.9 * np.pi / 300.0)
    assert traj.slowdowns and traj.slowdowns[0].limit == "velocity"
    assert traj.slowdowns[0].joint == 0
    for n, bound in ((1, lim.velocity), (2, lim.acceleration), (3, lim.jerk)):
        assert (np.abs(_fd(traj.q, n)) <= bound * 1.02 + 1e-9).all()
    np.testing.assert_allclose(_fd(traj.q, 1), (traj.qd[1:] + traj.qd[:-1]) / 2, atol=0.01)


def test_points_progress_and_arrivals(system):
    rng = np.random.default_rng(2)
    Q = system.home + rng.uniform(-0.3, 0.3, (6, 6))
    Q[2] = np.nan  # a failed target is skipped
    calls: list[int] = []
    traj, rep = points_trajectory(system, Q, rate=RATE, order="given", progress=calls.append)
    assert calls == list(range(5))
    assert rep.order.tolist() == [0, 1, 3, 4, 5]
    ends = [round(s.t1 * RATE) for s in traj.segments]
    np.testing.assert_allclose(traj.q[ends], Q[[0, 1, 3, 4, 5]], atol=1e-12)
    np.testing.assert_allclose(traj.qd[ends], 0.0, atol=1e-9)  # rest to rest
