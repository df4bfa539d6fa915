"""Swept trajectory check: first violation, between-sample collisions, clear trajectories."""

from __future__ import annotations

import numpy as np
import pytest

from planner.safety import SafetyWorld, all_pair_distances, check_sweep
from planner.safety.sweep import reach_table
from tests.planner.safety.worlds import REACH, UPRIGHT, relay

RATE = 500.0
WORLD = SafetyWorld(relay())


def _line(q0: np.ndarray, q1: np.ndarray, duration: float, rate: float = RATE):
    t = np.arange(0.0, duration + 1e-12, 1.0 / rate)
    s = (t / duration)[:, None]
    return t, (1 - s) * q0 + s * q1


def _swing(pan0: float, pan1: float) -> tuple[np.ndarray, np.ndarray]:
    """arm1 stretched horizontally, panning from pan0 to pan1 (rad) past upright arm0."""
    q0 = np.r_[UPRIGHT, [pan0, 0.0, 0.0, 0.0, 0.0, 0.0]]
    q1 = np.r_[UPRIGHT, [pan1, 0.0, 0.0, 0.0, 0.0, 0.0]]
    return q0, q1


def test_first_violation_at_the_servo_rate_matches_a_finer_scan():
    q0, q1 = np.r_[UPRIGHT, UPRIGHT], np.r_[REACH, REACH]
    t, Q = _line(q0, q1, 2.0)
    v = check_sweep(WORLD, t, Q)
    assert v is not None and not v.clearance.ok
    assert v.reason == "collision" and "t = " in str(v)
    assert v.clearance.a.startswith("arm0/") and v.clearance.b.startswith("arm1/")
    # a scan 20x finer than the servo rate finds nothing earlier than the reported time
    tf, Qf = _line(q0, q1, 2.0, RATE * 20)
    required = np.array([0.0 if k.value == "arm_self" else 0.01 for k in WORLD.pair_kinds])
    first = next(i for i in range(len(tf)) if np.any(all_pair_distances(WORLD, Qf[i]) < required))
    assert v.t <= tf[first] + 1e-12
    assert v.t >= tf[first] - 1.0 / RATE


def test_collision_between_two_clear_samples_is_found():
    world = SafetyWorld(relay(gap=0.9))  # arm1's stretched arm sweeps through arm0
    q0, q1 = _swing(np.pi / 2, 3 * np.pi / 2)
    t = np.array([0.0, 1.0])
    for q in (q0, q1):  # both samples are clear
        assert check_sweep(world, t[:1], q[None]) is None
    v = check_sweep(world, t, np.array([q0, q1]))
    assert v is not None and 0.0 < v.t < 1.0 and v.sample == 0
    assert v.clearance.distance < 0.01
    assert v.clearance.b.startswith("arm1/") or v.clearance.a.startswith("arm1/")


def test_clear_trajectory_passes():
    q0, q1 = _swing(np.pi / 2, np.pi / 2 - 0.5)
    t, Q = _line(q0, q1, 0.5)
    assert check_sweep(WORLD, t, Q) is None


def test_reach_bound_covers_the_true_motion():
    rng = np.random.default_rng(5)
    R = reach_table(WORLD)
    for _ in range(20):
        q = rng.uniform(-3, 3, WORLD.nq)
        dq = rng.uniform(-0.05, 0.05, WORLD.nq)
        WORLD.update(q)
        before = [WORLD.placement(p.index).getTranslation() for p in WORLD.parts]
        WORLD.update(q + dq)
        after = [WORLD.placement(p.index).getTranslation() for p in WORLD.parts]
        moved = np.linalg.norm(np.array(after) - np.array(before), axis=1)
        assert np.all(moved <= R @ np.abs(dq) + 1e-12)


def test_bad_trajectories_are_rejected():
    t = np.array([0.0, 0.002])
    with pytest.raises(ValueError):
        check_sweep(WORLD, t, np.zeros((2, 6)))
    with pytest.raises(ValueError):
        check_sweep(WORLD, t, np.full((2, 12), np.nan))


def test_pair_bound_covers_the_true_distance_change():
    from planner.safety.sweep import pair_weights

    W = pair_weights(WORLD)
    rng = np.random.default_rng(7)
    for _ in range(30):
        q = rng.uniform(-3, 3, WORLD.nq)
        dq = rng.uniform(-0.05, 0.05, WORLD.nq)
        d0, d1 = all_pair_distances(WORLD, q), all_pair_distances(WORLD, q + dq)
        assert np.all(np.abs(d1 - d0) <= W @ np.abs(dq) + 1e-9)
    # a robot's own moving links ignore the joints that carry both: panning does not count
    moving = {p.index for p in WORLD.parts if p.link > 0}
    own = [i for i, cp in enumerate(WORLD.geom_model.collisionPairs)
           if WORLD.pair_kinds[i].value == "arm_self" and {cp.first, cp.second} <= moving]  # fmt: skip
    assert own and np.all(W[own][:, 0] == 0) and np.all(W[own][:, 6] == 0)


def test_first_violation_matches_a_dense_scan_on_random_moves():
    """Random joint-space moves of both arms: the sweep's first violation lies between the
    last clear and the first violating sample of a scan 20x finer; clear moves are clear."""
    rng = np.random.default_rng(11)
    required = np.array([0.0 if k.value == "arm_self" else 0.01 for k in WORLD.pair_kinds])
    found = clear = 0
    for _ in range(8):
        q0 = np.r_[UPRIGHT, UPRIGHT] + rng.uniform(-0.3, 0.3, 12)
        q1 = np.r_[REACH, REACH] + rng.uniform(-0.5, 0.5, 12)
        if np.any(all_pair_distances(WORLD, q0) < required):
            continue
        t, Q = _line(q0, q1, 0.2, RATE)
        v = check_sweep(WORLD, t, Q)
        tf, Qf = _line(q0, q1, 0.2, RATE * 20)
        bad = [i for i in range(len(tf)) if np.any(all_pair_distances(WORLD, Qf[i]) < required)]
        if not bad:
            assert v is None
            clear += 1
            continue
        found += 1
        assert v is not None and v.t <= tf[bad[0]] + 1e-12
        assert v.t >= tf[bad[0]] - 1.0 / (RATE * 20) - 1e-12
    assert found >= 3
