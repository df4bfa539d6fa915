"""Numpy beam geometry of the checkers: DH FK vs SPEC and Pinocchio, poses, limits, rays."""

from __future__ import annotations

import numpy as np
import pytest

from planner.errors import InputError
from planner.model.kinematics import RobotKinematics
from planner.model.transforms import make_T, rpy_to_matrix
from planner.verify.numpy_beam import limits_from_dict, pose_matrix, trace_rays, ur5e_dh_fk


def test_dh_check_value_from_spec() -> None:
    q = np.array([0, -np.pi / 2, 0, -np.pi / 2, 0, 0])
    np.testing.assert_allclose(ur5e_dh_fk(q)[:3, 3], [0.0, -0.2329, 1.0794], atol=1e-4)
    np.testing.assert_allclose(ur5e_dh_fk(q[None])[0, :3, 3], [0.0, -0.2329, 1.0794], atol=1e-4)


def test_dh_matches_pinocchio_model() -> None:
    kin = RobotKinematics.ur5e()
    Q = np.random.default_rng(3).uniform(-np.pi, np.pi, (10, 6))
    for q in Q:
        np.testing.assert_allclose(ur5e_dh_fk(q), kin.fk(q), atol=1e-14)
    np.testing.assert_allclose(ur5e_dh_fk(Q), np.stack([kin.fk(q) for q in Q]), atol=1e-12)


def test_pose_forms() -> None:
    R = rpy_to_matrix([0.1, -0.2, 0.3])
    expect = make_T(R, [1, 2, 3])
    np.testing.assert_allclose(pose_matrix({"xyz": [1, 2, 3], "rpy": [0.1, -0.2, 0.3]}), expect)
    got = pose_matrix({"xyz": [1, 2, 3], "rpy_deg": np.degrees([0.1, -0.2, 0.3]).tolist()})
    np.testing.assert_allclose(got, expect)
    np.testing.assert_allclose(pose_matrix({"matrix": expect.tolist()}), expect)
    T = pose_matrix({"xyz": [1, 2, 3], "rpy_deg": [0, 0, 90]})
    np.testing.assert_allclose(T[:3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    # quat [x, y, z, w]: 90 deg about z
    T = pose_matrix({"quat": [0, 0, np.sqrt(0.5), np.sqrt(0.5)]})
    np.testing.assert_allclose(T[:3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(pose_matrix({}), np.eye(4))
    with pytest.raises(InputError):
        pose_matrix({"matrix": [[1, 0], [0, 1]]}, "x")
    with pytest.raises(InputError):
        pose_matrix(None, "x")


def test_limits_defaults_and_overrides() -> None:
    lim = limits_from_dict({"upper": [1.0] * 6, "jerk": None}, 6)
    np.testing.assert_allclose(lim.upper, 1.0)
    np.testing.assert_allclose(lim.lower, [-2 * np.pi] * 2 + [-np.pi] + [-2 * np.pi] * 3)
    np.testing.assert_allclose(lim.velocity, np.pi)
    np.testing.assert_allclose(lim.acceleration, 5.0)
    np.testing.assert_allclose(lim.jerk, 50.0)
    np.testing.assert_allclose(limits_from_dict(None, 7).upper, 2 * np.pi)


def test_two_mirror_periscope() -> None:
    # beam along +x from the origin; mirror 1 at x = 1 tilted 45 deg sends it up (+z);
    # mirror 2 at z = 1 above it sends it along +x again (a periscope)
    laser = make_T(rpy_to_matrix([0, np.pi / 2, 0]), [0, 0, 0])  # +z of laser = +x world
    n1, n2 = np.array([-1, 0, 1]) / np.sqrt(2), np.array([1, 0, -1]) / np.sqrt(2)

    def mirror(n: np.ndarray, c: list[float], du: float) -> np.ndarray:
        y = np.array([0.0, 1.0, 0.0])
        R = np.column_stack([np.cross(y, n), y, n])
        return make_T(R, np.array(c) + du * R[:, 0])[None]  # centre shifted along its x

    rays = trace_rays(laser, [mirror(n1, [1, 0, 0], 0.01), mirror(n2, [1, 0, 1], -0.02)])
    np.testing.assert_allclose(rays.hits[0][0], [1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(rays.hits[1][0], [1, 0, 1], atol=1e-15)
    np.testing.assert_allclose(rays.uv[0][0], [-0.01, 0.0], atol=1e-15)
    np.testing.assert_allclose(rays.uv[1][0], [0.02, 0.0], atol=1e-15)
    np.testing.assert_allclose(rays.front[0], [np.sqrt(0.5)], atol=1e-15)
    np.testing.assert_allclose(rays.front[1], [np.sqrt(0.5)], atol=1e-15)
    np.testing.assert_allclose([rays.ahead[0][0], rays.ahead[1][0]], [1.0, 1.0], atol=1e-15)
    np.testing.assert_allclose(rays.p[0], [1, 0, 1], atol=1e-15)
    np.testing.assert_allclose(rays.v[0], [1, 0, 0], atol=1e-15)


def test_batch_matches_one_by_one() -> None:
    rng = np.random.default_rng(5)
    laser = make_T(rpy_to_matrix(rng.uniform(-1, 1, 3)), rng.uniform(-1, 1, 3))
    stacks = [np.stack([make_T(rpy_to_matrix(rng.uniform(-1, 1, 3)), rng.uniform(-1, 1, 3))
                        for _ in range(4)]) for _ in range(2)]  # fmt: skip
    batch = trace_rays(laser, stacks)
    for m in range(4):
        one = trace_rays(laser, [S[m : m + 1] for S in stacks])
        np.testing.assert_allclose(batch.p[m], one.p[0], atol=1e-12)
        np.testing.assert_allclose(batch.v[m], one.v[0], atol=1e-12)
        # the last direction is the laser's, reflected by hand: v - 2 (v.n) n per mirror
        v = laser[:3, 2].copy()
        for S in stacks:
            n = S[m, :3, 2]
            v = v - 2 * (v @ n) * n
        np.testing.assert_allclose(batch.v[m], v, atol=1e-12)
