"""Closed-form family: geometry helpers, member-by-member validity, search behaviour."""

from __future__ import annotations

import numpy as np
import pytest

from planner.beam.graph import BeamModel
from planner.ik.closed_form import ClosedForm, bisector, pick_branch, seed_kinematics
from planner.model.kinematics import RobotKinematics
from planner.model.mirror import Mirror
from planner.model.transforms import inv_T
from tests.planner.ik import ik_systems as sy


def test_bisector_reflects_incoming_into_outgoing() -> None:
    rng = np.random.default_rng(1)
    for _ in range(20):
        d_in, d_out = (x / np.linalg.norm(x) for x in rng.normal(size=(2, 3)))
        n = bisector(d_in, d_out)
        assert n is not None
        np.testing.assert_allclose(d_in - 2 * (d_in @ n) * n, d_out, atol=1e-14)
        assert -(n @ d_in) > 0  # front face
    assert bisector(np.array([1.0, 0, 0]), np.array([1.0, 0, 0])) is None


def test_mirror_frame_places_hit_at_uv() -> None:
    h, n = np.array([0.1, 0.2, 0.3]), np.array([0.0, 0.6, 0.8])
    T = Mirror(np.eye(4)).place(h, n, np.array([1.0, 0.0, 0.0]), 0.7, np.array([0.01, -0.02]))
    np.testing.assert_allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-15)
    assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)
    np.testing.assert_allclose(T[:3, 2], n)
    np.testing.assert_allclose((inv_T(T) @ np.append(h, 1))[:3], [0.01, -0.02, 0.0], atol=1e-15)


def test_pick_branch_wraps_toward_reference_and_respects_limits() -> None:
    lower, upper = np.full(2, -2 * np.pi), np.full(2, 2 * np.pi)
    branches = np.array([[0.1, -3.0], [3.0, 3.0]])
    q, viol = pick_branch(branches, np.array([0.0, 3.2]), lower, upper)
    np.testing.assert_allclose(q, [0.1, -3.0 + 2 * np.pi])  # -3 is 6.28-3 = 3.28 near 3.2
    assert viol == 0.0
    q, viol = pick_branch(branches, np.zeros(2), np.full(2, -0.05), np.full(2, 0.2))
    assert q is None
    assert viol == pytest.approx(3.0 - 0.2)  # branch 1: 3.0 (or -3.28 wrapped) vs 0.2


def test_seed_kinematics() -> None:
    nominal = RobotKinematics.ur5e()
    assert seed_kinematics(nominal) is nominal


def test_seed_for_calibrated_urdf_is_nominal(tmp_path) -> None:  # type: ignore[no-untyped-def]
    cal = RobotKinematics.from_urdf(sy.perturbed_urdf(tmp_path, 0.002))
    seed = seed_kinematics(cal)
    assert seed is not None and seed.has_analytic_ik
    far = RobotKinematics.from_urdf(sy.perturbed_urdf(tmp_path, 0.05))
    assert seed_kinematics(far) is None


@pytest.mark.parametrize("s", [0.7, 0.9, 1.1])
@pytest.mark.parametrize("psi", [0.0, 1.0, -2.5])
@pytest.mark.parametrize("uv", [(0.0, 0.0), (0.02, -0.015)])
def test_every_member_branch_satisfies_the_nlp_constraints(s, psi, uv) -> None:  # type: ignore[no-untyped-def]
    """Members (s, psi, u, v): every IK branch hits the target exactly and is a valid chain
    by the CasADi beam graph (front face, ahead, ROI, target ahead)."""
    system = sy.n1()
    model = BeamModel(system)
    r = system.robots[0]
    p0, v0 = system.world_T_laser[:3, 3], system.world_T_laser[:3, 2]
    target = np.array([0.3, 0.3, 0.3])
    h = p0 + s * v0
    d = (target - h) / np.linalg.norm(target - h)
    n = bisector(v0, d)
    assert n is not None
    T = r.mirror.place(h, n, np.array([1.0, 0, 0]), psi, np.array(uv))
    branches = r.kinematics.analytic_ik(inv_T(r.world_T_base) @ T @ inv_T(r.mirror.flange_T_mirror))
    assert branches
    for q in branches:
        tr = model.trace(q, target)
        assert tr.error <= 1e-12
        assert tr.valid
        np.testing.assert_allclose(tr.uv[0], uv, atol=1e-12)
        np.testing.assert_allclose(tr.hits[0], h, atol=1e-12)


def test_search_follows_previous_configuration() -> None:
    system = sy.n1()
    cf = ClosedForm(system)
    a = cf.search(np.array([0.3, 0.3, 0.3]), None, system.home)
    assert a.q is not None
    b = cf.search(np.array([0.301, 0.3, 0.3]), None, a.q)
    assert b.q is not None
    assert np.abs(b.q - a.q).max() < 0.05  # 1 mm target step: small joint step
    assert b.members == 1


def test_closed_form_needs_seed_models(tmp_path) -> None:  # type: ignore[no-untyped-def]
    far = RobotKinematics.from_urdf(sy.perturbed_urdf(tmp_path, 0.05))
    with pytest.raises(ValueError, match="analytic seed"):
        ClosedForm(sy.n1(kin=far))


def test_combos_follow_the_documented_priority_order() -> None:
    """The lazy generator yields hit lists in the order of an explicit full sort: cost =
    |s offset| + sum of the intermediate steps' lengths (ties in product order)."""
    import itertools

    from planner.ik.closed_form import _H_STEPS

    cf = ClosedForm(sy.n2())
    centres = [np.zeros(3), np.array([0.1, 0.2, 0.3])]
    offsets = (0.0, 0.03, -0.03, 0.3)
    steps = [np.zeros(3)] + [
        a * e for a in _H_STEPS[1:] for e in np.vstack([np.eye(3), -np.eye(3)])
    ]
    mids = sorted(itertools.product(range(len(steps)), repeat=1),
                  key=lambda ks: sum(np.linalg.norm(steps[k]) for k in ks))[:25]  # fmt: skip
    expected = sorted(
        itertools.product(offsets, mids),
        key=lambda c: abs(c[0]) + sum(np.linalg.norm(steps[k]) for k in c[1]),
    )
    got = list(cf._combos(0.5, centres, offsets))
    assert len(got) == len(expected) == 4 * len(steps)  # 19 steps for one free hit
    for hits, (ds, ks) in zip(got, expected, strict=True):
        np.testing.assert_allclose(hits[0], cf.p0 + max(0.5 + ds, 0.02) * cf.v0, atol=1e-15)
        np.testing.assert_allclose(hits[1], centres[1] + steps[ks[0]], atol=1e-15)
