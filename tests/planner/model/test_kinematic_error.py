"""The true arm's kinematic error: the perturbed UR5e against an independent DH computation."""

from __future__ import annotations

import numpy as np
import pytest

from planner.model.kinematic_error import (
    FACTORY,
    UNCALIBRATED,
    DHError,
    KinematicSpread,
    perturbed_ur5e,
)
from planner.model.kinematics import RobotKinematics
from planner.studies import experiments_setup as setup

# the UR5e's published standard DH (SPEC section 2), typed again here on purpose
D = [0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996]
A = [0.0, -0.425, -0.3922, 0.0, 0.0, 0.0]
ALPHA = [np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0]


def _dh_fk(q: np.ndarray, e: DHError) -> np.ndarray:
    """Textbook DH product with the deltas: Rz(q + dtheta) Tz(d) Tx(a) Rx(alpha) Ry(beta)."""
    T = np.eye(4)
    for i in range(6):
        th, d, a = q[i] + e.dtheta[i], D[i] + e.dd[i], A[i] + e.da[i]
        al, be = ALPHA[i] + e.dalpha[i], e.dbeta[i]
        ct, st, ca, sa, cb, sb = (
            np.cos(th),
            np.sin(th),
            np.cos(al),
            np.sin(al),
            np.cos(be),
            np.sin(be),
        )
        Rz = np.array([[ct, -st, 0, 0], [st, ct, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
        Tza = np.array([[1, 0, 0, a], [0, 1, 0, 0], [0, 0, 1, d], [0, 0, 0, 1]])
        Rx = np.array([[1, 0, 0, 0], [0, ca, -sa, 0], [0, sa, ca, 0], [0, 0, 0, 1]])
        Ry = np.array([[cb, 0, sb, 0], [0, 1, 0, 0], [-sb, 0, cb, 0], [0, 0, 0, 1]])
        T = T @ Rz @ Tza @ Rx @ Ry
    return T


def _error(rng: np.random.Generator, scale: float = 1e-2) -> DHError:
    return DHError(*(scale * rng.standard_normal((5, 6))))


def test_perturbed_fk_is_the_dh_product_with_the_drawn_deltas() -> None:
    rng = np.random.default_rng(3)
    nominal = RobotKinematics.ur5e()
    for _ in range(5):
        e = _error(rng)
        kin = perturbed_ur5e(e, nominal)
        for q in rng.uniform(-np.pi, np.pi, (10, 6)):
            np.testing.assert_allclose(kin.fk(q), _dh_fk(q, e), atol=1e-12)
            np.testing.assert_allclose(np.asarray(kin.casadi_fk(q)), kin.fk(q), atol=1e-12)
        assert not kin.has_analytic_ik and kin.name == nominal.name


def test_zero_error_is_the_nominal_arm_and_the_nominal_is_untouched() -> None:
    nominal = RobotKinematics.ur5e()
    q = np.array([0.3, -1.2, 1.1, -0.7, -1.5, 0.4])
    before = nominal.fk(q)
    kin = perturbed_ur5e(DHError(*np.zeros((5, 6))), nominal)
    np.testing.assert_allclose(kin.fk(q), before, atol=1e-15)
    perturbed_ur5e(_error(np.random.default_rng(0)), nominal)
    np.testing.assert_array_equal(nominal.fk(q), before)


def test_joint_zero_offsets_shift_the_joints() -> None:
    rng = np.random.default_rng(5)
    dtheta = rng.uniform(-0.01, 0.01, 6)
    e = DHError(dtheta, *np.zeros((4, 6)))
    nominal = RobotKinematics.ur5e()
    kin = perturbed_ur5e(e, nominal)
    for q in rng.uniform(-3, 3, (10, 6)):
        np.testing.assert_allclose(kin.fk(q), nominal.fk(q + dtheta), atol=1e-12)


@pytest.mark.parametrize("spread", [FACTORY, UNCALIBRATED])
def test_draws_have_the_spread_of_the_level(spread: KinematicSpread) -> None:
    rng = np.random.default_rng(11)
    draws = [spread.draw(rng) for _ in range(2000)]
    np.testing.assert_allclose(np.std([d.dtheta for d in draws]), spread.zero, rtol=0.03)
    np.testing.assert_allclose(np.std([[d.dd, d.da] for d in draws]), spread.length, rtol=0.03)
    np.testing.assert_allclose(np.std([[d.dalpha, d.dbeta] for d in draws]), spread.angle,
                               rtol=0.03)  # fmt: skip


def test_factory_level_is_the_rms_of_the_published_ur5e_calibration() -> None:
    # (calibrated, nominal) as printed in the calibration file and ur_description's
    # default_kinematics.yaml of the UR5e
    lengths = [(0.1627122445743823, 0.1625), (0.0001820110310317555, 0.0),
               (-0.425170344631444, -0.425), (-0.392646598028507, -0.3922),
               (-0.0004030322688786401, 0.0), (0.1331063119537431, 0.1333),
               (-7.071306960874342e-06, 0.0), (-0.09960359635829828, -0.0997),
               (-3.198591184007791e-07, 0.0), (1.369362273278849e-05, 0.0),
               (0.09958483828527664, 0.0996), (9.521789789182917e-05, 0.0)]  # fmt: skip
    angles = [(1.571314866107557, np.pi / 2), (0.001444320579376547, 0.0),
              (-0.0004261037597356073, 0.0), (0.003027888244224887, 0.0),
              (-0.001185722601572754, 0.0), (1.570799538115874, np.pi / 2),
              (1.571752475045119, np.pi / 2)]  # fmt: skip
    rms = [float(np.sqrt(np.mean([(c - n) ** 2 for c, n in x]))) for x in (lengths, angles)]
    assert FACTORY.length == pytest.approx(rms[0], rel=1e-3)
    assert FACTORY.angle == pytest.approx(rms[1], rel=1e-3)
    assert UNCALIBRATED.angle > FACTORY.angle and UNCALIBRATED.length > FACTORY.length


def test_truth_gets_its_own_arm_and_the_other_draws_do_not_move() -> None:
    nominal = setup.nominal_system()
    plain = setup.draw_truth(nominal, setup.Unknowns(), np.random.default_rng(2))
    arm = setup.draw_truth(nominal, setup.Unknowns(), np.random.default_rng(2), FACTORY,
                           np.random.default_rng(9))  # fmt: skip
    np.testing.assert_array_equal(plain.system.world_T_laser, arm.system.world_T_laser)
    np.testing.assert_array_equal(plain.flange_T_board, arm.flange_T_board)
    q = nominal.home
    true_kin = arm.system.robots[0].kinematics
    assert true_kin is not nominal.robots[0].kinematics
    e = FACTORY.draw(np.random.default_rng(9))
    np.testing.assert_allclose(true_kin.fk(q), _dh_fk(q, e), atol=1e-12)
    assert plain.system.robots[0].kinematics is nominal.robots[0].kinematics
