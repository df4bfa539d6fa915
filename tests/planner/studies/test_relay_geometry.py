"""Beam IK at a prescribed relay geometry: exact reflection, exact spot, joint limits."""

from __future__ import annotations

import numpy as np
import pytest

from planner.beam.graph import BeamModel
from planner.studies.coverage import coverage_system
from planner.studies.relay_geometry import laser_ray, mirror_ik, solve_chain
from planner.studies.sensitivity import default_system, grid_targets


def test_mirror_ik_reflects_v_in_into_v_out() -> None:
    """FK of the returned joints (Pinocchio) puts the mirror at the hit with the bisector
    normal: the numpy reflection of v_in is v_out."""
    system = default_system()
    robot = system.robots[0]
    p0, v_in = laser_ray(system)
    hit = p0 + 0.8 * v_in
    rng = np.random.default_rng(1)
    checked = 0
    for t in rng.uniform(-0.1, 0.1, (10, 3)) + np.array([0.45, 0.15, 0.0]):
        v_out = (t - hit) / np.linalg.norm(t - hit)
        q = mirror_ik(robot, hit, v_in, v_out)
        if q is None:
            continue
        M = robot.world_T_base @ robot.kinematics.fk(q) @ robot.mirror.flange_T_mirror
        n = M[:3, 2]
        assert np.allclose(M[:3, 3], hit, atol=1e-9)
        assert np.allclose(v_in - 2 * (v_in @ n) * n, v_out, atol=1e-9)
        assert n @ v_in < 0  # front face
        assert np.all(q >= robot.limits.lower) and np.all(q <= robot.limits.upper)
        checked += 1
    assert checked >= 8


def test_mirror_ik_rejects_straight_through() -> None:
    system = default_system()
    v = np.array([0.0, 0.0, 1.0])
    assert mirror_ik(system.robots[0], np.array([0.4, 0.0, 0.3]), v, v) is None


def test_solve_chain_one_robot_hits_the_mirror_centre() -> None:
    system = default_system()
    model = BeamModel(system)
    p0, v0 = laser_ray(system)
    for t in grid_targets(n=2):
        q = solve_chain(system, [p0 + 0.8 * v0], t)
        assert q is not None
        tr = model.trace(q, t)
        assert tr.error < 1e-9 and tr.valid
        assert np.all(tr.uv == pytest.approx(0.0, abs=1e-9))  # hits the mirror centre
        assert np.all(q >= system.lower) and np.all(q <= system.upper)


def test_solve_chain_relays_through_two_robots() -> None:
    system = coverage_system(2)
    p0, v0 = system.world_T_laser[:3, 3], system.world_T_laser[:3, 2]
    hits = [p0 + 0.5 * v0, np.array([-0.1, 0.25, 0.45])]
    target = np.array([0.0, 0.0, 0.43])  # top of the sphere
    q = solve_chain(system, hits, target)
    assert q is not None
    tr = BeamModel(system).trace(q, target)
    assert tr.error < 1e-9 and tr.valid
    assert np.allclose(tr.hits, np.array(hits), atol=1e-9)
