"""The follower's ``streaming`` mode on its own (no bus, no clock): Ruckig online toward the
streamed target within the limits, checked on the follower's own output positions by finite
differences, and against the time-optimal duration computed here in closed form."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.robot.follower import STOP_ACCELERATION, STOP_JERK, TrajectoryFollower
from planner.model.system import DEFAULT_HOME, Limits

HOME = np.array(DEFAULT_HOME)
LIMITS = Limits.ur_default()
DT = 0.002


def derivatives(q: np.ndarray, dt: float = DT) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Velocity, acceleration and jerk of sampled positions (K x n) by finite differences."""
    v = np.diff(q, axis=0) / dt
    a = np.diff(v, axis=0) / dt
    return v, a, np.diff(a, axis=0) / dt


def rest_to_rest_time(d: float, v: float, a: float, j: float) -> float:
    """Time-optimal rest-to-rest duration over distance ``d`` with velocity, acceleration
    and jerk limits, for a move that reaches ``a`` but not ``v`` (asserted): the symmetric
    profile jerk up (a/j), hold a for t2, jerk down, mirrored. Distance
    ``a (t1 + t2)(2 t1 + t2)`` solved for t2; duration ``2 (2 t1 + t2)``."""
    t1 = a / j
    # a t2^2 + 3 a t1 t2 + 2 a t1^2 - d = 0
    t2 = (-3 * a * t1 + math.sqrt(9 * a * a * t1 * t1 - 4 * a * (2 * a * t1 * t1 - d))) / (2 * a)
    assert t2 >= 0 and a * (t1 + t2) <= v, "profile assumption broken"
    return 2 * (2 * t1 + t2)


def run(f: TrajectoryFollower, steps: int, target=None) -> np.ndarray:  # type: ignore[no-untyped-def]
    out = []
    for k in range(steps):
        if target is not None:
            f.stream(*target((k + 1) * DT))
        out.append(f.step().q)
    return np.array(out)


def test_reaches_a_static_setpoint_time_optimally_within_limits() -> None:
    dq = np.array([0.5, -0.3, 0.2, 0.1, 0.0, -0.05])
    f = TrajectoryFollower(HOME, LIMITS, DT)
    f.stream(HOME + dq, np.zeros(6))
    q = np.vstack([HOME, HOME, HOME, run(f, 800)])  # at rest before the first step
    v, a, j = derivatives(q)
    slack = 1 + 1e-6
    assert np.all(np.abs(v) <= LIMITS.velocity * slack)
    assert np.all(np.abs(a) <= LIMITS.acceleration * slack)
    assert np.all(np.abs(j) <= LIMITS.jerk * slack)
    np.testing.assert_allclose(q[-1], HOME + dq, atol=0)  # lands exactly
    assert f.mode == "streaming" and np.all(f.qd == 0)
    # time-synchronised on the slowest joint (0.5 rad): its closed-form optimum
    arrival = (np.argmax(np.all(q == HOME + dq, axis=1)) - 2) * DT
    t_opt = rest_to_rest_time(0.5, math.pi, 5.0, 50.0)
    print(f"arrival {arrival:.3f} s, time-optimal {t_opt:.3f} s")
    assert t_opt - 1e-9 <= arrival <= t_opt + DT + 1e-9  # in the period holding the optimum


def test_plays_a_feasible_moving_target_exactly() -> None:
    """A sine on wrist_1 (0.1 rad at 0.5 Hz: 0.31 rad/s, 0.99 rad/s^2, 3.1 rad/s^3) given
    as (q, qd, qdd) at the end of each step, starting on it: the arm is on it every period."""
    amp, w = 0.1, 2 * math.pi * 0.5
    e = np.eye(6)[3]

    def ref(t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return (HOME + amp * math.sin(w * t) * e, amp * w * math.cos(w * t) * e,
                -amp * w * w * math.sin(w * t) * e)  # fmt: skip

    f = TrajectoryFollower(HOME, LIMITS, DT)
    f.reset(HOME, amp * w * e)
    q = run(f, 1500, ref)
    expected = np.array([ref((k + 1) * DT)[0] for k in range(1500)])
    assert np.abs(q - expected).max() < 1e-12


def test_a_target_beyond_reach_is_chased_within_the_limits() -> None:
    """The target jumps 1 rad back and forth every 0.2 s: Ruckig never exceeds a limit."""
    f = TrajectoryFollower(HOME, LIMITS, DT)

    def ref(t: float) -> tuple[np.ndarray, np.ndarray]:
        return HOME + (1.0 if int(t / 0.2) % 2 == 0 else -1.0) * np.ones(6), np.zeros(6)

    q = np.vstack([HOME, HOME, HOME, run(f, 1000, ref)])
    v, a, j = derivatives(q)
    slack = 1 + 1e-6
    assert np.abs(v).max() <= math.pi * slack
    assert np.abs(a).max() <= 5.0 * slack
    assert np.abs(j).max() <= 50.0 * slack
    assert np.abs(v).max() > 1.0  # it did chase


def test_finish_stream_rests_or_brakes() -> None:
    f = TrajectoryFollower(HOME, LIMITS, DT)
    f.stream(HOME + 0.01, np.zeros(6))
    run(f, 200)
    assert np.all(f.q == HOME + 0.01) and f.finish_stream() and f.mode == "idle"
    f.stream(HOME + 1.0, np.zeros(6))
    before = run(f, 100)  # mid-move
    v0 = np.abs(f.qd).max()
    assert v0 > 0.5 and not f.finish_stream() and f.mode == "braking"
    q = np.vstack([before[-2:], run(f, 60)])
    assert f.mode == "stopped" and np.all(f.qd == 0)
    _, a, _ = derivatives(q)
    assert np.abs(a).max() <= STOP_ACCELERATION * (1 + 1e-6)
    # stop time for a deceleration reaching its limit: v/a + a/j
    t_rest = (np.argmax(np.all(np.diff(q, axis=0) == 0, axis=1)) - 1) * DT  # from row 1
    assert t_rest == pytest.approx(
        v0 / STOP_ACCELERATION + STOP_ACCELERATION / STOP_JERK, abs=2 * DT
    )


def test_a_trajectory_replaces_the_stream() -> None:
    from drivers.robot.follower import Reference

    f = TrajectoryFollower(HOME, LIMITS, DT)
    f.stream(HOME + 0.5, np.zeros(6))
    run(f, 50)
    t = np.array([0.0, 1.0])
    q = np.vstack([f.q, f.q])
    f.follow(Reference(t, q, np.zeros((2, 6)), np.zeros((2, 6))))
    assert f.mode == "approach" and f.target is None


@pytest.mark.parametrize("start", [0.0, -math.pi / 2, 1.234])
def test_the_ruckig_boundary_distance_is_reached(start: float) -> None:
    """0.1 rad = 2 a^3 / j^2 at 5 rad/s^2 and 50 rad/s^3: Ruckig 0.19 raises on it from most
    starting positions (RUCKIG_NUDGE); the follower still arrives, in the optimal 0.4 s."""
    q0 = np.full(6, start)
    f = TrajectoryFollower(q0, LIMITS, DT)
    f.stream(q0 + 0.1, np.zeros(6))
    q = run(f, 400)
    arrival = (np.argmax(np.all(q == q0 + 0.1, axis=1)) + 1) * DT
    t_opt = rest_to_rest_time(0.1, math.pi, 5.0, 50.0)
    assert t_opt == pytest.approx(0.4) and t_opt - 1e-9 <= arrival <= t_opt + DT + 1e-9
