"""Closed-form relay IK: exact reflection, exact spot, joint limits."""

from __future__ import annotations

import numpy as np
import pytest

from planner.beam import BeamModel
from planner.studies.coverage import coverage_system
from planner.studies.relay_geometry import mirror_pose, solve_chain, solve_single
from planner.studies.sensitivity import default_system, grid_targets


def test_mirror_pose_reflects_v_in_into_v_out() -> None:
    rng = np.random.default_rng(1)
    for _ in range(50):
        v_in, v_out = rng.standard_normal((2, 3))
        v_in /= np.linalg.norm(v_in)
        v_out /= np.linalg.norm(v_out)
        M = mirror_pose(np.zeros(3), v_in, v_out, rng.uniform(0, 6))
        n = M[:3, 2]
        assert np.allclose(v_in - 2 * (v_in @ n) * n, v_out, atol=1e-12)
        assert n @ v_in < 0  # front face
        assert np.allclose(M[:3, :3].T @ M[:3, :3], np.eye(3), atol=1e-12)


def test_mirror_pose_rejects_straight_through() -> None:
    v = np.array([0.0, 0.0, 1.0])
    with pytest.raises(ValueError):
        mirror_pose(np.zeros(3), v, v, 0.0)


def test_solve_single_puts_the_spot_on_the_target() -> None:
    system = default_system()
    model = BeamModel(system)
    for t in grid_targets(n=2):
        q = solve_single(system, t)
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
